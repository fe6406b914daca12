"""A video's face, frame by frame: MediaPipe Face Mesh's 468 landmarks and its two irises
(the attention model's 10 points), in pixels, streamed from any video ffmpeg reads or a
directory of frames, one frame in memory at a time.

MediaPipe runs in its video mode: it detects a face once and tracks it from frame to
frame, detecting again only when it loses it. It looks for two faces so that a second
one is noticed; the larger is followed. A frame where it detects a face (the first, or
after frames without one) is looked at again, tracked from its own landmarks: found
from the detector's box alone, the landmarks differ from the tracked ones of the frames
after it (the first frame of facesim's own round trip read the right eye 0.24 closed,
and the frames after it 0.01).
"""

from __future__ import annotations

import contextlib
from dataclasses import dataclass
from pathlib import Path
from typing import Iterator

import numpy as np

from ..errors import InputError

#: Image files a directory of frames may hold, taken in name order.
FRAME_SUFFIXES = (".png", ".jpg", ".jpeg", ".bmp", ".webp")
#: The Face Mesh's landmarks and, after them, the irises' centres and rims.
LANDMARKS, WITH_IRISES = 468, 478
#: The two iris centres (MediaPipe's 468 and 473).
IRIS_CENTRES = (468, 473)


@dataclass(frozen=True)
class Source:
    """A video or a directory of frames: its frame rate, size and (for a video, from its
    duration) about how many frames it has."""

    path: Path
    fps: float
    size: tuple[int, int]
    frames: int


def open_source(path: Path, fps: float | None) -> Source:
    """Check that ``path`` is a readable video or a directory of frames (one line
    otherwise), before anything is written."""
    if path.is_dir():
        files = frame_files(path)
        if not files:
            raise InputError(f"{path}: a directory with no frames in it (expected {', '.join(FRAME_SUFFIXES)} files)")
        from PIL import Image

        try:
            with Image.open(files[0]) as first:
                size = first.size
        except OSError as exc:
            raise InputError(f"{files[0]}: not an image ({exc})") from None
        return Source(path, fps or 25.0, size, len(files))
    if not path.is_file():
        raise InputError(f"{path}: no such video or directory of frames")
    import imageio_ffmpeg

    reader = imageio_ffmpeg.read_frames(str(path))
    try:
        meta = next(reader)
    except (OSError, RuntimeError, StopIteration) as exc:
        reason = (str(exc).strip().splitlines() or ["ffmpeg cannot read it"])[-1]
        raise InputError(f"{path}: not a video ffmpeg can read ({reason})") from None
    finally:
        reader.close()
    rate = fps or float(meta.get("fps") or 0)
    if not rate > 0:
        raise InputError(f"{path}: the video does not say its frame rate; give --fps")
    duration = float(meta.get("duration") or 0)
    return Source(path, rate, tuple(meta["size"]), max(1, int(round(duration * float(meta.get("fps") or rate)))))


def frame_files(directory: Path) -> list[Path]:
    return sorted(p for p in directory.iterdir() if p.suffix.lower() in FRAME_SUFFIXES and p.is_file())


def frames_of(source: Source) -> Iterator[np.ndarray]:
    """The source's frames, (height, width, 3) uint8 RGB, one at a time."""
    if source.path.is_dir():
        from PIL import Image, ImageOps

        for path in frame_files(source.path):
            try:
                with Image.open(path) as image:
                    yield np.asarray(ImageOps.exif_transpose(image).convert("RGB"))
            except OSError as exc:
                raise InputError(f"{path}: not an image ({exc})") from None
        return
    import imageio_ffmpeg

    reader = imageio_ffmpeg.read_frames(str(source.path))
    try:
        meta = next(reader)
        width, height = meta["size"]
        for data in reader:
            yield np.frombuffer(data, dtype=np.uint8).reshape(height, width, 3)
    except RuntimeError as exc:
        raise InputError(f"{source.path}: ffmpeg stopped reading it ({str(exc).strip().splitlines()[-1]})") from None
    finally:
        reader.close()


@dataclass
class Tracked:
    """Per frame, (478, 3) landmarks in pixels (x right, y down, z away from the camera,
    image-width units; float32: an hour at 30 fps is 620 MB) or None where no face was
    found; and whether a second face was ever seen."""

    landmarks: list[np.ndarray | None]
    several: bool = False


@contextlib.contextmanager
def face_tracker(still: bool = False):
    """A function giving the faces MediaPipe finds in a frame of a video, largest first,
    (478, 3) pixels each; ``still``: in images each looked at afresh."""
    from ..face.photo import quiet_stderr

    with quiet_stderr():
        import mediapipe as mp

        mesh = mp.solutions.face_mesh.FaceMesh(static_image_mode=still, max_num_faces=2, refine_landmarks=True,
                                               min_detection_confidence=0.5, min_tracking_confidence=0.5)

        def faces_in(image: np.ndarray) -> list[np.ndarray]:
            height, width = image.shape[:2]
            result = mesh.process(np.ascontiguousarray(image))
            faces = [np.array([(p.x * width, p.y * height, p.z * width) for p in face.landmark[:WITH_IRISES]])
                     for face in result.multi_face_landmarks or []]
            return sorted(faces, key=lambda f: -float(np.ptp(f[:LANDMARKS, :2], axis=0).max()))

        try:
            yield faces_in
        finally:
            mesh.close()


#: Times a still image is read as a video's frame (``read_as_video``): detected, then tracked
#: from its own landmarks until they settle.
SETTLING_READS = 3


def read_as_video(image: np.ndarray) -> list[np.ndarray]:
    """The faces in one image as MediaPipe's video mode reads a frame of a face it has been
    tracking (``face_tracker``'s), not as a still: its landmarks' region comes from the
    landmarks before, not from the detector's box, and a turned face's hidden side is
    guessed differently."""
    with face_tracker() as faces_in:
        for _ in range(SETTLING_READS):
            faces = faces_in(image)
    return faces


def track(source: Source, progress=None) -> Tracked:
    """Every frame's face (``Tracked``); ``progress(1)`` after each frame."""
    from ..files import check_terminated

    tracked = Tracked([])
    with face_tracker() as faces_in:
        for frame in frames_of(source):
            faces = faces_in(frame)
            if faces and (not tracked.landmarks or tracked.landmarks[-1] is None):  # detected: tracked again
                faces = faces_in(frame)
            tracked.several = tracked.several or len(faces) > 1
            tracked.landmarks.append(faces[0].astype(np.float32) if faces else None)  # 5.7 KB a frame
            check_terminated()
            if progress:
                progress(1)
    if not tracked.landmarks:
        raise InputError(f"{source.path}: no frames in it")
    return tracked
