"""ARKit's 52 blendshapes baked by facesim's physics, and animations fitted back onto them.

A rig that plays in any engine is a rest mesh and a set of shapes (morph targets) the
engine adds up with weights. facesim's shapes are not sculpted: each of ARKit's 52
(facesim.animation.arkit.ARKIT_52) is its control (muscles, the jaw's and lips' rig, the
lids, the tongue) held at full weight until the skin settles (``calibration.FRAMES``
frames eased in over ``calibration.ONSET``, as REALISM.md measures them), and the shape
is every vertex of the head at the last frame, in ICT FaceKit's order, as the figure
draws it (facesim.face.figure): skin, lids, lashes, teeth and tongue. ARKit's
``mouthClose`` is, as ICT scans it, the lips closed over the open jaw, and ``tongueOut``
the tongue out between parted teeth: each is baked on top of ``jawOpen`` and stored as
the difference (``BAKED_ON_TOP``), as an engine adds it to jawOpen.

The eyeballs' turn is left out of the shapes: a rotation is not a vertex offset (a
linear blend of a turned sphere shrinks it), so gaze travels as the eyes' joints (as
ARKit's own face geometry leaves the eyes to their transforms); the lids and skin that
follow the gaze stay in ``eyeLook*``.

``fit_weights`` goes the other way: each frame of a simulated animation, as the head
shows it without its head pose and eye turns, as the weights in [0, 1] whose shapes add
up closest to it, by bounded least squares over every vertex a shape moves (BVLS,
scipy.optimize.lsq_linear, on the shapes' 52x52 triangular factor, so a frame costs the
same however many vertices move). Its residual, the playback's error, is reported over
ICT's face area: nonlinear physics (two muscles pulling one fold) does not add up
exactly.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..errors import InputError
from .arkit import ARKIT_52
from .calibration import FACE_AREA, FRAMES, ONSET

#: Shapes baked on top of another: ICT's mouthClose is the lips closed over the open jaw
#: (calibration.ON_TOP: its AU27 is jawOpen), and the tongue comes out between parted
#: incisors only (facesim.face.tongue: with the jaw closed it stays behind the teeth).
BAKED_ON_TOP = {"mouthClose": "jawOpen", "tongueOut": "jawOpen"}
#: A vertex is part of a shape when that shape moves it this far (cm): 1 µm.
MOVED = 1e-4


@dataclass(frozen=True)
class Shapes:
    """The head's rest (N, 3), cm, ICT's vertex order, and each of ``names``' displacement
    from it at full weight, ``deltas`` (S, N, 3) float32 cm."""

    names: tuple[str, ...]
    rest: np.ndarray
    deltas: np.ndarray

    def moved(self, k: int) -> np.ndarray:
        """The vertices shape k moves at least MOVED."""
        return np.flatnonzero(np.linalg.norm(self.deltas[k], axis=1) >= MOVED)

    def played(self, weights: np.ndarray) -> np.ndarray:
        """(N, 3) the rest plus the weighted shapes: what an engine plays for ``weights`` (S,)."""
        return self.rest + np.tensordot(np.asarray(weights, dtype=np.float64), self.deltas, axes=1)


def unturned(animation, frame: int) -> np.ndarray:
    """(N, 3) the head at ``frame`` as the shapes carry it: the figure for the simulated
    skin, the jaw, the pupils and the tongue, without the head's pose and the eyeballs'
    turn (which travel as joints)."""
    pose = animation.pose_at(frame)
    look = None
    if pose is not None and len(pose) > 5:
        look = np.array(pose[5:], dtype=np.float64)
        look[0:4] = 0.0
    return animation.figure.positions(animation.positions_at(frame), animation.jaw_at(frame), (0.0, 0.0), look)


def _held(spec, weights: dict[str, float]) -> np.ndarray:
    from .simulate import simulate

    held = spec.model_copy(update=dict(
        name="+".join(weights), frames=FRAMES, onset=ONSET, arkit=weights, aus={}, activations={}, expressions={},
        timeline=[], pose=[], include=[], sequence=[]))
    held._source = spec._source
    animation = simulate(held)
    return unturned(animation, animation.frames - 1)


def _baked(spec) -> dict[str, np.ndarray]:
    from ..face.figure import figure_for
    from .simulate import model_for

    rest = figure_for(model_for(spec)).rest
    deltas = []
    for name in ARKIT_52:
        base = {BAKED_ON_TOP[name]: 1.0} if name in BAKED_ON_TOP else None
        shape = _held(spec, {**(base or {}), name: 1.0}) - (rest if base is None else _held(spec, base))
        deltas.append(shape.astype(np.float32))
    return {"rest": rest, "deltas": np.stack(deltas)}


def _source_digest() -> bytes:
    """facesim's own source, every module: the shapes follow from all of its physics."""
    package = Path(__file__).resolve().parents[1]
    return b"".join(p.read_bytes() for p in sorted(package.rglob("*.py")))


def check_head(spec) -> None:
    """InputError unless ``spec``'s face is a head: a rig, its curves and a point cache are
    a head's (a face mask has no figure to bake or cache)."""
    from ..face.figure import figure_for
    from .simulate import model_for

    if figure_for(model_for(spec)) is None:
        raise InputError(f"{spec.source}: mesh: {spec.mesh_path.name} is a face mask; the rig, its curves and point "
                         "caches are a head's (ICT's, --identity or --face)")


def bake(spec) -> Shapes:
    """ARKit's 52 shapes on the head of ``spec`` (facesim.animation.spec.Spec: its mesh,
    muscles, material, identity or face directory; its motion is ignored), kept in
    facesim's cache (facesim.cache) by everything they follow from."""
    from .. import cache
    from .simulate import model_for

    check_head(spec)
    model = model_for(spec)
    parts = [_source_digest(), model.rest_position.tobytes(), model.faces.tobytes(), spec.muscles_path.read_bytes(),
             spec.material.model_dump_json().encode()]
    stored = cache.cached_arrays("arkit-shapes", cache.key(*parts), lambda: _baked(spec), keep=4)
    return Shapes(ARKIT_52, stored["rest"].astype(np.float64), stored["deltas"])


@dataclass(frozen=True)
class Fit:
    """Weights (frames, S) in [0, 1], and the playback's error per frame over ICT's face
    area (cm): the root mean square and the largest of the vertices' distances."""

    weights: np.ndarray
    rms: np.ndarray
    largest: np.ndarray


def _fit(shapes: Shapes, weights, frames) -> Fit:
    """A Fit of ``weights`` (frames, S) to ``frames``: each frame's playback error over the
    face area, played on the face area's rows alone."""
    face = slice(0, min(FACE_AREA, len(shapes.rest)))
    errors = [np.linalg.norm(shapes.rest[face] + np.tensordot(w, shapes.deltas[:, face], axes=1) - x[face], axis=1)
              for w, x in zip(weights, frames)]
    return Fit(np.asarray(weights, dtype=np.float64).reshape(-1, len(shapes.names)),
               np.array([np.sqrt(np.mean(e ** 2)) for e in errors]), np.array([e.max() for e in errors]))


def fit_weights(shapes: Shapes, frames) -> Fit:
    """The weights of ``shapes`` closest to each of ``frames`` ((N, 3) heads, as ``unturned``
    gives them), bounded to [0, 1] (module docstring)."""
    from scipy.linalg import cho_factor, solve_triangular
    from scipy.optimize import lsq_linear

    rows = np.unique(np.concatenate([shapes.moved(k) for k in range(len(shapes.names))]))
    a = shapes.deltas[:, rows].reshape(len(shapes.names), -1).astype(np.float64).T  # (3k, S)
    normal = a.T @ a
    normal[np.diag_indices_from(normal)] += 1e-9 * np.trace(normal) / len(normal)  # a shape that moves nothing
    factor = cho_factor(normal, lower=False)[0]
    upper = np.triu(factor)
    frames = [np.asarray(x, dtype=np.float64) for x in frames]
    weights = [lsq_linear(upper, solve_triangular(upper, a.T @ (x[rows] - shapes.rest[rows]).ravel(), trans="T"),
                          bounds=(0.0, 1.0), method="bvls").x for x in frames]
    return _fit(shapes, weights, frames)


#: A clip's playback is made faithful (``with_correctives``) until its error over the face
#: area is within these (cm): 0.45 mm RMS and 1.8 mm at most, inside issue 47's bounds (0.5 and 2 mm) ...
FAITHFUL_RMS, FAITHFUL_LARGEST = 0.045, 0.18
#: The correctives' names: this and their number from 1.
CORRECTIVE = "corrective_"
#: ... with at most this many correctives, found from at most SAMPLED of its frames ...
MOST_CORRECTIVES, SAMPLED = 8, 240
#: ... each holding only the vertices it moves at least as far as one of these (cm: 1.5 to
#: 0.05 mm): of the components and the least motion kept that bring the playback within
#: the bounds, the ones that store the fewest numbers (``_stored``), since a corrective's
#: size in the file follows the vertices it holds (happy's three over every vertex they
#: move by 0.05 mm: 213 KB in the GLB, 0.16 mm RMS; as chosen: 41 KB, 0.41 mm RMS).
CORRECTIVE_MOVED = (1.5e-1, 1.25e-1, 1e-1, 8e-2, 5e-2, 3e-2, 2e-2, 1e-2, 5e-3)
#: ... and kept to this step (cm): a normalised 16-bit integer's in metres (1/32767 m, 0.03
#: mm), as the GLB stores a corrective (facesim.export.gltf, KHR_mesh_quantization), so that
#: the fit's error is the error of what is written.
CORRECTIVE_STEP = 100.0 / 32767


def _faithful(errors: np.ndarray) -> bool:
    """Whether (frames, vertices) playback errors over the face area are within the bounds."""
    return np.sqrt(np.mean(errors ** 2, axis=1)).max() <= FAITHFUL_RMS and errors.max() <= FAITHFUL_LARGEST


def _stored(deltas: list) -> int:
    """Numbers a GLB stores for corrective ``deltas``: three values a vertex each holds, and
    an index a vertex for each distinct set of vertices (a component and its opposite share
    one: facesim.export.gltf)."""
    rows = {np.flatnonzero(np.any(d != 0, axis=1)).tobytes() for d in deltas}
    return sum(3 * int(np.any(d != 0, axis=1).sum()) for d in deltas) + sum(len(r) // 8 for r in rows)


def _correctives(directions: np.ndarray, coefficients: np.ndarray, moved: float) -> list[np.ndarray]:
    """The corrective shapes (N, 3) of principal ``directions`` (c, 3N) played with
    ``coefficients`` (frames, c): each scaled to the largest coefficient (its weight peaks
    at 1), split in two (it and its opposite) where its coefficient changes sign (every
    weight in [0, 1]: ``_refitted`` finds them), holding the vertices it moves at least
    ``moved``, on ``CORRECTIVE_STEP``."""
    deltas = []
    for direction, c in zip(directions, coefficients.T):
        scale = np.abs(c).max()
        for sign in (1.0, -1.0):
            if np.maximum(sign * c, 0.0).max() > 0.01 * max(scale, 1e-12):
                delta = (sign * scale * direction).reshape(-1, 3)
                delta[np.linalg.norm(delta, axis=1) < moved] = 0.0
                if delta.any():
                    deltas.append((np.rint(delta / CORRECTIVE_STEP) * CORRECTIVE_STEP).astype(np.float32))
    return deltas


def _refitted(deltas: list, residuals) -> np.ndarray:
    """(frames, d) the weights in [0, 1] of corrective ``deltas`` (d of (N, 3)) closest to
    each of ``residuals`` ((N, 3) each): bounded least squares, as ``fit_weights``, since a
    corrective cut to the vertices it holds is no longer the component it was cut from."""
    from scipy.linalg import cho_factor, solve_triangular
    from scipy.optimize import lsq_linear

    d = np.stack(deltas).reshape(len(deltas), -1).astype(np.float64)
    normal = d @ d.T
    normal[np.diag_indices_from(normal)] += 1e-9 * np.trace(normal) / len(normal)
    upper = np.triu(cho_factor(normal, lower=False)[0])
    return np.array([lsq_linear(upper, solve_triangular(upper, d @ np.ravel(r), trans="T"), bounds=(0.0, 1.0),
                                method="bvls").x for r in residuals]).reshape(-1, len(deltas))


def with_correctives(shapes: Shapes, frame_at, frames: int, fit: Fit) -> tuple[Shapes, Fit]:
    """``shapes`` and ``fit`` extended by corrective shapes for one clip, so that playing
    the weights back is faithful to the clip's own ``frames`` (``frame_at(k)``: (N, 3)).

    What the 52 shapes miss is mostly motion outside their span, not two shapes that fail
    to add up: baking each left-right pair together and adding its difference as a
    product-driven corrective moved happy's worst vertex only from 4.25 to 3.87 mm (the
    nasolabial fold, where its muscles pull that no single ARKit shape does; surprise's,
    the middle of the forehead). The residual of a clip lies in few directions (happy's
    first two principal components hold 97% of it), so those are its correctives: the
    principal components of its residual over the head (from up to ``SAMPLED`` frames),
    those that bring the playback within ``FAITHFUL_RMS`` and ``FAITHFUL_LARGEST`` (at
    most ``MOST_CORRECTIVES``) in the fewest numbers stored (``CORRECTIVE_MOVED``), every
    weight in [0, 1] as an engine's sliders expect (``_correctives``); the fit's error is
    measured with them as kept. Named ``corrective_1``, ``corrective_2``, ... (``CORRECTIVE``).
    """
    if frames == 0:
        return shapes, fit
    face = np.arange(min(FACE_AREA, len(shapes.rest)))
    sample = np.unique(np.linspace(0, frames - 1, min(frames, SAMPLED)).astype(int))
    residual = np.stack([(frame_at(k) - shapes.played(fit.weights[k])).astype(np.float32) for k in sample])
    if _faithful(np.linalg.norm(residual[:, face], axis=2)):
        return shapes, fit
    _, _, directions = np.linalg.svd(residual.reshape(len(sample), -1), full_matrices=False)
    projected = residual.reshape(len(sample), -1) @ directions.T
    best, smallest = None, np.inf
    for count in range(1, min(MOST_CORRECTIVES, len(directions)) + 1):
        if best is not None and count > best[0] + 1:  # one more component than the fewest faithful: enough
            break
        for moved in CORRECTIVE_MOVED:
            deltas = _correctives(directions[:count], projected[:, :count], moved)
            if not deltas or _stored(deltas) >= smallest:
                continue
            left = residual - np.tensordot(_refitted(deltas, residual), np.stack(deltas), axes=1)
            if _faithful(np.linalg.norm(left[:, face], axis=2)):
                best, smallest = (count, moved), _stored(deltas)
    if best is None:  # as faithful as MOST_CORRECTIVES make it
        best = min(MOST_CORRECTIVES, len(directions)), CORRECTIVE_MOVED[-1]
    count, moved = best
    basis = directions[:count].astype(np.float64)
    coefficients = np.empty((frames, count))
    for k in range(frames):
        coefficients[k] = basis @ (frame_at(k) - shapes.played(fit.weights[k])).ravel()
    deltas = _correctives(basis, coefficients, moved)
    weights = _refitted(deltas, (frame_at(k) - shapes.played(fit.weights[k]) for k in range(frames)))
    names = tuple(f"{CORRECTIVE}{k + 1}" for k in range(len(deltas)))
    extended = Shapes(shapes.names + names, shapes.rest, np.concatenate([shapes.deltas, np.stack(deltas)]))
    return extended, _fit(extended, np.column_stack([fit.weights, weights]), map(frame_at, range(frames)))
