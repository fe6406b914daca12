"""The facesim command line. Each command parses its arguments and calls plain functions
of the package; errors the user can act on are one line on stderr with exit code 2
(bad input) or 1 (a run that failed), never a traceback.
"""

from __future__ import annotations

import functools
import signal
import subprocess
import sys
from pathlib import Path
from typing import Optional

import numpy as np
import typer

from .dataset import SCHEDULER_TIMEOUT
from .errors import FacesimError, InputError
from .files import Terminated, check_destination, handling_termination, terminating_signal
from .workers import capped_jobs

app = typer.Typer(add_completion=False, no_args_is_help=True, pretty_exceptions_enable=False, rich_markup_mode=None,
                  help="Anatomy-based facial expression animation: simulate a muscle-driven face and render it offscreen.")
mesh_app = typer.Typer(no_args_is_help=True, help="Face meshes: build one from a photo, check one.")
app.add_typer(mesh_app, name="mesh")
face_app = typer.Typer(no_args_is_help=True, help="Your own face on a full head: fit ICT's head to a photo.")
app.add_typer(face_app, name="face")


def notice(message: str) -> None:
    typer.echo(f"facesim: {message}", err=True)


def fail(message: str, code: int) -> None:
    typer.echo(f"facesim: error: {message}", err=True)
    raise typer.Exit(code)


def handled(command):
    """Turn facesim's errors and Ctrl-C into one line and an exit code."""

    @functools.wraps(command)
    def wrapper(*args, **kwargs):
        with handling_termination():
            try:
                return command(*args, **kwargs)
            except KeyboardInterrupt:
                fail("interrupted; nothing was written", 130)
            except BaseException as exc:
                # any error after a signal is the signal's: ctypes, for one, turns the
                # signal's exception into an ArgumentError when it lands while arguments convert
                signum = exc.signum if isinstance(exc, Terminated) else terminating_signal()
                if signum == signal.SIGINT:
                    fail("interrupted; nothing was written", 130)
                if signum is not None:
                    fail(f"stopped by {signal.Signals(signum).name}; nothing was written", 128 + signum)
                if isinstance(exc, FacesimError):
                    fail(str(exc), exc.exit_code)
                raise

    return wrapper


def settings_from(size: str, camera: str, wireframe: bool = False, show_muscles: bool = False, antialias: bool = True,
                  framing: str = "face", look: str = "auto", onto: Path | None = None, supersample: bool = False):
    from .renderer.settings import RenderSettings, parse_size
    width, height = parse_size(size)
    return RenderSettings(width, height, camera, wireframe, show_muscles, antialias, framing, look, onto, supersample)


def positive(value: Optional[int], name: str) -> None:
    if value is not None and value < 1:
        raise InputError(f"{name}: must be at least 1, got {value}")


#: The order of the thesis's figure 3.12 (and 3.13), used by the sheet.
THESIS_ORDER = ("angry", "disgust", "fear", "happy", "sad", "surprise", "disgusted_anger", "happy_surprise")

SIZE = typer.Option("512x512", "--size", help="frame size WxH")
CAMERA = typer.Option("front", "--camera", help="front, three-quarter or profile")
FRAMING = typer.Option("face", "--framing", help="a head's frame: face (brow to chin) or head (head and shoulders)")
BACKEND = typer.Option("auto", "--backend", help="OpenGL platform: auto (EGL, then OSMesa), egl or osmesa")
ANTIALIAS = typer.Option(True, "--antialias/--no-antialias", help="smooth the frame's edges (an FXAA-style filter; off: "
                         "a few ms faster a frame)")
SUPERSAMPLE_OPTION = typer.Option(False, "--supersample", help="antialias by 4 samples per pixel instead of the edge "
                                  "filter: finer shading, about twice the time a frame")
FORCE = typer.Option(False, "--force", help="overwrite an existing output")
MESH = typer.Option(None, "--mesh", help="face mesh to use instead of the spec's")
MUSCLES = typer.Option(None, "--muscles", help="muscle file to use instead of the spec's")
IDENTITY = typer.Option(None, "--identity", help="the head's identity instead of the spec's: a seed for the "
                        "weights of ICT's 100 identity modes (standard normal)")
FACE = typer.Option(None, "--face", help="a face directory (facesim face from-photo): your head, its muscles and texture")
SCHEDULER = typer.Option(None, "--scheduler", help="tcp://HOST:PORT of a Dask scheduler")
SCHEDULER_TIMEOUT_OPTION = typer.Option(SCHEDULER_TIMEOUT, "--scheduler-timeout", help="seconds to wait for --scheduler to answer")
LOOK = typer.Option("auto", "--look", help="photo (a face directory's baked photo, unlit), clay (facesim's materials, "
                    "lit), or auto: photo for a head with a face directory")


def identity_seed(identity: Optional[int]) -> Optional[int]:
    if identity is not None and identity < 0:
        raise InputError(f"--identity: expected a non-negative seed, got {identity}")
    return identity


@app.command()
@handled
def render(
    spec: Optional[Path] = typer.Argument(None, help="expression spec (YAML); optional with --blend"),
    output: Optional[str] = typer.Option(None, "-o", "--output", help="out.mp4, out.gif, out.npz, out.png (one frame), "
                                         "a directory of PNGs (DIR/, or an existing directory; default out/<name>.mp4), "
                                         "out.glb (the rig and its clip: docs/export.md), out.csv (ARKit curves, "
                                         "Live Link Face's layout) or out.pc2 (a point cache, out.obj beside it)"),
    frame: Optional[int] = typer.Option(None, "--frame", help="with -o x.png: the frame to write (default: the apex)"),
    size: Optional[str] = typer.Option(None, "--size", help="frame size WxH (default 512x512; with --onto, the photo's)"),
    fps: Optional[float] = typer.Option(None, "--fps", help="playback rate (default: the spec's, 25)"),
    camera: str = CAMERA,
    framing: str = FRAMING,
    backend: str = BACKEND,
    wireframe: bool = typer.Option(False, "--wireframe", help="draw the mesh as wireframe"),
    show_muscles: bool = typer.Option(False, "--show-muscles", help="draw muscle forces as red arrows"),
    antialias: bool = ANTIALIAS,
    supersample: bool = SUPERSAMPLE_OPTION,
    force: bool = FORCE,
    jobs: int = typer.Option(1, "--jobs", help="render frames in this many processes"),
    mesh: Optional[Path] = MESH,
    muscles: Optional[Path] = MUSCLES,
    identity: Optional[int] = IDENTITY,
    face: Optional[Path] = FACE,
    look: str = LOOK,
    onto: Optional[Path] = typer.Option(None, "--onto", help="render through the face's fitted camera into this photo "
                                        "(the one it was fitted to), at its size: the photo comes alive"),
    blend: Optional[str] = typer.Option(None, "--blend", help="blend expressions, e.g. happy=0.6,surprise=0.4"),
    timings: bool = typer.Option(False, "--timings", help="say where the time went: imports, kernels (loaded or "
                                 "compiled), model, figure, GL context, simulation, drawing, encoding"),
):
    """Simulate one expression spec (or a blend of expressions) and render it."""
    from . import timings as phases
    from .animation.spec import blend_spec, load_spec

    if timings:
        phases.start()

    positive(jobs, "--jobs")
    jobs = capped_jobs(jobs, notice)
    if fps is not None and not 0 < fps <= 240:
        raise InputError(f"--fps: must be between 0 and 240, got {fps}")
    if spec is None and blend is None:
        raise InputError("render: give a SPEC file, --blend, or both")
    loaded = load_spec(spec) if spec else blend_spec(blend)
    if spec and blend:
        loaded = loaded.with_overrides(include=loaded.include + blend_spec(blend).include)
    loaded = loaded.with_overrides(mesh=mesh, muscles=muscles, identity=identity_seed(identity), face=face)
    _render(loaded, output, frame, size, fps, camera, framing, backend, wireframe, show_muscles, antialias, supersample,
            force, jobs, look, onto, timings)


def _render(loaded, output, frame, size, fps, camera, framing, backend, wireframe, show_muscles, antialias, supersample,
            force, jobs, look, onto, timings):
    """`facesim render` and `facesim say` once the spec is loaded: the output checked,
    the spec simulated and written."""
    from . import timings as phases
    from .animation.simulate import simulate
    from .export.output import EXPORTS, check_output, drawn_in_order, progress_bar, write_animation
    from .physics.run import compiled_here

    if fps is not None and loaded.speech is not None and abs(fps - loaded.fps) > 1e-9:
        raise InputError(f"--fps {fps:g}: {loaded.source} speaks, in real time at its own {loaded.fps:g} fps; "
                         "set fps in the spec")
    if onto is not None and size is not None:
        raise InputError(f"--size: not with --onto, whose frames take the photo's size; got --size {size}")
    settings = settings_from(size or "512x512", camera, wireframe, show_muscles, antialias, framing, look, onto,
                             supersample)
    settings.for_face(loaded.face_directory)  # before any work: the photo look and --onto need a face
    if onto is not None:  # the frames take the photo's size, and the photo is checked against the face
        from dataclasses import replace

        from .face.own_face import ONTO_LIMIT, onto_photo

        height, width = onto_photo(loaded.face_directory, onto)[0].shape[:2]
        if max(width, height) == ONTO_LIMIT:
            from PIL import Image

            with Image.open(onto) as photo:
                if max(photo.size) > ONTO_LIMIT:
                    notice(f"--onto: {onto} is {photo.size[0]}x{photo.size[1]}; drawn at {width}x{height} (frames "
                           f"are at most {ONTO_LIMIT} pixels on their longer side)")
        settings = replace(settings, width=width, height=height)
    output = output or str(Path("out") / f"{loaded.title}.mp4")
    kind = check_output(output, force, settings)
    if loaded.speech is not None and kind not in ("mp4", "npz"):
        notice(f"{output}: carries no sound (an MP4 or an NPZ carries the words' sound)")
    if frame is not None and (kind != "image" or not 0 <= frame < loaded.frames):
        raise InputError(f"--frame: with -o x.png, a frame from 0 to {loaded.frames - 1}, got {frame}" if kind == "image"
                         else f"--frame: only with a .png output (one frame), not {output}")
    if kind in EXPORTS:  # the rig, its curves, a point cache: nothing drawn (--frame was refused above)
        from .animation.blendshapes import check_head
        from .export.rig import write_clip

        if show_muscles or onto is not None:
            given = "--show-muscles" if show_muscles else "--onto"
            raise InputError(f"{given}: draws frames; {output} carries the face to other tools, undrawn")
        check_head(loaded)
        animation = simulate(loaded, notice=notice)
        exported = write_clip(animation, loaded, output, kind, replace=force)
        typer.echo(f"wrote {output}: {exported.summary()}", err=True)
        return
    # drawn and encoded as its frames come, from a few frames of positions where each is read once, in order
    animation = simulate(loaded, notice=notice, background=True, with_muscle_forces=show_muscles,
                         stream=drawn_in_order(kind, settings, loaded.frames, jobs))
    try:
        with progress_bar(animation.frames, f"rendering {loaded.title}") as advance:
            report = write_animation(animation, output, settings, fps, backend, jobs, advance, replace=force, frame=frame)
    finally:
        animation.cancel()  # after a failed render, the simulation stops too
    compiled = " (this run compiled the Numba kernels; later runs load them from cache)" if compiled_here() else ""
    typer.echo(f"wrote {output}: {report.frames} frames, simulation {report.simulation_seconds * 1000:.1f} ms, "
               f"render {report.render_seconds:.2f} s{compiled}", err=True)
    if timings:
        phases.add("simulation", report.simulation_seconds)
        typer.echo(phases.summary(phases.process_age()), err=True)


def _speech_options(
    blend: Optional[str] = typer.Option(None, "--blend", help="expressions held under the words, e.g. happy=0.8"),
    size: Optional[str] = typer.Option(None, "--size", help="frame size WxH (default 512x512; with --onto, the photo's)"),
    fps: float = typer.Option(25.0, "--fps", help="frames a second (the clip plays in real time)"),
    camera: str = CAMERA,
    framing: str = FRAMING,
    backend: str = BACKEND,
    antialias: bool = ANTIALIAS,
    supersample: bool = SUPERSAMPLE_OPTION,
    force: bool = FORCE,
    mesh: Optional[Path] = MESH,
    muscles: Optional[Path] = MUSCLES,
    identity: Optional[int] = IDENTITY,
    face: Optional[Path] = FACE,
    look: str = LOOK,
    onto: Optional[Path] = typer.Option(None, "--onto", help="render through the face's fitted camera into this photo"),
    timings: bool = typer.Option(False, "--timings", help="say where the time went"),
):
    """The options `say` and `speak` share (``with_speech_options``)."""


def with_speech_options(command):
    """``command`` (whose last parameter, ``options``, takes them as a dict) with the
    options of ``_speech_options`` after its own, as typer reads a command's signature."""
    import inspect

    shared = inspect.signature(_speech_options).parameters
    own = [p for name, p in inspect.signature(command).parameters.items() if name != "options"]

    @functools.wraps(command)
    def wrapper(**given):
        return command(**{k: v for k, v in given.items() if k not in shared},
                       options={k: v for k, v in given.items() if k in shared})

    wrapper.__signature__ = inspect.Signature(own + list(shared.values()))
    wrapper.__annotations__ = {**{k: v for k, v in command.__annotations__.items() if k != "options"},
                               **_speech_options.__annotations__}
    return wrapper


@app.command()
@handled
@with_speech_options
def say(
    text: str = typer.Argument(..., help="the words to say"),
    output: Optional[str] = typer.Option(None, "-o", "--output", help="out.mp4 (with the sound), out.gif, out.npz, "
                                         "a directory of PNGs, out.glb, out.csv or out.pc2, as `render` takes"),
    voice: str = typer.Option("en", "--voice", help="eSpeak NG's voice or language (en, en-us, de, fr, ...)"),
    rate: int = typer.Option(175, "--rate", help="words a minute (80-450)"),
    options: dict = None,
):
    """Say TEXT: eSpeak NG speaks it, its phonemes become visemes, the face's muscles and
    jaw say them, and the MP4 carries the sound (docs/speech.md)."""
    _speak(dict(text=text, voice=voice, rate=rate), text, output, **options)


@app.command()
@handled
@with_speech_options
def speak(
    recording: Path = typer.Argument(..., help="a recording of the words (WAV, MP3, FLAC, ...: any rate and channels)"),
    text: Optional[str] = typer.Option(None, "--text", help="the words said in it (required: they are aligned to it)"),
    output: Optional[str] = typer.Option(None, "-o", "--output", help="out.mp4 (with the recording's sound), out.gif, "
                                         "out.npz, a directory of PNGs, out.glb, out.csv or out.pc2"),
    force_long: bool = typer.Option(False, "--force-long", help="align a recording longer than two minutes"),
    options: dict = None,
):
    """Speak a RECORDING: its words (--text) aligned to it by PocketSphinx, their phonemes
    as visemes, the face saying them, and the recording's own sound in the MP4."""
    if text is None:
        raise InputError("speak: --text: the words said in the recording (facesim aligns them to it)")
    _speak(dict(text=text, audio=recording.resolve(), long=force_long), recording.stem, output, **options)


def _speak(speech: dict, title: str, output, blend, size, fps, camera, framing, backend, antialias, supersample, force,
           mesh, muscles, identity, face, look, onto, timings):
    """`say` and `speak`: a spec of the words (``speech``) with the expressions of
    ``blend`` under them, rendered as `render` renders a spec."""
    from pydantic import ValidationError

    from . import timings as phases
    from .animation.spec import Spec, blend_spec
    from .schema import describe

    if timings:
        phases.start()
    if not 0 < fps <= 240:
        raise InputError(f"--fps: must be between 0 and 240, got {fps}")
    include = [] if blend is None else [i.model_dump() for i in blend_spec(blend).include]
    command = "speak" if "audio" in speech else "say"
    words = "_".join("".join(c for c in w if c.isalnum()) for w in title.split()[:4]).strip("_").lower() or "speech"
    try:
        loaded = Spec.model_validate(dict(name=words if command == "speak" else f"say_{words}", fps=fps, onset=0,
                                          include=include, speech=speech))
    except ValidationError as exc:
        raise InputError(f"{command}: "
                         f"{describe(exc).replace('speech: Value error, ', '', 1).replace('speech -> ', '', 1)}") from None
    loaded = loaded.with_overrides(mesh=mesh, muscles=muscles, identity=identity_seed(identity), face=face)
    _render(loaded, output, None, size, None, camera, framing, backend, False, False, antialias, supersample, force, 1,
            look, onto, timings)


@app.command()
@handled
def batch(
    inputs: list[Path] = typer.Argument(..., help="spec files or directories of specs"),
    outdir: Path = typer.Option(..., "-o", "--output", help="directory for the outputs"),
    jobs: int = typer.Option(2, "--jobs", help="specs rendered at once, each in its own process"),
    fmt: str = typer.Option("mp4", "--format", help="mp4, gif, npz or png (a directory per spec)"),
    size: str = SIZE,
    camera: str = CAMERA,
    framing: str = FRAMING,
    backend: str = BACKEND,
    antialias: bool = ANTIALIAS,
    force: bool = FORCE,
    mesh: Optional[Path] = MESH,
    muscles: Optional[Path] = MUSCLES,
    identity: Optional[int] = IDENTITY,
    face: Optional[Path] = FACE,
    look: str = LOOK,
    executor: str = typer.Option("local", "--executor", help="local (processes) or dask"),
    scheduler: Optional[str] = SCHEDULER,
    scheduler_timeout: float = SCHEDULER_TIMEOUT_OPTION,
):
    """Render many specs in parallel; a failing spec does not stop the others."""
    from rich.console import Console
    from rich.table import Table

    from .batch import collect_specs, run_batch
    from .export.output import progress_bar

    positive(jobs, "--jobs")
    if scheduler is None:
        jobs = capped_jobs(jobs, notice)
    if executor not in ("local", "dask"):
        raise InputError(f"--executor: expected local or dask, got {executor!r}")
    suffix = {"mp4": ".mp4", "gif": ".gif", "npz": ".npz", "png": ""}.get(fmt)
    if suffix is None:
        raise InputError(f"--format: expected mp4, gif, npz or png, got {fmt!r}")
    settings = settings_from(size, camera, antialias=antialias, framing=framing, look=look)
    if face is not None:
        from .face.own_face import load_face_directory

        face = load_face_directory(face).path  # checked once, before any spec
    specs = collect_specs(inputs)
    if outdir.exists() and not outdir.is_dir():
        raise InputError(f"{outdir}: is not a directory")
    with progress_bar(len(specs), "batch") as advance:
        results = run_batch(specs, outdir, suffix, settings, backend, jobs, force, mesh, muscles, identity_seed(identity), face,
                            on_done=(lambda _: advance()) if advance else None, executor=executor, scheduler=scheduler,
                            scheduler_timeout=scheduler_timeout)
    table = Table(title=f"facesim batch: {len(specs)} specs")
    for column in ("spec", "muscles", "frames", "simulation (ms)", "render (s)", "fps", "output"):
        table.add_column(column, justify="left" if column in ("spec", "output") else "right")
    for r in results:
        if r.report:
            p = r.report
            table.add_row(r.spec.stem, str(p.muscles), str(p.frames), f"{p.simulation_seconds * 1000:.1f}",
                          f"{p.render_seconds:.2f}", f"{p.fps:.1f}", str(p.output))
        else:
            table.add_row(r.spec.stem, "", "", "", "", "", "FAILED")
    Console(stderr=False, width=140).print(table)
    failed = [r for r in results if r.error]
    for r in failed:
        typer.echo(f"facesim: error: {r.error}", err=True)
    if failed:
        raise typer.Exit(1)


@app.command()
@handled
def validate(specs: list[Path] = typer.Argument(..., help="spec files")):
    """Check specs (schema, muscles, mesh) without simulating."""
    from .animation.simulate import model_for
    from .animation.spec import activation_table, load_spec

    bad = 0
    for path in specs:
        try:
            spec = load_spec(path)
            model = model_for(spec)
            activation_table(spec, model.muscles)
            typer.echo(f"ok: {path} ({len(spec.activations)} muscles, {spec.frames} frames, dt {spec.dt})")
        except FacesimError as exc:
            typer.echo(f"facesim: error: {exc}", err=True)
            bad += 1
    if bad:
        raise typer.Exit(2)


@app.command()
@handled
def info(mesh: Optional[Path] = MESH, muscles: Optional[Path] = MUSCLES):
    """The face mesh, its muscles, and which OpenGL backends work here."""
    from .config import DEFAULT_MESH, muscles_file
    from .face.loading import load_face
    from .face.muscle_file import load_muscles
    from .physics.muscles import SPHINCTER
    from .renderer.settings import BACKENDS
    mesh_path = mesh or DEFAULT_MESH
    muscles = muscles_file(muscles)
    face = load_face(mesh_path)
    muscle_set = load_muscles(muscles, face)
    cx, cz, radius = face.vertical_axis
    typer.echo(f"mesh: {mesh_path}: {face.vertex_count} vertices, {len(face.faces)} triangles, "
               f"boundary loops {[len(l) for l in face.boundary_loops]}, size {face.scale:.1f} cm")
    typer.echo(f"projection (eq. 3.21): vertical axis at x={cx:.2f}, z={cz:.2f} cm, radius {radius:.2f} cm")
    sphincters = int((muscle_set.kind == SPHINCTER).sum())
    typer.echo(f"muscles: {muscles}: {muscle_set.count} muscles ({muscle_set.count - sphincters} linear, "
               f"{sphincters} sphincter), {len(muscle_set.pinned)} pinned vertices, "
               f"controls: {', '.join(muscle_set.controls) or 'none'}")
    for backend in BACKENDS:
        result = subprocess.run([sys.executable, "-c", f"from facesim.renderer.scene import probe; print(probe({backend!r}))"],
                                capture_output=True, text=True, timeout=120)
        status = result.stdout.strip().splitlines()[-1] if result.stdout.strip() else f"fails: {result.stderr.strip()[-200:]}"
        typer.echo(f"backend {backend}: {status}")


@app.command("muscles")
@handled
def muscles_command(
    plot: Optional[Path] = typer.Option(None, "--plot", help="draw the muscle map to this PNG"),
    mesh: Optional[Path] = MESH,
    muscles: Optional[Path] = MUSCLES,
):
    """List the muscles of a face (and draw them)."""
    import numpy as np
    from rich.console import Console
    from rich.table import Table

    from .config import DEFAULT_MESH, muscles_file
    from .export.plots import plot_muscles
    from .face.loading import load_face
    from .face.material import face_model
    from .face.muscle_file import load_muscles
    from .physics.model import muscle_regions
    from .physics.muscles import SPHINCTER
    mesh = mesh or DEFAULT_MESH
    face = load_face(mesh)
    model = face_model(face, load_muscles(muscles_file(muscles), face))
    regions = muscle_regions(model)
    m = model.muscles
    table = Table(title=f"{model.muscle_count} muscles; controls: {', '.join(m.controls) or 'none'}")
    for column in ("name", "kind", "attachment / centre", "insertion / ring", "zone (deg)", "falloff", "force", "region"):
        table.add_column(column)
    for k, name in enumerate(m.names[:m.count]):
        centre = m.centre_index[m.centre_start[k]:m.centre_start[k + 1]]
        if m.kind[k] == SPHINCTER:
            ends = ("sphincter", "+".join(map(str, centre)), f"{len(m.ring[k])} points", "-")
        else:
            ends = ("linear", str(m.attachment[k]), str(m.insertion[k]), f"{np.degrees(m.zone[k]):.0f}")
        table.add_row(name, *ends, f"{m.falloff[k, 0]:g}-{m.falloff[k, 1]:g}", f"{m.force[k]:g}", f"{len(regions[k])} vertices")
    Console(width=140).print(table)
    if plot:
        plot_muscles(model, regions, plot)
        typer.echo(f"wrote {plot}", err=True)


@app.command()
@handled
def rig(
    output: Path = typer.Option(..., "-o", "--output", help="the rig, a glTF binary: head.glb"),
    identity: Optional[int] = IDENTITY,
    face: Optional[Path] = FACE,
    force: bool = FORCE,
):
    """Write the head as a glTF rig for Blender, three.js, Unity and Unreal: ARKit's 52
    morph targets, each baked by facesim's physics, and a skeleton (neck, head, jaw, eyes);
    docs/export.md."""
    from .animation.spec import Spec
    from .export.output import output_kind
    from .export.rig import write_rig
    from .files import check_destination

    if output_kind(output) != "glb":
        raise InputError(f"{output}: a rig is written as a glTF binary: name it NAME.glb")
    check_destination(output, force)
    spec = Spec(name="head").with_overrides(identity=identity_seed(identity), face=face)
    exported = write_rig(spec, output, replace=force)
    typer.echo(f"wrote {output}: {exported.summary()}", err=True)


@app.command()
@handled
def shapes(
    mesh: Optional[Path] = MESH,
    muscles: Optional[Path] = MUSCLES,
):
    """List the shapes a spec's arkit: takes (ARKit's 52, ICT FaceKit's spellings) and the
    action units, with the muscles and controls that drive each on this face."""
    from rich.console import Console
    from rich.table import Table

    from .animation.arkit import ARKIT_52, ICT_ALIASES, shape_facs
    from .animation.timeline import ACTION_UNITS, ONE_SIDED, au_muscles
    from .config import DEFAULT_MESH, muscles_file
    from .face.loading import load_face
    from .face.muscle_file import load_muscles
    from .physics.muscles import JAW_CONTROLS, PUPIL, TONGUE

    mesh = mesh or DEFAULT_MESH
    names = load_muscles(muscles_file(muscles), load_face(mesh)).names

    def drives(unit: str) -> str:
        if unit in names:  # a control FACS has no unit for
            return ("the control: the pupil's radius, drawn by the renderer" if unit.startswith(PUPIL) else
                    "the control: the jaw's rig (the mandible, the lips, the mouth's air)" if unit in JAW_CONTROLS else
                    "the control: the tongue's rig, drawn by the renderer" if unit in TONGUE else
                    "the control")
        try:
            return ", ".join(f"{m} {w:g}" if w != 1 else m for m, w in au_muscles(unit, names).items())
        except ValueError as exc:
            return f"not on this face: {exc}"

    aliases: dict[str, list[str]] = {}
    for ict, target in ICT_ALIASES.items():
        aliases.setdefault(target, []).append(ict)
    table = Table(title=f"ARKit's 52 shapes on {mesh.name} (a spec's arkit:, 0-1; ICT's spellings are aliases)")
    for column in ("ARKit", "ICT", "FACS", "drives"):
        table.add_column(column)
    extra = [name for name in aliases if name not in ARKIT_52]
    for name in [*ARKIT_52, *extra]:
        ict = ", ".join(n for n in aliases.get(name, []) if n != name) or ("" if name not in ICT_ALIASES else name)
        unit = shape_facs(name)
        table.add_row(name if name in ARKIT_52 else "", ict or (name if name not in ARKIT_52 else ""), unit, drives(unit))
    units = Table(title="FACS action units (a spec's aus:, A-E or 0-1; _L or _R for one side)")
    for column in ("AU", "name", "drives"):
        units.add_column(column)
    for unit, (name, _) in ACTION_UNITS.items():
        units.add_row(unit + (" (_L/_R)" if unit in ONE_SIDED else ""), name,
                      drives(f"{unit}_L" if unit in ONE_SIDED else unit) + (" (the _L form)" if unit in ONE_SIDED else ""))
    console = Console(width=160)
    console.print(table)
    console.print(units)


@app.command()
@handled
def sheet(
    inputs: list[Path] = typer.Argument(..., help="expression specs or directories of them"),
    output: Path = typer.Option(..., "-o", "--output", help="PNG to write"),
    size: str = typer.Option("384x384", "--size", help="size of each face"),
    framing: str = FRAMING,
    backend: str = BACKEND,
    force: bool = FORCE,
    columns: int = typer.Option(3, "--columns"),
    mesh: Optional[Path] = MESH,
    muscles: Optional[Path] = MUSCLES,
    identity: Optional[int] = IDENTITY,
    face: Optional[Path] = FACE,
    look: str = LOOK,
):
    """Every expression at its apex in a labelled grid, the neutral face first: the last
    frame of an expression that eases in and holds, the strongest of a sequence. An
    expression that fails to simulate gets an empty cell saying where, and exit code 1."""
    from .animation.simulate import simulate
    from .animation.spec import load_spec
    from .batch import collect_specs
    from .errors import SimulationError
    from .export.plots import contact_sheet
    from .renderer.scene import FaceRenderer
    from .renderer.settings import BACKGROUND

    positive(columns, "--columns")
    if output.suffix.lower() != ".png":
        raise InputError(f"{output}: the sheet is a .png")
    check_destination(output, force)
    order = {name: k for k, name in enumerate(THESIS_ORDER)}
    overrides = dict(mesh=mesh, muscles=muscles, identity=identity_seed(identity), face=face)
    specs = sorted((load_spec(p).with_overrides(**overrides) for p in collect_specs(inputs)),
                   key=lambda s: (order.get(s.title, len(order)), s.title))
    results, failures = [], []
    for spec in specs:
        try:
            results.append((spec.title, simulate(spec)))
        except SimulationError as exc:
            results.append((f"{spec.title} (fails at frame {exc.frame})", None))
            failures.append(str(exc))
    done = [a for _, a in results if a is not None]
    if not done:
        raise SimulationError(failures[0])
    first = done[0]
    settings = settings_from(size, "front", framing=framing, look=look)
    blank = np.full((settings.height, settings.width, 3), np.array(BACKGROUND[:3]) * 255, dtype=np.uint8)
    images, labels = [], ["neutral"]
    with FaceRenderer.of(first, settings, backend) as renderer:
        images.append(renderer.render(first.rest))
        for title, a in results:
            labels.append(title.replace("_", " "))
            if a is None:
                images.append(blank)
                continue
            same_face = (a.rest.shape == first.rest.shape and (a.rest == first.rest).all() and a.figure is first.figure
                         and a.face is first.face)
            if same_face:
                images.append(renderer.frame(a, a.apex_frame))
            else:
                with FaceRenderer.of(a, settings, backend) as own:
                    images.append(own.frame(a, a.apex_frame))
    contact_sheet(images, labels, output, columns, replace=force)
    typer.echo(f"wrote {output}: {len(images)} faces", err=True)
    for failure in failures:
        typer.echo(failure, err=True)
    if failures:
        raise typer.Exit(1)


@app.command()
@handled
def dataset(
    output: Path = typer.Option(..., "-o", "--output", help="dataset directory (a rerun finishes it)"),
    n: int = typer.Option(..., "--n", help="number of samples"),
    seed: int = typer.Option(0, "--seed", help="the same seed gives the same dataset on any executor"),
    executor: str = typer.Option("local", "--executor", help="local (processes) or dask"),
    scheduler: Optional[str] = SCHEDULER,
    scheduler_timeout: float = SCHEDULER_TIMEOUT_OPTION,
    jobs: int = typer.Option(2, "--jobs", help="worker processes (local, or the Dask LocalCluster)"),
    size: str = typer.Option("256x256", "--size", help="image size WxH"),
    jitter: bool = typer.Option(False, "--jitter", help="vary the camera and the lights per sample"),
    clip: bool = typer.Option(False, "--clip", help="also write each sample's 20 frames as an MP4 clip"),
    backend: str = BACKEND,
    face: Optional[Path] = typer.Option(None, "--face", help="a face directory (facesim face from-photo): every sample "
                                        "is that person, instead of ICT's generic head (or, with --jitter, a new person each)"),
    look: str = LOOK,
    sheet_png: Optional[Path] = typer.Option(None, "--sheet", help="also draw the first 12 samples to this PNG"),
):
    """Render N labelled expressions (PNG + labels + manifest) for training recognisers."""
    from .dataset import DatasetSettings, build_dataset, dataset_sheet
    from .export.output import progress_bar
    from .renderer.settings import parse_size
    width, height = parse_size(size)
    if face is not None:
        from .face.own_face import load_face_directory

        face = load_face_directory(face).path
    settings = DatasetSettings(seed, width, height, jitter, backend, clip, None if face is None else str(face), look)
    with progress_bar(max(n, 0), "dataset") as advance:
        manifest = build_dataset(output, n, settings, executor, jobs, scheduler, advance, warn=notice,
                                 scheduler_timeout=scheduler_timeout)
    typer.echo(f"wrote {manifest} ({n} samples)", err=True)
    if sheet_png:
        dataset_sheet(output, sheet_png)
        typer.echo(f"wrote {sheet_png}", err=True)


@mesh_app.command("info")
@handled
def mesh_info(mesh: Path = typer.Argument(..., help="a mesh file (OBJ, PLY, GLB, ...)")):
    """Vertices, triangles, openings, scale and orientation of a mesh, which muscle file
    fits it, and what is wrong with it. Exit code 1 when something is."""
    from .config import DEFAULT_MUSCLES, HOPPER_MESH
    from .face.loading import diagnose, load_mesh
    face = load_mesh(mesh)
    default = load_mesh(HOPPER_MESH)
    v = face.vertices
    typer.echo(f"{mesh}: {face.vertex_count} vertices, {len(face.faces)} triangles, "
               f"{face.connected_components()} piece(s)")
    typer.echo(f"boundary loops: {[len(loop) for loop in face.boundary_loops] or 'none'}")
    extent = np.ptp(v, axis=0)
    typer.echo(f"size: {extent[0]:.2f} x {extent[1]:.2f} x {extent[2]:.2f} (x, y, z)")
    same_topology = face.vertex_count == default.vertex_count and np.array_equal(face.edges, default.edges)
    typer.echo("muscles: " + (f"{DEFAULT_MUSCLES} fits by landmark index (MediaPipe topology)" if same_topology else
                              "another topology: name landmarks (`facesim mesh landmarks`), then `facesim mesh align` "
                              "writes it in the face frame with the muscles carried by position"))
    problems = diagnose(face)
    for problem in problems:
        typer.echo(f"problem: {problem}")
    if problems:
        raise typer.Exit(1)
    typer.echo("ok: usable as a facesim face")


@mesh_app.command("landmarks")
@handled
def mesh_landmarks(
    mesh: Path = typer.Argument(..., help="a mesh roughly upright (+y) and facing +z, in any units"),
    output: Optional[Path] = typer.Option(None, "-o", "--output", help="write the proposal as YAML to edit"),
    force: bool = FORCE,
):
    """Propose the named landmarks of a mesh of another topology by nearest vertex, for
    `facesim mesh align`. Check them: a wrong one skews the alignment."""
    import yaml
    from rich.console import Console
    from rich.table import Table

    from .config import HOPPER_MESH
    from .face.align import propose_landmarks
    from .face.loading import load_mesh
    from .files import atomic_path

    if output:
        check_destination(output, force)
    proposal = propose_landmarks(load_mesh(mesh), load_mesh(HOPPER_MESH))
    table = Table(title=f"landmarks of {mesh} (distance after matching bounding boxes, cm of the Hopper face)")
    for column in ("landmark", "vertex", "distance"):
        table.add_column(column)
    for name, (vertex, distance) in proposal.items():
        table.add_row(name, str(vertex), f"{distance:.2f}")
    Console(width=100).print(table)
    if output:
        with atomic_path(output, replace=force) as tmp:
            tmp.write_text(yaml.safe_dump({name: vertex for name, (vertex, _) in proposal.items()}, sort_keys=False))
        typer.echo(f"wrote {output}", err=True)


@mesh_app.command("align")
@handled
def mesh_align(
    mesh: Path = typer.Argument(..., help="a mesh file of any topology (OBJ, PLY, GLB, ...)"),
    landmarks: Path = typer.Option(..., "--landmarks", help="YAML: landmark name -> vertex index or [x, y, z]"),
    output: Path = typer.Option(..., "-o", "--output", help="OBJ to write, in the Hopper face's frame (cm)"),
    muscles_out: Optional[Path] = typer.Option(None, "--muscles-out", help="muscle file to write (default: OUTPUT with .muscles.yaml)"),
    muscles: Optional[Path] = typer.Option(None, "--muscles", help="the muscle file to carry, by MediaPipe landmark "
                                           "index (default: the head's calibrated one; `thesis`: the thesis's)"),
    force: bool = FORCE,
):
    """Move, turn and scale a mesh onto the Hopper face (meshes/face.obj) by named landmarks
    (a similarity fit) and write it with the head's calibrated muscles carried to it by position."""
    from .config import HOPPER_MESH, muscles_file
    from .face.align import align, load_landmarks
    from .face.loading import check_face, load_mesh, obj_text
    from .face.muscle_file import carried_text, load_muscles
    from .files import atomic_path

    muscles_out = muscles_out or output.with_suffix("").with_suffix(".muscles.yaml")
    for path in (output, muscles_out):
        check_destination(path, force)
    face = load_mesh(mesh)
    default = load_mesh(HOPPER_MESH)
    aligned, residual = align(face, load_landmarks(landmarks, face), default)
    source = muscles_file(muscles)
    carried = carried_text(source, default)
    # both files written under temporary names and checked together; renamed only if every muscle snaps
    with atomic_path(output, replace=force) as obj_tmp, atomic_path(muscles_out, replace=force) as muscles_tmp:
        obj_tmp.write_text(obj_text(aligned, header=f"{mesh} aligned to the Hopper face by {landmarks}"))
        muscles_tmp.write_text(f"# {source.name} carried by position from the Hopper face to {output.name}.\n" + carried)
        resolved = load_muscles(muscles_tmp, check_face(load_mesh(obj_tmp), output), source=str(muscles_out))
    typer.echo(f"wrote {output} and {muscles_out}: {resolved.count} muscles; landmark residuals "
               f"median {np.median(residual):.2f} cm, largest {residual.max():.2f} cm", err=True)


@app.command()
@handled
def capture(
    video: Path = typer.Argument(..., help="a face video (any format ffmpeg reads) or a directory of frames"),
    output: Path = typer.Option(..., "-o", "--output", help="the performance to write: a spec (.yaml)"),
    fps: Optional[float] = typer.Option(None, "--fps", help="frames per second (a video's own unless given; "
                                        "a directory of frames: 25)"),
    curves: Optional[Path] = typer.Option(None, "--curves", help="also write ARKit's 52 curves and the head's and "
                                          "eyes' rotations, in Live Link Face's CSV layout"),
    plot: Optional[Path] = typer.Option(None, "--plot", help="also draw the main curves over time (.png)"),
    neutral: float = typer.Option(0.0, "--neutral", help="the time (s) from which the face is at rest and facing "
                                  "the camera for 0.3 s: expressions and turns are measured from it (default: the start)"),
    force: bool = FORCE,
):
    """Capture a performance from a face video: MediaPipe's landmarks per frame, the
    head's pose, the eyes' gaze and ARKit's shapes solved against facesim's own, written
    as a spec that `facesim render` replays on any face. Needs facesim[photo]."""
    from .capture.performance import capture as captured
    from .capture.tracking import open_source
    from .export.output import progress_bar

    if fps is not None and not 0 < fps <= 240:
        raise InputError(f"--fps: expected frames per second between 0 and 240, got {fps:g}")
    outputs = [(output, "-o", (".yaml", ".yml")), (curves, "--curves", (".csv",)), (plot, "--plot", (".png",))]
    for path, option, suffixes in outputs:
        if path is not None and path.suffix.lower() not in suffixes:
            raise InputError(f"{option}: {path}: expected a {' or '.join(suffixes)} file")
    given = [p.resolve() for p, _, _ in outputs if p is not None]
    if len(set(given)) < len(given):
        raise InputError("-o, --curves and --plot must name different files")
    for path, _, _ in outputs:
        if path is not None:
            check_destination(path, force)
    source = open_source(video, fps)
    if not 0 <= neutral < source.frames / source.fps:
        raise InputError(f"--neutral: expected a time within {video} (0-{source.frames / source.fps:.1f} s), got {neutral:g}")
    with progress_bar(3 * source.frames, f"capturing {video.name}") as advance:
        performance = captured(source, output, curves, plot, replace=force, notice=notice, progress=advance,
                               neutral_at=neutral)
    moving = int((performance.weights.max(axis=0) >= 0.03).sum())
    written = ", ".join(str(p) for p in (output, curves, plot) if p is not None)
    typer.echo(f"wrote {written}: {performance.frames} frames at {performance.fps:g} fps, {moving} shapes that move, "
               f"head turned {np.abs(performance.head[:, 0]).max():.0f} degrees at most", err=True)


@mesh_app.command("from-photo")
@handled
def mesh_from_photo_command(
    photo: Path = typer.Argument(..., help="a portrait photo (JPEG, PNG)"),
    output: Path = typer.Option(..., "-o", "--output", help="OBJ to write"),
    symmetrise: bool = typer.Option(True, "--symmetrise/--no-symmetrise", help="average with the mirror image"),
    force: bool = FORCE,
):
    """Build a face mesh (MediaPipe topology, cm) from one photo. Needs facesim[photo]."""
    from .face.photo import mesh_from_photo

    check_destination(output, force)
    built = mesh_from_photo(photo, output, symmetric=symmetrise, replace=force)
    typer.echo(f"wrote {output}: {built.vertex_count} vertices, {len(built.faces)} triangles", err=True)


@face_app.command("from-photo")
@handled
def face_from_photo_command(
    photo: Path = typer.Argument(..., help="a portrait photo (JPEG, PNG), the face at least 100 pixels across"),
    output: Path = typer.Option(..., "-o", "--output", help="directory to write: head.obj/.mtl/.png, face.yaml, muscles.yaml"),
    force: bool = FORCE,
):
    """Fit the head (ICT's identity modes) and a camera to a photo's face and bake the
    photo into its texture. Needs facesim[photo]."""
    from .face.own_face import face_from_photo

    check_destination(output, force, directory=True)
    record = face_from_photo(photo, output, replace=force, notice=notice)
    fit = record["landmarks"]
    typer.echo(f"wrote {output}: the head fitted to {fit['face_width_pixels']:.0f} pixels of face, landmarks within "
               f"{100 * fit['median_residual_face_widths']:.1f}% of its width (median), "
               f"{100 * fit['p90_residual_face_widths']:.1f}% (90th percentile)", err=True)


def main() -> None:
    """The ``facesim`` command (and ``python -m facesim``): ``app``, then a quick exit.

    By the time a command returns, everything it wrote is closed, verified and renamed.
    What Python's own exit would still do that matters is done here: non-daemon threads
    joined, the ``atexit`` handlers run (weakref finalizers, multiprocessing's and Dask's
    clean-ups, logging's flush), the standard streams flushed. What ``os._exit`` then
    skips is the interpreter freeing every module's objects one by one, which took 0.3 s
    of a 3 s ``facesim render`` (measured on 2026-12-02: NumPy, Numba's and LLVM's
    tables, pyrender's scene)."""
    import atexit
    import os
    import threading

    try:
        app(prog_name="facesim")
        code = 0
    except SystemExit as exc:
        code = exc.code
    if code is None:
        code = 0
    elif not isinstance(code, int):
        print(code, file=sys.stderr)
        code = 1
    for thread in threading.enumerate():
        if thread is not threading.main_thread() and not thread.daemon:
            thread.join()
    atexit._run_exitfuncs()
    for stream in (sys.stdout, sys.stderr):
        try:
            stream.flush()
        except (OSError, ValueError):  # a closed pipe: nothing more can be said there
            pass
    os._exit(code)
