"""From tracked landmarks to a performance: the head's pose, the eyes' gaze and ARKit's
shapes per frame, solved against facesim's own landmark motion as MediaPipe sees it.

1. **The basis** (``head_basis``: the default head's ships with the package, another
   head's is kept in facesim's cache). Each shape held by the physics on the default head
   at ``BASIS_WEIGHTS``, rendered from the front, its landmarks found and put into the
   head's frame; its motion per unit weight is the slope through them.
   The neutral head turned by known angles, each render read as a video's frame is
   (tracking.read_as_video), measures how MediaPipe misreads a turned head: its angles
   (``TURNS``) and, on a yaw-by-pitch grid, its landmarks in the image (``GRID``,
   ``_image_residual``).
2. **Pose.** Each frame's landmarks (the face frame: x the subject's left, y up, z toward
   the camera) are fitted by the similarity (Umeyama 1991) that best takes a template
   onto them, first at the ``RIGID`` landmarks, which expressions barely move. Its
   rotation is the head's yaw, pitch and roll (facesim.geometry.rotation's order), from
   how it faced the camera at first, calibrated by ``TURNS``.
3. **The subject's own neutral.** The median of the first frames (``NEUTRAL_SECONDS``,
   from the start or from the time the user gives: ``neutral_frames``) in the head's
   frame is what expressions are measured from, so that a face's shape, anyone's, is not
   read as an expression, and the head's turns are measured from how it faced the camera
   there. A face that is not at rest there would be read wrong without a word, so it is
   compared with the video's usual face (``at_rest``: the lips' gap, the mouth's width,
   the brows' and the lids' heights) and the difference is said.
4. **Shapes, in the image.** The neutral, turned and placed by the frame's pose, plus the
   turned head's misreading, plus the shapes' motion turned with it, is solved against
   the frame's landmarks in the image (x, y: MediaPipe's depth is a guess) by bounded
   least squares with a small ridge and a sparsity prior (``SPARSITY``: a shape moves
   only where the landmarks need it; scipy's ``lsq_linear``, weights 0-1), the side
   turned away counting less (``FAR_SIDE``). The pose is solved with them: a small turn
   about each axis, a shift and a scale of the fitted head are unknowns of the same
   solve, unbounded and without a ridge (the similarity's differential), so that a pose
   a few tenths of a degree off is not read as shapes nor shapes as a pose.
5. **Smoothing without lag.** Weights, angles and the irises are smoothed over time by a
   Savitzky-Golay filter (a centred, zero-phase least-squares polynomial), which removes
   the tracker's jitter and leaves peaks where they are.
6. **Gaze.** Each iris's centre, against where it is in the neutral frames, is an
   eye's turn: asin(offset / the eyeball's radius), held through blinks.

Frames with no face, or a face turned past ``TURN_LIMIT``, are bridged by straight lines
from the frames around them (held at the ends), and reported.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ..animation.arkit import ARKIT_52
from ..errors import InputError
from ..face.align import similarity
from ..face.photo import image_to_face_frame
from .tracking import IRIS_CENTRES, LANDMARKS, Tracked

#: The seconds at the start taken as the subject's neutral face.
NEUTRAL_SECONDS = 0.3
#: What ``at_rest`` compares: each a distance between two landmarks (MediaPipe's indices)
#: in the head's frame, what it is compared with over the video's frames facing the
#: camera (its median, or for the lips' gap, which only opens, its 10th percentile), and
#: by how much (cm on the head) the neutral may differ from that. On five round trips that
#: start at rest (clay, identity 7, the photo look, --onto, turns only; 2026-12-07) the
#: neutral frames differed by at most 0.3 mm in the lips' gap and 0.8 mm in the others; a
#: start with the jaw at 0.5 showed a gap 20 mm wider, one smiling at 0.7 a mouth 15 mm
#: wider.
REST_GAUGES = {"the lips' gap": ((13, 14), 10, 0.3), "the mouth's width": ((61, 291), 50, 0.4),
               "the left brow's height": ((334, 386), 50, 0.3), "the right brow's height": ((105, 159), 50, 0.3),
               "the left lids' gap": ((386, 374), 50, 0.3), "the right lids' gap": ((159, 145), 50, 0.3)}
#: The frames ``at_rest`` compares the neutral with: turned less than this (degrees) from it.
FACING = 8.0
#: A face turned further than this (degrees, yaw or pitch) is not solved: bridged.
TURN_LIMIT = 40.0
#: Landmarks the pose is fitted on (MediaPipe's indices): those ARKit's 52 shapes move
#: least on the head, at most 1.2-2.3 mm each at full weight (the nose's bridge, the
#: eyes' corners, the temples, the face's sides at the cheekbones), where the forehead
#: moves 4 mm and the nose's tip 7. Not the glabella (8) or the bridge's top (168): the
#: inner brows raise them 2.7 and 2.0 mm (ICT's AU1 raises the glabella 5 mm).
RIGID = (6, 133, 362, 243, 463, 244, 464, 127, 356, 162, 389, 34, 264, 139, 368, 33, 263, 130, 359, 234, 454)
#: ARKit's shapes the landmarks are solved for: all but the eyes' looks (the irises give
#: them) and tongueOut (a face mesh has no tongue).
SOLVED = tuple(n for n in ARKIT_52 if not n.startswith("eyeLook") and n != "tongueOut")
#: The ridge on the weights, in centimetres of landmark motion per unit weight: it keeps
#: shapes that barely explain the motion at zero.
RIDGE = 0.05
#: The sparsity prior (cm²): each weight costs SPARSITY x its value (an L1 penalty, the
#: lasso's, on weights that are never negative), so a shape moves only where its motion
#: explains at least this much of the landmarks' misfit (the sum over landmarks of its
#: motion per unit weight dotted with the misfit, cm on the head). A ridge only shrinks
#: what it does not stop: a head turning with no expression, captured from the default
#: head's clay, read some shape above 0.5 in 29 of its 100 frames (eyeWideRight 0.76,
#: jawForward 0.62) with the ridge alone, in none with this prior (the largest 0.29), and
#: the round trips' curves moved by at most 0.04, the jaw's up (2026-12-07; 0.1 left 13
#: frames above 0.3, 0.5 read the default head's left blink at 0.83).
SPARSITY = 0.2
#: How much less the side turned away counts: 1 - FAR_SIDE x (how far out) x sin(yaw).
FAR_SIDE = 1.0

#: The Savitzky-Golay filter's window (seconds) and polynomial order.
SMOOTHING, ORDER = 0.2, 2


@dataclass
class Performance:
    """A captured performance at ``fps``: ``weights`` (frames, len(SOLVED)) in [0, 1];
    ``head`` (frames, 3) yaw, pitch, roll and ``gaze`` (frames, 2, 2) each eye's yaw and
    pitch in degrees (facesim.animation.spec.POSE: the subject's left eye first); how far
    each frame's landmarks lie from the solved face (``residual``, frames: RMS over the
    landmarks, cm on the head; NaN where bridged); the frames bridged, and why."""

    fps: float
    weights: np.ndarray
    head: np.ndarray
    gaze: np.ndarray
    residual: np.ndarray
    missing: list[int] = field(default_factory=list)
    turned: list[int] = field(default_factory=list)
    names: tuple[str, ...] = SOLVED
    turns_read_on: str = "facesim's default head"
    neutral: tuple[int, int] = (0, 0)  # the first and last frame the neutral is taken from
    unsettled: str | None = None  # how the neutral differs from the video's usual face (``at_rest``)
    usual_from: float | None = None  # and the time (s) from which the face is most its usual one

    @property
    def frames(self) -> int:
        return len(self.weights)

    def arkit_weights(self) -> np.ndarray:
        """(frames, 52): the weights in ARKit's order, the eyes' looks from the gaze."""
        out = np.zeros((self.frames, len(ARKIT_52)))
        for k, name in enumerate(self.names):
            out[:, ARKIT_52.index(name)] = self.weights[:, k]
        return out


@dataclass(frozen=True)
class Basis:
    """The head at rest at MediaPipe's landmarks (468, 3) cm (the template the pose is
    first fitted to), each solved shape's landmark motion per unit weight (S, 470, 3: the
    468 and the irises' centres, in the head's frame, cm), the eyeballs' radius (cm)."""

    rest: np.ndarray
    motion: np.ndarray
    eye_radius: float
    turns: dict[str, np.ndarray] = field(default_factory=dict)  # TURNS' tables, GRID's residuals

    def turned_as(self, turns: dict[str, np.ndarray]) -> "Basis":
        """This basis with another head's turns (``face_turns``)."""
        return Basis(self.rest, self.motion, self.eye_radius, turns)

    def true_angles(self, raw: np.ndarray) -> np.ndarray:
        """The head's true yaw, pitch and roll for the ``raw`` (frames, 3) angles a fit
        found: measured on the neutral head turned by known angles (``TURNS``) and
        interpolated; the roll as found."""
        angles = raw.copy()
        for axis, name in enumerate(("yaw", "pitch")):
            order = np.argsort(self.turns[f"{name}_seen"])
            angles[:, axis] = np.interp(raw[:, axis], self.turns[f"{name}_seen"][order], self.turns[f"{name}_true"][order])
        return angles

    def image_residual(self, yaw: float, pitch: float) -> np.ndarray:
        """(468, 2) ``_image_residual`` of the neutral head at this true yaw and pitch,
        bilinear in the grid measured (GRID's nodes, or some of them: ``grid_yaw``,
        ``grid_pitch``), held at its edges."""
        out = 0.0
        (ya, yb, fy), (pa, pb, fp) = (_between(self.turns[f"grid_{n}"], v) for n, v in (("yaw", yaw), ("pitch", pitch)))
        table = self.turns["grid_residual"]
        for j, wy in ((ya, 1 - fy), (yb, fy)):
            for i, wp in ((pa, 1 - fp), (pb, fp)):
                out = out + wy * wp * table[j, i]
        return out


def _between(grid: np.ndarray, value: float) -> tuple[int, int, float]:
    j = int(np.clip(np.searchsorted(grid, value) - 1, 0, len(grid) - 2))
    return j, j + 1, float(np.clip((value - grid[j]) / (grid[j + 1] - grid[j]), 0.0, 1.0))


#: The default head's basis, measured by ``make kernels`` (scripts/build_kernels.py) and
#: shipped with the package (facesim/compiled), so that a new user's first capture does not
#: spend its first 20 s rendering and reading the head's shapes and turns (330
#: renders); used when its ``basis_key`` is this code's and head's (the suite fails when it
#: is not: tests/test_capture.py).
SHIPPED_BASIS = Path(__file__).resolve().parent.parent / "compiled" / "capture_basis.npz"
#: The renders the basis is measured on: their size, and the frames each shape is held.
BASIS_SIZE, BASIS_FRAMES = 384, 30
#: The weights each shape is held at: its motion per unit weight is the least-squares
#: slope through them (and rest). A muscle's response flattens toward its full weight,
#: and MediaPipe follows a closing lid only past half way: either weight alone misreads
#: the other's shapes.
BASIS_WEIGHTS = (0.5, 1.0)
#: The neutral head turned by these angles (degrees) measures how MediaPipe's landmarks
#: of a turned face differ from the turned landmarks of the face: the side turned away is
#: partly hidden, and the tracker's fit bends it.
TURNS = {"yaw": np.arange(-45.0, 46.0, 7.5), "pitch": np.arange(-30.0, 31.0, 7.5)}
#: The neutral head turned by each yaw and pitch of this grid measures where MediaPipe's
#: landmarks of a turned face lie in the image against the turned and projected neutral
#: (``_image_residual``): the yaw's and the pitch's artifacts do not add, nor do they
#: change smoothly: the neutral head turned 5 or 15 degrees, halfway between the nodes of
#: a 10-degree grid, read as shapes up to 0.48; with this 5-degree grid, at most 0.16.
GRID = {"yaw": np.arange(-40.0, 41.0, 5.0), "pitch": np.arange(-30.0, 31.0, 5.0)}


def _image_residual(points: np.ndarray, neutral: np.ndarray) -> np.ndarray:
    """(468, 2): a face's landmarks in the image less ``neutral`` turned, scaled and
    placed by the similarity fitted to them on every landmark, in the neutral's units."""
    fitted = list(range(LANDMARKS))
    scale, rotation, translation = similarity(neutral[fitted], points[fitted])
    return (points[:LANDMARKS, :2] - (scale * neutral[:LANDMARKS] @ rotation.T + translation)[:, :2]) / scale


def head_basis(spec) -> Basis:
    """ARKit's shapes' landmark motion on ``spec``'s head as MediaPipe sees it: each shape
    held at full weight by the physics, rendered from the front, its landmarks found and
    put into the head's frame as a video's are (``canonical``), less the neutral render's;
    and the head's turns (``TURNS``, ``GRID``). Measured once and kept in facesim's cache
    (facesim.cache) by the code and the head; the default head's ships with the package
    (``SHIPPED_BASIS``)."""
    from .. import cache

    rest, radius = _landmarks_at_rest(spec)
    digest = basis_key(spec, rest)
    stored = _shipped_basis(digest)
    if stored is None:
        stored = cache.cached_arrays("capture-basis", digest, lambda: _rendered(spec, rest, shapes=True), keep=2)
    return Basis(rest, stored["motion"], radius, {k: v for k, v in stored.items() if k != "motion"})


def basis_key(spec, rest: np.ndarray) -> str:
    """What ``head_basis`` is measured from, hashed: this code, facesim's version, the head
    at rest (``rest``: its landmarks), its muscles and material, and the shapes solved."""
    from .. import cache
    from ..config import VERSION

    return cache.key(Path(__file__).read_bytes(), VERSION.encode(), rest.tobytes(), spec.muscles_path.read_bytes(),
                     spec.material.model_dump_json().encode(), " ".join(SOLVED).encode())


def _shipped_basis(digest: str) -> dict[str, np.ndarray] | None:
    """The shipped basis's arrays if it was measured from what ``digest`` hashes, else None."""
    try:
        with np.load(SHIPPED_BASIS, allow_pickle=False) as stored:
            if str(stored["key"]) != digest:
                return None
            return {name: stored[name].astype(np.float64) for name in stored.files if name != "key"}
    except (OSError, KeyError, ValueError):  # not shipped (a source tree without it), or unreadable
        return None


def face_turns(face: Path, grid: dict[str, np.ndarray]) -> dict[str, np.ndarray]:
    """``Basis.turns``' grid (``grid_yaw``, ``grid_pitch``, ``grid_residual``) measured at
    ``grid``'s nodes on a face directory's head in its photo look (the subject's, fitted
    from a video's neutral frame: facesim.capture.subject)."""
    from ..animation.spec import Spec

    spec = Spec(name="capture", face=face)
    return _rendered(spec, _landmarks_at_rest(spec)[0], shapes=False, angles=False, look="photo", grid=grid)


def turn_grid(tracked: Tracked, fps: float, basis: Basis, neutral_at: float = 0.0) -> dict[str, np.ndarray]:
    """The nodes of ``GRID`` the video's turns span, one node beyond them each way, and 0
    (the face facing the camera, which the grid is read against), the turns measured
    from the neutral frames (``neutral_frames``)."""
    found = np.array([landmarks is not None for landmarks in tracked.landmarks])
    raw = np.zeros((len(found), 3))
    for k in np.flatnonzero(found):
        raw[k] = canonical(image_to_face_frame(np.asarray(tracked.landmarks[k], dtype=np.float64)), basis.rest)[0]
    angles = basis.true_angles(raw[found] - np.median(raw[neutral_frames(found, fps, neutral_at)], axis=0))
    out = {}
    for axis, name in enumerate(("yaw", "pitch")):
        nodes, step = GRID[name], GRID[name][1] - GRID[name][0]
        low, high = min(angles[:, axis].min(), 0.0) - step, max(angles[:, axis].max(), 0.0) + step
        out[name] = nodes[(nodes >= low) & (nodes <= high)]
    return out


def _landmarks_at_rest(spec) -> tuple[np.ndarray, float]:
    """``spec``'s head's landmarks at rest (468, 3) cm, and its eyeballs' radius."""
    from ..animation.simulate import model_for

    head = model_for(spec).mesh.head
    return head.landmark_positions, head.eyeball("left")[1]


def _rendered(spec, rest: np.ndarray, shapes: bool, angles: bool = True, look: str = "clay",
              grid: dict[str, np.ndarray] = GRID) -> dict[str, np.ndarray]:
    """The renders ``head_basis`` and ``face_turns`` measure: each shape's ``motion`` (if
    ``shapes``), the turned head's angles (``yaw_seen``, ``pitch_seen``, if ``angles``) and
    its landmarks' misreading at ``grid``'s nodes (``grid_residual``)."""
    from ..animation.simulate import simulate
    from ..renderer.scene import FaceRenderer
    from ..renderer.settings import RenderSettings
    from .tracking import face_tracker, read_as_video

    settings = RenderSettings(width=BASIS_SIZE, height=BASIS_SIZE, look=look)
    renderer = None

    def seen(animation, pose=None) -> np.ndarray:
        """The landmarks of ``animation``'s last frame, found as in a still, or for a
        turned head (``pose``) as in a video (how the head's turns are read)."""
        image = renderer.frame(animation, BASIS_FRAMES - 1, pose=pose)
        if pose is not None:
            faces = read_as_video(image)
        else:
            with face_tracker(still=True) as faces_in:
                faces = faces_in(image)
        if not faces:
            raise RuntimeError("MediaPipe found no face in facesim's render of its own head")
        return image_to_face_frame(faces[0])

    def held(name: str, weight: float = 1.0):
        return simulate(spec.with_overrides(frames=BASIS_FRAMES, arkit={name: weight} if name else {}, timeline=[],
                                            pose=[], name="basis"))

    try:
        neutral = held("")
        renderer = FaceRenderer.of(neutral, settings)
        points = seen(neutral)
        # every render of the still head is put into the head's frame by the neutral's fit:
        # a shape that moves a fitted point (the brows the bridge) must not turn its motion
        scale, rotation, translation = similarity(rest[list(RIGID)], points[list(RIGID)])

        def in_head_frame(points):
            kept = np.concatenate([points[:LANDMARKS], points[list(IRIS_CENTRES)]])
            return (kept - translation) @ rotation / scale

        at_rest = in_head_frame(points)
        out = {}
        if shapes:  # the slope through rest of each shape's motion at BASIS_WEIGHTS, by least squares
            levels = np.asarray(BASIS_WEIGHTS)
            out["motion"] = np.stack([sum(w * (in_head_frame(seen(held(name, w))) - at_rest) for w in levels)
                                      / (levels**2).sum() for name in SOLVED])
        # a turned head read as a video's frames are: the angles a fit finds, and where its
        # landmarks lie against the same head facing the camera read the same way (as a
        # video's turns are read against its neutral frames)
        for axis, name in enumerate(("yaw", "pitch") if angles else ()):
            out[f"{name}_true"] = np.asarray(TURNS[name])
            out[f"{name}_seen"] = np.array([canonical(seen(neutral, _turn(**{name: angle})), at_rest,
                                                      range(LANDMARKS))[0][axis] for angle in TURNS[name]])
        residual = np.stack([[_image_residual(seen(neutral, _turn(yaw, pitch)), at_rest) for pitch in grid["pitch"]]
                             for yaw in grid["yaw"]])
        out["grid_yaw"], out["grid_pitch"] = np.asarray(grid["yaw"]), np.asarray(grid["pitch"])
        out["grid_residual"] = residual - residual[list(grid["yaw"]).index(0.0), list(grid["pitch"]).index(0.0)]
        return out
    finally:
        if renderer is not None:
            renderer.close()


def _turn(yaw: float = 0.0, pitch: float = 0.0) -> np.ndarray:
    """A pose (facesim.animation.spec.POSE's order) turning the head by ``yaw`` and ``pitch``."""
    return np.array([yaw, pitch, 0.0, 0.0, 0.0])


def canonical(points: np.ndarray, template: np.ndarray, fitted=RIGID) -> tuple[np.ndarray, np.ndarray]:
    """A face's (478, 3) landmarks in the face frame (facesim.face.photo.image_to_face_frame)
    into the head's frame: the yaw, pitch and roll (degrees) of the similarity that best
    takes ``template`` onto them at the ``fitted`` landmarks, and the 468 landmarks and the
    irises' centres (470, 3) with it undone (cm)."""
    rigid = list(fitted)
    scale, rotation, translation = similarity(template[rigid], points[rigid])
    kept = np.concatenate([points[:LANDMARKS], points[list(IRIS_CENTRES)]])
    return yaw_pitch_roll(rotation), (kept - translation) @ rotation / scale


def yaw_pitch_roll(rotation: np.ndarray) -> np.ndarray:
    """The angles (degrees) of facesim.geometry.rotation(yaw, pitch, roll) = R."""
    pitch = math.asin(float(np.clip(rotation[1, 2], -1.0, 1.0)))
    return np.degrees([math.atan2(rotation[0, 2], rotation[2, 2]), pitch, math.atan2(-rotation[1, 0], rotation[1, 1])])


def bridged(values: np.ndarray, good: np.ndarray) -> np.ndarray:
    """``values`` (frames, ...) with the frames not ``good`` replaced by straight lines
    between the good ones around them (held before the first and after the last)."""
    frames = np.arange(len(values))
    flat = values.reshape(len(values), -1)
    out = np.stack([np.interp(frames, frames[good], column[good]) for column in flat.T], axis=1)
    return out.reshape(values.shape)


def neutral_frames(found: np.ndarray, fps: float, at: float = 0.0) -> np.ndarray:
    """The frames the subject's neutral is taken from: the first ``NEUTRAL_SECONDS`` of
    those ``found`` (frames,) bool, from ``at`` seconds on (none, if none is found from
    there on)."""
    frames = np.flatnonzero(found)
    return frames[frames >= int(round(at * fps))][:max(1, int(round(NEUTRAL_SECONDS * fps)))]


def at_rest(faces: np.ndarray, angles: np.ndarray, good: np.ndarray, neutral: np.ndarray,
            fps: float) -> tuple[str | None, float | None]:
    """How the ``neutral`` frames' face differs from the video's usual one (``REST_GAUGES``,
    over the ``good`` frames turned less than ``FACING`` from them: ``faces`` (frames,
    470, 3) in the head's frame, ``angles`` (frames, 3) degrees), and the time (s) from
    which a stretch as long as the neutral's is nearest the usual face; None, None where
    the neutral does not differ."""
    facing = good & (np.abs(angles[:, :2] - np.median(angles[neutral, :2], axis=0)).max(axis=1) < FACING)
    facing[neutral] = True
    frames = np.flatnonzero(facing)
    gauges, away = [], np.zeros(len(frames))
    for name, ((a, b), percentile, tolerance) in REST_GAUGES.items():
        size = np.linalg.norm(faces[frames, a] - faces[frames, b], axis=1)
        usual = np.percentile(size, percentile)
        ours = float(np.median(np.linalg.norm(faces[neutral, a] - faces[neutral, b], axis=1)))
        away += np.abs(size - usual) / tolerance
        if abs(ours - usual) > tolerance:
            gauges.append(f"{name} {10 * ours:.0f} mm against its usual {10 * usual:.0f}")
    if not gauges:
        return None, None
    count = min(len(neutral), len(frames))  # the window as long as the neutral's nearest the usual face
    nearest = frames[int(np.argmin(np.convolve(away, np.ones(count) / count, mode="valid")))]
    return f"{', '.join(gauges)}, scaled to facesim's head", nearest / fps


def solve(tracked: Tracked, fps: float, basis: Basis, source: str, progress=None,
          neutral_at: float = 0.0) -> Performance:
    """The performance in ``tracked`` (see the module's steps), its neutral taken from
    ``neutral_at`` seconds on."""
    from scipy.signal import savgol_filter

    frames = len(tracked.landmarks)
    found = np.array([lm is not None for lm in tracked.landmarks])
    if not found.any():
        raise InputError(f"{source}: no face found in any of its {frames} frames")

    def points(k: int) -> np.ndarray:
        return image_to_face_frame(np.asarray(tracked.landmarks[k], dtype=np.float64))

    raw, faces = np.zeros((frames, 3)), np.zeros((frames, LANDMARKS + 2, 3), dtype=np.float32)
    for k in np.flatnonzero(found):
        raw[k], faces[k] = canonical(points(k), basis.rest, RIGID)
    first = neutral_frames(found, fps, neutral_at)
    if not len(first):
        raise InputError(f"{source}: no face found from {neutral_at:g} s on, where --neutral takes the face at rest")
    raw -= np.median(raw[first], axis=0)  # the turns from how the head faced the camera at first
    turned = found & (np.abs(raw[:, :2]).max(axis=1) > TURN_LIMIT)
    good = found & ~turned
    if not good.any():
        raise InputError(f"{source}: the face is turned more than {TURN_LIMIT:.0f} degrees in every frame it is found in")
    first = neutral_frames(good, fps, neutral_at)
    if not len(first):
        raise InputError(f"{source}: the face is turned more than {TURN_LIMIT:.0f} degrees in every frame from "
                         f"{neutral_at:g} s on, where --neutral takes the face at rest")
    unsettled, usual_from = at_rest(faces, raw, good, first, fps)
    neutral = np.median(faces[first], axis=0).astype(np.float64)
    weights, residual = np.zeros((frames, len(SOLVED))), np.full(frames, np.nan)
    for k in np.flatnonzero(good):
        seen = points(k)
        raw[k], faces[k] = canonical(seen, neutral, RIGID)
        yaw, pitch, _ = basis.true_angles(raw[k:k + 1])[0]
        weights[k], residual[k] = _shapes_in_the_image(seen, neutral, basis.image_residual(yaw, pitch), basis)
        if progress:
            progress(1)
    weights, raw, faces = bridged(weights, good), bridged(raw, good), bridged(faces, good)
    head = basis.true_angles(raw)
    head -= np.median(head[first], axis=0)  # from how the head faced the camera at first
    window = max(ORDER + 1, int(round(SMOOTHING * fps)) | 1)
    if frames > window:
        weights = np.clip(savgol_filter(weights, window, ORDER, axis=0), 0.0, 1.0)
        head, faces = savgol_filter(head, window, ORDER, axis=0), savgol_filter(faces, window, ORDER, axis=0)
    weights[weights < 0.01] = 0.0
    gaze = _gaze(faces[:, LANDMARKS:] - neutral[LANDMARKS:], neutral, basis, weights)
    return Performance(fps, weights, head, gaze, residual, missing=np.flatnonzero(~found).tolist(),
                       turned=np.flatnonzero(turned).tolist(), neutral=(int(first[0]), int(first[-1])),
                       unsettled=unsettled, usual_from=usual_from)


def _shapes_in_the_image(points: np.ndarray, neutral: np.ndarray, misread: np.ndarray,
                         basis: Basis) -> tuple[np.ndarray, float]:
    """One frame's shapes, solved where MediaPipe is surest, in the image: the subject's
    neutral turned, scaled and placed by the similarity fitted at the ``RIGID`` landmarks,
    what MediaPipe's landmarks of a head so turned are off by (``misread``:
    ``Basis.image_residual``) allowed for, and the landmarks' image positions (x, y)
    solved by bounded least squares with a ridge and the sparsity prior (``SPARSITY``)
    for the shapes' weights, turned and scaled by that fit, and for the fit's small
    corrections (``_pose_differential``). A turned face's hidden side, whose depth
    MediaPipe guesses, counts only as far as it shows. Returns the weights, and the
    landmarks' RMS distance from the solved face (cm on the head, as counted)."""
    from scipy.optimize import lsq_linear

    rigid = list(RIGID)
    scale, rotation, translation = similarity(neutral[rigid], points[rigid])
    turned = scale * neutral[:LANDMARKS] @ rotation.T
    start = (turned + translation)[:, :2] + scale * misread
    # the side of the face turned away counts less, the more so the further out and the more turned
    away = np.clip(np.sign(rotation[0, 2]) * neutral[:LANDMARKS, 0] / np.abs(neutral[:LANDMARKS, 0]).max(), 0.0, 1.0)
    counts = np.clip(1.0 - FAR_SIDE * away * abs(rotation[0, 2]), 0.1, 1.0)[:, None]
    shapes = (scale * basis.motion[:, :LANDMARKS] @ rotation.T)[:, :, :2]
    columns = np.concatenate([shapes, _pose_differential(turned - turned.mean(axis=0))]) * counts
    solved, free = len(SOLVED), len(columns) - len(SOLVED)
    design = np.vstack([columns.reshape(len(columns), -1).T,
                        np.hstack([scale * RIDGE * np.eye(solved), np.zeros((solved, free))])])
    target = np.concatenate([((points[:LANDMARKS, :2] - start) * counts).ravel(), np.zeros(solved)])
    bounds = (np.r_[np.zeros(solved), np.full(free, -np.inf)], np.r_[np.ones(solved), np.full(free, np.inf)])
    # the sparsity prior: |D w - t|² + 2 λ·w is |D w - (t - D c)|² and a constant, for DᵀD c = λ
    # (λ = SPARSITY for each shape's weight, 0 for the pose's; the image is in units of ``scale``)
    prior = np.r_[np.full(solved, SPARSITY * scale * scale), np.zeros(free)]
    shifted = target - design @ np.linalg.solve(design.T @ design, prior)
    solution = lsq_linear(design, shifted, bounds=bounds, method="bvls").x
    misfit = (design[:-solved] @ solution - target[:-solved]).reshape(-1, 2)
    return solution[:solved], float(np.sqrt((misfit**2).sum(axis=1).mean()) / scale)


def _pose_differential(turned: np.ndarray) -> np.ndarray:
    """(6, n, 2): how the image positions of the head's ``turned`` points (about their
    centroid, face frame) move per radian of a turn about the x, y and z axes (omega x
    p), per unit shift along x and y, and per unit of scale."""
    x, y, z = turned.T
    nothing, one = np.zeros_like(x), np.ones_like(x)
    return np.stack([np.stack(pair, axis=1) for pair in
                     ((nothing, -z), (z, nothing), (-y, x), (one, nothing), (nothing, one), (x, y))])


def _gaze(iris_moved: np.ndarray, neutral: np.ndarray, basis: Basis, weights: np.ndarray) -> np.ndarray:
    """(frames, 2, 2): each eye's yaw and pitch from its iris's offset, the subject's left
    eye first; held where the eye is more than half closed."""
    left_first = [0, 1] if neutral[LANDMARKS, 0] > neutral[LANDMARKS + 1, 0] else [1, 0]
    offset = iris_moved[:, left_first, :2]
    angles = np.degrees(np.arcsin(np.clip(offset / basis.eye_radius, -1.0, 1.0)))
    blinks = [weights[:, SOLVED.index(n)] for n in ("eyeBlinkLeft", "eyeBlinkRight")]
    for eye, blink in enumerate(blinks):
        open_ = blink < 0.5
        if open_.any() and not open_.all():
            angles[:, eye] = bridged(angles[:, eye], open_)
    return angles
