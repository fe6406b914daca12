"""How far an action unit of facesim is from a scanned one (issue 16): the measurement
the muscles are calibrated by.

ICT FaceKit (USC ICT, MIT licence) publishes, for each FACS action unit of its table, the
light-stage shapes a real face takes under it. facesim never moves toward them: they are
measurements. An action unit is simulated alone at full intensity (eased in over
``ONSET`` frames and held to ``FRAMES``), and its displacement from the neutral at the
last frame is compared with ICT's, vertex for vertex, over the vertices that either moves
at least ``MOVES``:

- direction: the cosine between the two displacement fields;
- amplitude: the ratio of their norms; and the ratio of the mean displacement at the
  ``TOP`` vertices ICT moves most (the peak).

On the default head the simulated vertices are MediaPipe's landmarks, vertex k lying on
ICT's vertex ``Head.landmarks[k]``. facesim's field is compared where the head shows it,
carried over its face area by the head's follow (``on_face``, facesim.face.figure), against
ICT's full shape there, as ``scripts/realism.py`` does; the tests read ICT's shape from
``tests/data/ict_shapes.npz`` (ICT's 57 shapes over the face area, as ICT ships them;
``scripts/calibrate.py`` fits to their value at the landmark vertices). ICT's
displacement at the landmarks alone, carried over the face by the same follow, keeps
cosine at least 0.95 with its full shape for every unit: the simulated mesh can carry
every unit, and the face area weighs each region by how much of the face it is (the lips
and lids have many vertices there, few landmarks).
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

#: ICT's FACS table (ICT FaceKit's README): action unit -> its shapes, summed. AU26 (jaw
#: drop) is half of jawOpen, AU27 (mouth stretch) all of it.
ICT_SHAPES = {
    "AU1": ["browInnerUp_L", "browInnerUp_R"], "AU2": ["browOuterUp_L", "browOuterUp_R"],
    "AU4": ["browDown_L", "browDown_R"], "AU5": ["eyeWide_L", "eyeWide_R"],
    "AU6": ["cheekSquint_L", "cheekSquint_R"], "AU7": ["eyeSquint_L", "eyeSquint_R"],
    "AU9": ["noseSneer_L", "noseSneer_R"], "AU10": ["mouthShrugUpper"],
    "AU11": ["mouthUpperUp_L", "mouthUpperUp_R"], "AU12": ["mouthSmile_L", "mouthSmile_R"],
    "AU14": ["mouthDimple_L", "mouthDimple_R"], "AU15": ["mouthFrown_L", "mouthFrown_R"],
    "AU16": ["mouthLowerDown_L", "mouthLowerDown_R"], "AU17": ["mouthShrugLower"], "AU18": ["mouthPucker"],
    "AU20": ["mouthStretch_L", "mouthStretch_R"], "AU22": ["mouthFunnel"], "AU24": ["mouthPress_L", "mouthPress_R"],
    "AU26": ["jawOpen"], "AU27": ["jawOpen"], "AU45": ["eyeBlink_L", "eyeBlink_R"],
}
ICT_WEIGHT = {"AU26": 0.5}
#: ICT FaceKit's 57 expression shapes, in its file's order: each is also compared alone,
#: with the control it stands for (facesim.animation.arkit.shape_facs: a side alone, the
#: jaw's glides, ...), so a one-sided shape is measured against ICT's shape for that side.
ICT_EXPRESSIONS = (
    "PupilDilate_L", "PupilDilate_R", "browDown_L", "browDown_R", "browInnerUp_L", "browInnerUp_R", "browOuterUp_L",
    "browOuterUp_R", "cheekPuff_L", "cheekPuff_R", "cheekRaiser_L", "cheekRaiser_R", "cheekSquint_L", "cheekSquint_R",
    "eyeBlink_L", "eyeBlink_R", "eyeLookDown_L", "eyeLookDown_R", "eyeLookIn_L", "eyeLookIn_R", "eyeLookOut_L",
    "eyeLookOut_R", "eyeLookUp_L", "eyeLookUp_R", "eyeSquint_L", "eyeSquint_R", "eyeWide_L", "eyeWide_R", "jawForward",
    "jawLeft", "jawOpen", "jawRight", "mouthClose", "mouthDimple_L", "mouthDimple_R", "mouthFrown_L", "mouthFrown_R",
    "mouthFunnel", "mouthLeft", "mouthLowerDown_L", "mouthLowerDown_R", "mouthPress_L", "mouthPress_R", "mouthPucker",
    "mouthRight", "mouthRollLower", "mouthRollUpper", "mouthShrugLower", "mouthShrugUpper", "mouthSmile_L", "mouthSmile_R",
    "mouthStretch_L", "mouthStretch_R", "mouthUpperUp_L", "mouthUpperUp_R", "noseSneer_L", "noseSneer_R",
)
#: Every row compared: the 21 action units (ICT's sums), then each of ICT's shapes alone.
ICT_ROWS = {**ICT_SHAPES, **{name: [name] for name in ICT_EXPRESSIONS}}
#: Shapes that correct another: ICT's mouthClose is the lips closed over jawOpen (alone,
#: its lower lip would pass through the upper one). Such a row is simulated on top of its
#: base, and the difference from the base alone is compared.
ON_TOP = {"mouthClose": "AU27"}


def row_control(row: str) -> str:
    """The FACS form a row is simulated as: an action unit is itself, an ICT shape the
    control it stands for (ValueError for a shape facesim does not simulate yet)."""
    from .arkit import shape_facs

    return row if row in ICT_SHAPES else shape_facs(row)
#: ICT's face area: its vertices 0-9408.
FACE_AREA = 9409
#: A vertex takes part in the comparison when either field moves it this far (cm).
MOVES = 0.1
#: The peak amplitude is taken at the vertices ICT moves most, this many.
TOP = 20
#: Issue 16's bounds: cosine at least COSINE, amplitude (the norm ratio) within AMPLITUDE.
COSINE, AMPLITUDE = 0.8, (0.75, 1.33)
#: The simulation of one unit: frames, and the frames it is eased in over.
FRAMES, ONSET = 80, 10


@dataclass(frozen=True)
class Comparison:
    cosine: float
    amplitude: float
    peak: float  # ratio of the mean displacement at the TOP vertices ICT moves most
    ours_peak: float  # cm
    their_peak: float  # cm

    @property
    def within_bounds(self) -> bool:
        return self.cosine >= COSINE and AMPLITUDE[0] <= self.amplitude <= AMPLITUDE[1]


def ict_displacement(shapes, row: str) -> np.ndarray:
    """(N, 3) ICT's displacement for a row (an action unit or one of ICT's shapes) over
    the vertices ``shapes`` gives, from its ``expression_names`` and ``expression_deltas``
    (ICT's ``shapes.npz``, or the tests' ``ict_shapes.npz`` over the face area)."""
    names = [str(n) for n in shapes["expression_names"]]
    deltas = shapes["expression_deltas"]
    total = sum(deltas[names.index(n)].astype(np.float64) for n in ICT_ROWS[row])
    return ICT_WEIGHT.get(row, 1.0) * total


def ict_fields(shapes) -> dict[str, np.ndarray]:
    """Every row's ICT displacement over the face area, (FACE_AREA, 3) in cm, from ICT's
    shapes (``tests/data/ict_shapes.npz`` or ICT's own file)."""
    return {row: ict_displacement(shapes, row)[:FACE_AREA] for row in ICT_ROWS}


def compare(ours: np.ndarray, theirs: np.ndarray) -> Comparison:
    """Direction and amplitude of displacement field ``ours`` (k, 3) against ``theirs``."""
    either = (np.linalg.norm(ours, axis=1) >= MOVES) | (np.linalg.norm(theirs, axis=1) >= MOVES)
    a, b = ours[either].ravel(), theirs[either].ravel()
    top = np.argsort(np.linalg.norm(theirs, axis=1))[-TOP:]
    ours_peak = float(np.linalg.norm(ours[top], axis=1).mean())
    their_peak = float(np.linalg.norm(theirs[top], axis=1).mean())
    return Comparison(
        cosine=float(a @ b / max(np.linalg.norm(a) * np.linalg.norm(b), 1e-12)),
        amplitude=float(np.linalg.norm(a) / max(np.linalg.norm(b), 1e-12)),
        peak=ours_peak / max(their_peak, 1e-12), ours_peak=ours_peak, their_peak=their_peak,
    )


@dataclass(frozen=True)
class Held:
    """An action unit simulated and held: the simulated vertices' displacement at the
    last frame (n, 3), as the head shows it (a lid landmark's motion scaled to the head's
    own opening, facesim.face.figure); the most inverted triangles in any frame; and the
    kinetic energy at the end over its peak (how far from settled)."""

    displacement: np.ndarray
    inverted: int
    unsettled: float
    kinetic_energy: np.ndarray  # (frames,)
    last_step: float  # the most a vertex moved in the last frame (cm)


def on_face(figure, displacement: np.ndarray) -> np.ndarray:
    """(FACE_AREA, 3): a displacement of the simulated vertices (n, 3) carried over the
    head's face area as the head shows it (facesim.face.figure's follow)."""
    out = np.zeros((FACE_AREA, 3))
    rows = figure.follow_rows < FACE_AREA
    out[figure.follow_rows[rows]] = (figure.follow @ displacement)[rows]
    return out


def hold(model, au: str | tuple[str, ...], intensity: float = 1.0, frames: int = FRAMES, figure=None) -> Held:
    """Simulate ``au`` alone (or several units together) on ``model``
    (facesim.physics.model.Model), eased in and held. ``figure``: the head it drives (default:
    built for the model); a caller trying many muscle files on one head passes the one it
    built, whose follow they all share."""
    from ..face.figure import figure_for
    from ..physics.run import run
    from .spec import Spec, activation_table
    from .timeline import AU_NAME

    units = (au,) if isinstance(au, str) else au
    facs = {u: intensity for u in units if AU_NAME.fullmatch(u)}  # and controls (a shape FACS has no unit for)
    spec = Spec.model_validate(dict(name="+".join(units), frames=frames, onset=ONSET, aus=facs,
                                    activations={u: intensity for u in units if u not in facs}))
    positions, energy, inverted, _ = run(model, activation_table(spec, model.muscles), spec.dt, stop_on_inversion=False)
    displacement = positions[-1] - model.rest_position
    figure = figure_for(model) if figure is None else figure
    if figure is not None:
        displacement = displacement * figure.follow_gain[:, None]
    return Held(displacement, int(inverted.max()), float(energy[-1] / max(energy.max(), 1e-300)), energy,
                float(np.linalg.norm(positions[-1] - positions[-2], axis=1).max()))


def hold_row(model, row: str, figure=None, frames: int = FRAMES) -> Held:
    """A row's control held (``hold``); for a row that corrects another (``ON_TOP``), held
    on top of its base, its displacement the difference from the base held alone."""
    unit = row_control(row)
    if row not in ON_TOP:
        return hold(model, unit, frames=frames, figure=figure)
    base = hold(model, ON_TOP[row], frames=frames, figure=figure)
    both = hold(model, (ON_TOP[row], unit), frames=frames, figure=figure)
    return replace(both, displacement=both.displacement - base.displacement)


#: FACS's prototypes of the library's expressions (issue 46.6), the units each is compared
#: with composed from ICT's shapes as the units' rows are (``ICT_SHAPES``): the units each
#: file names for its expression; for happy and surprise, which name none, EMFACS's
#: (Ekman, Friesen and Hager 2002: AU6 + AU12, AU1 + AU2 + AU5 + AU26); the thesis's two
#: compounds as Du, Tao and Martinez (2014) found them in faces (happily surprised
#: AU1 + AU2 + AU12 + AU25, angrily disgusted AU4 + AU10 + AU17). ICT's table has no
#: shape for AU23 (angry's lip tightener) or AU25 (lips parted): they are left out.
PROTOTYPES = {
    "happy": ("AU6", "AU12"), "sad": ("AU1", "AU4", "AU15", "AU17"), "surprise": ("AU1", "AU2", "AU5", "AU26"),
    "fear": ("AU1", "AU2", "AU4", "AU5", "AU7", "AU20", "AU26"), "angry": ("AU4", "AU5", "AU7", "AU23", "AU24"),
    "disgust": ("AU4", "AU9", "AU10", "AU15"), "duchenne_smile": ("AU6", "AU12"), "blink": ("AU45",),
    "happy_surprise": ("AU1", "AU2", "AU12", "AU25"), "disgusted_anger": ("AU4", "AU10", "AU17"),
}


@dataclass(frozen=True)
class Prototyped:
    """An expression's apex against its FACS prototype (``PROTOTYPES``) from ICT's shapes:
    composed with every unit at full intensity (``composed``), and with each unit's
    intensity (0-1) fitted to the apex by bounded least squares (``weights``, the units
    ICT has shapes for; ``fitted``): how far the face reads as the prototype, and how
    strongly it shows each unit."""

    composed: Comparison
    fitted: Comparison
    weights: dict[str, float]


def apex_frame(animation) -> int:
    """An expression's apex: the last frame at which its muscles (and jaw) are most
    activated, the held end of an expression, the middle of a blink."""
    total = animation.activations.sum(axis=1)
    return int(np.flatnonzero(total >= total.max() - 1e-9)[-1])


def against_prototype(ours: np.ndarray, fields: dict[str, np.ndarray], units: tuple[str, ...]) -> Prototyped:
    """``ours`` (FACE_AREA, 3), an expression's displacement at its apex, against ICT's
    shapes for ``units`` (``ict_fields``) composed at full intensity and fitted."""
    from scipy.optimize import lsq_linear

    shown = [u for u in units if u in ICT_SHAPES]
    basis = np.stack([fields[u].ravel() for u in shown], axis=1)
    weights = lsq_linear(basis, ours.ravel(), bounds=(0.0, 1.0), method="bvls").x
    composed = compare(ours, basis.sum(axis=1).reshape(-1, 3))
    fitted = compare(ours, (basis @ weights).reshape(-1, 3))
    return Prototyped(composed, fitted, dict(zip(shown, map(float, weights))))


#: ARKit's tongueOut has no ICT shape: it is held to anatomy instead (issue 46), shown as
#: FACS's AU19 (the jaw opened with it), its tip at least TONGUE_PAST (cm) in front of the
#: lower incisors' labial face, and nothing of the tongue inside a tooth.
TONGUE_PAST = 1.0


def teeth_pieces(head) -> list[np.ndarray]:
    """Each of the head's teeth as its vertices (ICT's M_Teeth: a connected piece a tooth,
    as the figure makes each one rigid)."""
    from ..face.figure import _components

    return _components(head.triangles_of("M_Teeth"), head.part("teeth"))


def lower_incisors(figure, head) -> np.ndarray:
    """The vertices of the teeth that turn with the mandible whole, at the front."""
    whole = set(figure.jaw_rows[figure.jaw_weight == 1.0].tolist())
    return np.concatenate([t for t in teeth_pieces(head) if t[0] in whole and figure.rest[t, 2].max() > 10.0])


def tongue_past_incisors(figure, head, x: np.ndarray) -> float:
    """How far (cm, forward) the tongue's tip lies in front of the lower incisors, the
    head's vertices at ``x`` (negative: behind them)."""
    return float(x[figure.tongue.rows, 2].max() - x[lower_incisors(figure, head), 2].max())


def tongue_in_teeth(figure, head, x: np.ndarray) -> int:
    """How many of the tongue's vertices and triangles' centroids lie inside a tooth (its
    convex hull), the head's vertices at ``x``."""
    from scipy.spatial import Delaunay

    rows = figure.tongue.rows
    triangles = head.triangles_of("M_GumsTongue")
    triangles = triangles[np.isin(triangles, rows).all(axis=1)]
    points = np.vstack([x[rows], x[triangles].mean(axis=1)])
    return sum(int(np.count_nonzero(Delaunay(x[tooth]).find_simplex(points) >= 0)) for tooth in teeth_pieces(head))
