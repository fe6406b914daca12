"""From an animation to files: render its frames (in one process or several) and write
them as MP4, GIF, a PNG sequence, or raw NPZ positions.

The output kind follows the path as the user means it: ``.mp4``, ``.gif``, ``.npz``,
``.png`` (one frame, the apex unless another is asked for), and a directory of
``frame_0000.png`` ... for a path that ends in a slash, is a directory already, or has no
suffix. Every output is written under a temporary name and renamed into
place when complete (``files.atomic_path``).
"""

from __future__ import annotations

import itertools
import os
import re
import subprocess
import sys
import time
import zipfile
from contextlib import contextmanager, nullcontext
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from numpy.lib import format as npy

from ..animation.simulate import Animation
from ..errors import InputError
from ..files import WriteError, atomic_path, check_destination, check_terminated, signals_deferred
from ..renderer.scene import FaceRenderer, shared_renderer
from ..renderer.settings import RenderSettings
from ..timings import phase
from ..workers import worker_pool

FULL_DISK = 1 << 20  # bytes free under which a short output is put down to a full disk
KINDS = {".mp4": "mp4", ".gif": "gif", ".npz": "npz", ".glb": "glb", ".csv": "csv", ".pc2": "pc2", ".usdc": "usdc"}
#: The kinds that carry the face to other tools, undrawn: a rig and its curves
#: (facesim.export.rig), a point cache (facesim.export.pointcache).
EXPORTS = ("glb", "csv", "pc2", "usdc")
#: Arrow length per unit of muscle force in --show-muscles (cm per force unit).
ARROW_SCALE = 0.004


def output_kind(path: str | Path) -> str:
    """mp4, gif, npz, image (one PNG), png (a directory of frames) or unknown."""
    text = os.fspath(path)
    suffix = Path(text).suffix.lower()
    if text.endswith(("/", os.sep)) or Path(text).is_dir() or suffix == "":
        return "png"
    return "image" if suffix == ".png" else KINDS.get(suffix, "unknown")


def check_output(path: str | Path, force: bool, settings: RenderSettings | None = None) -> str:
    """Validate an output path before any work: its kind, and that it may be written
    (facesim.files.check_destination: --force replaces only facesim's own outputs)."""
    kind = output_kind(path)
    path = Path(path)
    if kind == "unknown":
        raise InputError(f"{path}: unknown output type {path.suffix!r} (use .mp4, .gif, .npz, .png, a directory "
                         "written DIR/, .glb, .csv, .pc2 or .usdc)")
    if kind == "mp4" and settings is not None and (settings.width % 2 or settings.height % 2):
        raise InputError(f"--size: MP4 needs an even width and height, got {settings.width}x{settings.height}")
    if kind == "pc2":
        from .pointcache import check_point_cache

        check_point_cache(path, force)
    else:
        if kind == "usdc":
            from .usd import check_usd

            check_usd()
        check_destination(path, force, directory=kind == "png")
    return kind


def why_short(tmp: Path) -> str:
    """Why a written file came out short, as the end of a sentence: a full disk (as
    ffmpeg meets it, in its own process, where facesim sees no OSError), or unknown."""
    import shutil

    free = shutil.disk_usage(tmp.parent).free
    return f": no space left on device ({free // 1024} KB free)" if free < FULL_DISK else ""


def _verify_frames(kind: str, count: int, fps: float):
    """A check that a written output reads back with all ``count`` frames. A GIF holds a
    run of identical frames as one frame shown that much longer (Pillow merges them), so
    its frames are counted by their durations."""
    name = "PNG" if kind == "image" else kind.upper()

    def verify(tmp: Path) -> None:
        try:
            if kind == "mp4":
                import imageio_ffmpeg

                found = imageio_ffmpeg.count_frames_and_secs(str(tmp))[0]
            elif kind == "gif":
                from PIL import Image

                found = 0
                with Image.open(tmp) as image:
                    for k in range(image.n_frames):
                        image.seek(k)
                        found += max(1, round(image.info.get("duration", 1000.0 / fps) * fps / 1000.0))
            else:  # a directory of frames, or one frame
                from PIL import Image

                found = 0
                for png in [tmp] if kind == "image" else sorted(tmp.glob("frame_*.png")):
                    with Image.open(png) as image:
                        image.verify()
                    found += 1
        except Exception as exc:  # a truncated file fails in many ways
            raise WriteError(f"the written {name} does not read back ({type(exc).__name__}){why_short(tmp)}") from None
        if found != count:
            raise WriteError(f"the written {name} holds {found} of {count} frames{why_short(tmp)}")

    return verify


def arrows_for(animation: Animation) -> np.ndarray:
    """Muscle-force arrows (frames, n, 3) for --show-muscles, from an animation simulated
    ``with_muscle_forces`` (facesim.animation.simulate)."""
    if animation.muscle_force is None:
        raise ValueError("--show-muscles draws the muscle forces: simulate(spec, with_muscle_forces=True)")
    return ARROW_SCALE * animation.muscle_force


def _render_chunk(rest, faces, settings, backend, figure, face, positions, arrows, pose, jaw):
    """Frames rendered in a worker process, by the process's one shared renderer."""
    renderer = shared_renderer(rest, faces, settings, backend, figure, face)
    return np.stack([renderer.render(p, None if arrows is None else arrows[k], None if pose is None else pose[k], jaw[k])
                     for k, p in enumerate(positions)])


def render_frames(animation: Animation, settings: RenderSettings, backend: str = "auto", jobs: int = 1,
                  progress=None, renderer: FaceRenderer | None = None) -> np.ndarray:
    """All frames of an animation as (frames, height, width, 3) uint8 (``iter_frames``)."""
    return np.stack(list(iter_frames(animation, settings, backend, jobs, progress, renderer)))


def in_one_process(frames: int, jobs: int) -> bool:
    """Whether ``frames`` are drawn here rather than split over ``jobs`` processes."""
    return jobs <= 1 or frames < 2 * jobs


def drawn_in_order(kind: str, settings: RenderSettings, frames: int, jobs: int) -> bool:
    """Whether an output of ``kind`` reads each frame once, in order, in this process: a
    video or a directory of frames, without the muscles' arrows (which take every frame
    at once). Such an animation may be simulated streamed (facesim.animation.simulate)."""
    return kind in ("mp4", "gif", "png") and not settings.show_muscles and in_one_process(frames, jobs)


@contextmanager
def _renderer_for(animation: Animation, settings: RenderSettings, backend: str, renderer: FaceRenderer | None):
    """``renderer``, or one of the animation's own, closed after the block."""
    own = renderer is None
    if own:
        with phase("figure"):
            animation.figure  # the head's skin weights, built or read from facesim's cache
        with phase("GL context"):
            renderer = FaceRenderer.of(animation, settings, backend)
    try:
        yield renderer
    finally:
        if own:
            renderer.close()


def iter_frames(animation: Animation, settings: RenderSettings, backend: str = "auto", jobs: int = 1,
                progress=None, renderer: FaceRenderer | None = None):
    """The frames of an animation, (height, width, 3) uint8 each, in order, as they are
    rendered: a writer encodes one while the next renders (``write_frames``).

    With ``jobs`` > 1 the frames are split into contiguous chunks rendered by that many
    processes (started with spawn: an OpenGL context must not be forked), each with its
    own renderer. ``renderer`` lets a caller reuse one across animations of one mesh.
    """
    frames = animation.frames
    in_process = in_one_process(frames, jobs)
    if settings.show_muscles or not in_process:
        animation.ready()  # the arrows, and the processes' chunks, take every frame at once
    arrows = arrows_for(animation) if settings.show_muscles else None
    if in_process:
        with _renderer_for(animation, settings, backend, renderer) as renderer:
            for image in renderer.frames(animation, arrows):
                check_terminated()  # a signal that the OpenGL wrappers swallowed stops here
                yield image
                if progress:
                    progress(1)
        return
    if animation.streamed:
        raise ValueError("a streamed animation is drawn in order in one process")
    bounds = np.linspace(0, frames, jobs * 2 + 1).astype(int)
    pose = animation.pose
    chunks = [(animation.positions[a:b], None if arrows is None else arrows[a:b], None if pose is None else pose[a:b],
               animation.jaw[a:b]) for a, b in zip(bounds[:-1], bounds[1:])]
    fixed = [(animation.rest, animation.faces, settings, backend, animation.figure, animation.face)] * len(chunks)
    with worker_pool(jobs) as pool:
        for (positions, *_), images in zip(chunks, pool.map(_render_chunk, *zip(*fixed), *zip(*chunks))):
            check_terminated()
            yield from images
            if progress:
                progress(len(positions))


def write_frames(frames, path: Path, kind: str, fps: float, replace: bool = True, count: int | None = None,
                 audio: tuple[np.ndarray, int] | None = None) -> None:
    """Write rendered frames atomically as MP4, GIF or a PNG directory, verified by
    reading them back (``replace``: whether an existing output may be replaced).
    ``frames`` is an array or, with their ``count``, any iterable (``iter_frames``): an
    MP4's encoder then works in its own process on each frame while the next renders.
    ``audio`` (samples, rate): the sound an MP4 carries (AAC), read back with it (a
    GIF and PNGs carry none)."""
    import imageio.v3 as iio

    count = len(frames) if count is None else count
    verify = _verify_frames(kind, count, fps)
    if audio is not None and kind == "mp4":  # and, at another fps than its spec's, it is out of time with them
        verify = _with_sound(verify, count / fps, fps)
    frames = _drawn(frames)
    if kind == "png":
        with atomic_path(path, directory=True, replace=replace, verify=verify) as tmp:
            for k, frame in enumerate(frames):
                with phase("encoding"):
                    iio.imwrite(tmp / f"frame_{k:04d}.png", frame)
        return
    with atomic_path(path, replace=replace, verify=verify) as tmp:
        if kind == "mp4":
            import imageio_ffmpeg

            frames = iter(frames)
            first = next(frames)
            height, width = first.shape[:2]
            sound = None
            if audio is not None:
                sound = tmp.with_name(tmp.name + ".wav")
                write_wav(sound, *audio)
            with signals_deferred():  # the encoder, once started, is always closed
                writer = imageio_ffmpeg.write_frames(
                    str(tmp), (width, height), fps=fps, codec="libx264", pix_fmt_out="yuv420p",
                    output_params=["-crf", "18", "-preset", "veryfast"] + (["-b:a", "128k"] if sound else []),
                    macro_block_size=1, audio_path=None if sound is None else str(sound),
                    audio_codec=None if sound is None else "aac",
                    ffmpeg_log_level="quiet",  # its failures are found by reading the file back
                )
                writer.send(None)
            try:
                check_terminated()
                for frame in itertools.chain([first], frames):
                    with phase("encoding"):
                        writer.send(np.ascontiguousarray(frame))
            finally:
                writer.close()
                if sound is not None:
                    sound.unlink(missing_ok=True)
        elif kind == "gif":  # Pillow directly: imageio's plugin flushes again at garbage collection
            from PIL import Image

            first, *rest = (Image.fromarray(frame) for frame in frames)
            with open(tmp, "wb") as stream, phase("encoding"):
                first.save(stream, format="GIF", save_all=True, append_images=rest, duration=1000.0 / fps, loop=0)


def write_wav(path: Path, samples: np.ndarray, rate: int) -> None:
    """Mono 16-bit PCM WAV of ``samples`` (-1..1) at ``rate`` Hz."""
    import wave

    with wave.open(str(path), "wb") as wav:
        wav.setnchannels(1)
        wav.setsampwidth(2)
        wav.setframerate(rate)
        wav.writeframes((np.clip(samples, -1.0, 1.0) * 32767).astype("<i2").tobytes())


def streams(path: Path) -> dict[str, float]:
    """The duration (s) of each stream of a media file ffmpeg reads ('video', 'audio'),
    from ffmpeg decoding the stream to its end (its last timestamp)."""
    import imageio_ffmpeg

    found = {}
    for kind, letter in (("video", "v"), ("audio", "a")):
        result = subprocess.run([imageio_ffmpeg.get_ffmpeg_exe(), "-hide_banner", "-i", str(path), "-map",
                                 f"0:{letter}:0", "-f", "null", "-"], capture_output=True, text=True, timeout=300)
        times = re.findall(r"time=(\d+):(\d+):([\d.]+)", result.stderr)
        if result.returncode == 0 and times:
            h, m, sec = times[-1]
            found[kind] = int(h) * 3600 + int(m) * 60 + float(sec)
    return found


def _with_sound(verify, seconds: float, fps: float):
    """``verify``, and the MP4's sound there, as long as its frames within one frame."""

    def check(tmp: Path) -> None:
        verify(tmp)
        found = streams(tmp)
        if "audio" not in found:
            raise WriteError(f"the written MP4 has no sound{why_short(tmp)}")
        if abs(found["audio"] - seconds) > 1.0 / fps:
            raise WriteError(f"the written MP4's sound lasts {found['audio']:.2f} s, its frames {seconds:.2f} s")

    return check


def _drawn(frames):
    """``frames``, the time each takes to come counted as drawing (facesim.timings): a
    renderer's frame, with any wait for its simulation."""
    frames = iter(frames)
    while True:
        with phase("drawing"):
            frame = next(frames, None)
        if frame is None:
            return
        yield frame


def write_image(image: np.ndarray, path: Path, replace: bool = True) -> None:
    """One frame as a PNG, atomically, read back before it is renamed into place."""
    import imageio.v3 as iio

    with atomic_path(path, replace=replace, verify=_verify_frames("image", 1, 1.0)) as tmp:
        iio.imwrite(tmp, image)


def _verify_npz(frames: int):
    def verify(tmp: Path) -> None:
        try:
            with np.load(tmp) as data:
                complete = data["positions"].shape[0] == frames
        except Exception as exc:  # a truncated archive fails in many ways
            raise WriteError(f"the written NPZ does not read back ({type(exc).__name__}){why_short(tmp)}") from None
        if not complete:
            raise WriteError(f"the written NPZ is incomplete{why_short(tmp)}")

    return verify


def write_npz(animation: Animation, path: Path, replace: bool = True) -> None:
    """The animation's positions and what they mean, as NumPy arrays in an NPZ. On the head,
    ``positions`` holds every vertex of the head per frame, (frames, 26719, 3) float32 in
    ICT FaceKit's vertex order, as rendered (the skin, jaw, teeth, tongue, lids, eyes and
    the head's pose about the neck) with ``faces`` ICT's triangles and ``rest`` its rest
    shape; the simulated skin is apart (``skin_positions``, ``skin_faces``, ``skin_rest``,
    and ``skin_on_head``, the head's vertex each skin vertex lies on). The head's frames
    are written one by one into the archive, never held together. On a face mask,
    ``positions`` are its own vertices (frames, n, 3). A spec that speaks adds its sound:
    ``audio`` (float32, mono, as long as the frames) at ``audio_rate`` Hz."""
    if animation.streamed:
        raise ValueError("an NPZ holds every frame's positions: simulate without stream")
    arrays = dict(
        activations=animation.activations, muscles=np.array(animation.muscle_names), dt=np.array(animation.dt),
        kinetic_energy=animation.kinetic_energy,
        pose=np.zeros((animation.frames, 5)) if animation.pose is None else animation.pose,
    )
    if animation.audio is not None:  # a speaking spec's sound, as long as its frames
        arrays.update(audio=animation.audio, audio_rate=np.array(animation.audio_rate))
    head = None if animation.figure is None else animation.model.mesh.head
    if head is None:
        arrays.update(positions=animation.positions, faces=animation.faces, rest=animation.rest)
        frames = None
    else:
        arrays.update(skin_positions=animation.positions, skin_faces=animation.faces, skin_rest=animation.rest,
                      skin_on_head=head.landmarks, faces=head.triangles, rest=animation.figure.rest)
        frames = (animation.head_at(k).astype("<f4") for k in range(animation.frames))
    with atomic_path(path, replace=replace, verify=_verify_npz(animation.frames)) as tmp:
        with zipfile.ZipFile(tmp, "w", compression=zipfile.ZIP_DEFLATED) as archive:
            for name, array in arrays.items():
                with archive.open(f"{name}.npy", "w", force_zip64=True) as member:
                    npy.write_array(member, np.asanyarray(array), allow_pickle=False)
            if frames is not None:
                shape = (animation.frames, len(animation.figure.rest), 3)
                with archive.open("positions.npy", "w", force_zip64=True) as member:
                    npy.write_array_header_2_0(member, {"descr": "<f4", "fortran_order": False, "shape": shape})
                    for frame in frames:
                        member.write(frame.tobytes())


@dataclass
class RenderReport:
    """What one render did, for the batch table."""

    name: str
    output: Path
    muscles: int
    frames: int
    simulation_seconds: float
    render_seconds: float

    @property
    def fps(self) -> float:
        return self.frames / max(self.simulation_seconds + self.render_seconds, 1e-9)


def write_animation(animation: Animation, path: str | Path, settings: RenderSettings, fps: float | None = None,
                    backend: str = "auto", jobs: int = 1, progress=None,
                    renderer: FaceRenderer | None = None, replace: bool = False, frame: int | None = None) -> RenderReport:
    """Render (unless NPZ) and write one animation; the output path was checked before
    (``replace``: it was allowed to exist, with --force). A ``.png`` is one frame:
    ``frame``, by default the apex."""
    kind = output_kind(path)
    if kind in EXPORTS:
        raise ValueError(f"{path}: a rig and its curves are written by facesim.export.rig.write_clip, from the spec")
    path = Path(path)
    start = time.perf_counter()
    if kind == "npz":
        write_npz(animation.ready(), path, replace)
    elif kind == "image":
        k = animation.apex_frame if frame is None else frame
        with _renderer_for(animation, settings, backend, renderer) as renderer:
            image = renderer.frame(animation.ready(k), k, arrows_for(animation)[k] if settings.show_muscles else None)
        write_image(image, path, replace)
    else:
        frames = iter_frames(animation, settings, backend, jobs, progress, renderer)
        audio = None if animation.audio is None else (animation.audio, animation.audio_rate)
        write_frames(frames, path, kind, fps or animation.fps, replace, count=animation.frames, audio=audio)
    return RenderReport(animation.name, path, len(animation.active_muscles), 1 if kind == "image" else animation.frames,
                        animation.simulation_seconds, time.perf_counter() - start)


def render(animation: Animation, path: str | Path, settings: RenderSettings | None = None, force: bool = False,
           backend: str = "auto") -> RenderReport:
    """Write an animation (facesim.animation.simulate's) to ``path`` as ``facesim render -o`` does:
    an MP4, GIF, NPZ or a directory of PNG frames by its name, drawn with ``settings``
    (512x512 from the front by default). ``force``: replace an output facesim wrote
    before. The path is checked before anything is drawn (InputError)."""
    settings = (settings or RenderSettings()).for_face(animation.face)
    check_output(path, force, settings)
    return write_animation(animation, path, settings, backend=backend, replace=force)


def progress_bar(total: int, description: str, enabled: bool | None = None):
    """A rich progress bar on a terminal; a no-op context otherwise."""
    if enabled is None:
        enabled = sys.stderr.isatty()
    if not enabled:
        return nullcontext(None)
    from rich.progress import BarColumn, Progress, TextColumn, TimeRemainingColumn

    class _Bar:
        def __enter__(self):
            self.progress = Progress(TextColumn("{task.description}"), BarColumn(), TextColumn("{task.completed}/{task.total}"),
                                     TimeRemainingColumn(), transient=True)
            self.progress.__enter__()
            self.task = self.progress.add_task(description, total=total)
            return lambda n=1: self.progress.advance(self.task, n)

        def __exit__(self, *exc):
            self.progress.__exit__(*exc)

    return _Bar()

