"""The subject's own head, for reading their turns: MediaPipe misreads a turned face
differently on every face (the clay head's misreading, allowed for on the astronaut's
face, read her right eye as squinting whenever she turned), so the head turned by known
angles is measured on a face fitted to the video's subject.

The video's neutral frame (of its neutral frames, facesim.capture.solver.neutral_frames,
the one whose landmarks are nearest their median) goes through ``face from-photo`` (facesim.face.own_face: ICT's
identity fitted to its landmarks, the frame baked into the texture), and that face, in its
photo look, is turned over the grid's nodes the video's turns span and read as the
default head is (facesim.capture.solver.face_turns, turn_grid). The tables are kept in
facesim's cache by the frame's pixels and the nodes; the face directory is not.
facesim.capture.performance solves the frames with the default head's tables and with
these, and keeps the solve the landmarks fit better.
"""

from __future__ import annotations

import math
import tempfile
from pathlib import Path

import numpy as np

from ..errors import InputError
from .solver import LANDMARKS, neutral_frames
from .tracking import Source, Tracked, frames_of

#: A face is fitted at least this many pixels across (its landmarks' extent): a smaller
#: one (a face drawn --onto a photo is 92) is enlarged to it first; face from-photo takes
#: 100 or more.
FIT_SIZE = 200


def subject_turns(source: Source, tracked: Tracked, basis, notice=None,
                  neutral_at: float = 0.0) -> tuple[dict[str, np.ndarray], int] | None:
    """The turned head's misreading (facesim.capture.solver.face_turns) on a face fitted to
    the video's neutral frame, over the turns the video makes (``turn_grid``, the default
    head's ``basis`` reading them), and that frame's index; None, said through ``notice``,
    where the frame cannot be fitted."""
    from .. import cache
    from ..config import VERSION
    from ..face import own_face
    from . import solver

    k, size = _neutral_frame(tracked, source.fps, neutral_at)
    image = next(frame for index, frame in enumerate(frames_of(source)) if index == k)
    enlarged = max(1, math.ceil(FIT_SIZE / size))
    if enlarged > 1:
        from PIL import Image

        height, width = image.shape[:2]
        image = np.asarray(Image.fromarray(image).resize((width * enlarged, height * enlarged), Image.LANCZOS))
    grid = solver.turn_grid(tracked, source.fps, basis, neutral_at)
    parts = [np.ascontiguousarray(image).tobytes(), str(image.shape).encode(), grid["yaw"].tobytes(),
             grid["pitch"].tobytes(), VERSION.encode(),
             Path(solver.__file__).read_bytes(), Path(own_face.__file__).read_bytes(), Path(__file__).read_bytes()]

    def measured() -> dict[str, np.ndarray]:
        import imageio.v3 as iio

        with tempfile.TemporaryDirectory(prefix="facesim-subject-") as tmp:
            photo = Path(tmp) / f"{source.path.stem}-frame{k}.png"
            iio.imwrite(photo, image)
            own_face.face_from_photo(photo, Path(tmp) / "face")
            return solver.face_turns(Path(tmp) / "face", grid)

    try:
        return cache.cached_arrays("capture-turns", cache.key(*parts), measured, keep=8), k
    except (InputError, RuntimeError) as exc:  # a frame face from-photo cannot fit; a fitted face MediaPipe misses
        if notice:
            notice(f"{source.path}: its neutral frame {k} could not be fitted ({exc}); its turns are read as "
                   "facesim's default head's")
        return None


def _neutral_frame(tracked: Tracked, fps: float, neutral_at: float) -> tuple[int, float]:
    """Of the neutral frames (``neutral_frames``), the one whose landmarks (centred and
    scaled) lie nearest their median; and its face's size in pixels."""
    first = neutral_frames(np.array([landmarks is not None for landmarks in tracked.landmarks]), fps, neutral_at)
    shapes = []
    for k in first:
        points = np.asarray(tracked.landmarks[k][:LANDMARKS, :2], dtype=np.float64)
        points = points - points.mean(axis=0)
        shapes.append(points / np.linalg.norm(points))
    shapes = np.array(shapes)
    k = int(first[int(np.argmin(np.linalg.norm(shapes - np.median(shapes, axis=0), axis=(1, 2))))])
    return k, float(np.ptp(tracked.landmarks[k][:LANDMARKS, :2], axis=0).max())
