"""ICT FaceKit's scanned head (USC ICT, MIT licence), facesim's default face.

``meshes/ict/head.npz`` (written by ``scripts/build_ict_head.py`` from the upstream data)
holds the generic neutral head in ICT's own vertex order: face, scalp and neck, mouth and
eye sockets, gums and tongue, 32 teeth, eyeballs with sclera and iris, lacrimal fluid,
eye blend and occlusion shells and eyelashes, with its UV layout and the 100 identity
modes of ICT's model (a new person is neutral + Σ wᵢ · modeᵢ, wᵢ drawn from the standard
normal distribution).

The thesis's single-layer skin is simulated on a face of MediaPipe's 468-landmark
topology, the scale of the thesis's 612-node face: the Hopper face brought onto the head
by a similarity fitted to where MediaPipe finds its landmarks on the head
(:meth:`Head.simulation_mesh`). Landmark k moves the head's vertex ``landmarks[k]`` and
the head's 9,409-vertex face area follows (facesim.face.figure). Measured against simulating
the face area itself (9,409 vertices, 10 sub-steps): happy takes 0.75 s there against
0.03 s, and folds 12 triangles at the lip corners (and surprise 14 in the forehead,
blink 58 in the lids) under the same muscles and material; MediaPipe's measured
landmarks on the head, used as the simulation mesh directly, make lip-corner slivers of
0.1 degree that fold at once. The Hopper face's geometry is the one the material was
tuned on and folds nothing.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import lru_cache
from pathlib import Path

import numpy as np

from ..errors import InputError
from ..physics.mesh import FaceMesh

#: How many identity modes the head has (all of ICT's).
IDENTITY_MODES = 100
#: How far explicit identity weights may go, in standard deviations of ICT's modes (ICT
#: draws each weight from the standard normal distribution). Beyond ``IDENTITY_LIMIT`` on
#: any mode, or ``IDENTITY_NORM_LIMIT`` for the weights' length (a hundred standard
#: normal draws have length 10.0 +- 0.7: 15 is seven of its deviations out), the head is
#: no person's: weights of 5 on every mode tore and crossed its surface, and of 10 or more
#: its mirror map broke. Beyond ``IDENTITY_NOTICE`` on any mode a run says so, once:
#: one draw in 2,000 goes that far, and the head is then unusual, not broken. A seed's
#: weights are ICT's own sampling and are not bounded.
IDENTITY_LIMIT, IDENTITY_NORM_LIMIT, IDENTITY_NOTICE = 4.5, 15.0, 3.5


def identity_problem(weights: np.ndarray) -> str | None:
    """Why explicit identity weights (k,) are no plausible person, or None."""
    weights = np.asarray(weights, dtype=np.float64)
    if not np.isfinite(weights).all():
        return f"weight {int(np.flatnonzero(~np.isfinite(weights))[0])} is not a finite number"
    worst = int(np.argmax(np.abs(weights))) if len(weights) else 0
    if len(weights) and abs(weights[worst]) > IDENTITY_LIMIT:
        return (f"weight {worst} is {weights[worst]:g}, beyond {IDENTITY_LIMIT:g} standard deviations of ICT's mode "
                "(each is drawn from the standard normal)")
    if np.linalg.norm(weights) > IDENTITY_NORM_LIMIT:
        return (f"the weights' length is {np.linalg.norm(weights):.3g}, beyond {IDENTITY_NORM_LIMIT:g} (a person's is "
                "about 10: a hundred standard normal draws)")
    return None


def identity_notice(identity) -> str | None:
    """A line for explicit weights past ``IDENTITY_NOTICE`` on some mode, or None."""
    if identity is None or isinstance(identity, (int, np.integer)):
        return None
    weights = np.asarray(identity, dtype=np.float64)
    far = np.flatnonzero(np.abs(weights) > IDENTITY_NOTICE)
    if len(far):
        return (f"identity: {len(far)} weights beyond {IDENTITY_NOTICE:g} standard deviations (weight {far[0]} is "
                f"{weights[far[0]]:g}): an unusual head")
    return None


@dataclass(frozen=True)
class Head:
    """One person's head. vertices : (N, 3) float64 cm; triangles : (t, 3) int64;
    triangle_material : (t,) int; materials : names; parts : name -> (first, last)
    inclusive vertex range; uv : (u, 2); triangle_uv : (t, 3); identity : (100,) weights;
    neutral : (N, 3) the generic head this one is the identity of."""

    vertices: np.ndarray
    neutral: np.ndarray
    triangles: np.ndarray
    triangle_material: np.ndarray
    materials: tuple[str, ...]
    parts: dict
    uv: np.ndarray
    triangle_uv: np.ndarray
    identity: np.ndarray
    landmarks: np.ndarray
    landmark_vertex: np.ndarray
    landmark_weight: np.ndarray

    def part(self, name: str) -> np.ndarray:
        """(k,) int64: the vertices of one part."""
        first, last = self.parts[name]
        return np.arange(first, last + 1)

    def triangles_of(self, *materials: str) -> np.ndarray:
        """The triangles of the given OBJ material groups (M_Face, M_Teeth, ...)."""
        keep = np.isin(self.triangle_material, [self.materials.index(m) for m in materials])
        return self.triangles[keep]

    @property
    def face_count(self) -> int:
        """Vertices of the simulated skin: the face area, the first vertices of the head."""
        return self.parts["face"][1] + 1

    def face_mesh(self) -> FaceMesh:
        """The skin: the face area's vertices (ICT's indices) and triangles."""
        return FaceMesh(self.vertices[: self.face_count], self.triangles_of("M_Face"))

    @property
    def landmark_positions(self) -> np.ndarray:
        """(468, 3): where MediaPipe's landmarks lie on this head (ICT's measurement,
        made symmetric, carried by the identity)."""
        return np.einsum("kj,kjd->kd", self.landmark_weight, self.vertices[self.landmark_vertex])

    def simulation_mesh(self, mask: FaceMesh) -> "HeadMesh":
        """The simulated skin: ``mask`` (a face of MediaPipe's topology, the Hopper face)
        brought onto the head by the similarity that best fits its landmarks to the head's,
        then made exactly symmetric about x = 0 (the fit leaves it 1e-5 cm off, enough to
        make left and right muscles differ by round-off)."""
        from ..physics.mesh import mirror_map
        from .align import similarity
        scale, rotation, translation = similarity(mask.vertices, self.landmark_positions)
        placed = scale * mask.vertices @ rotation.T + translation
        placed = 0.5 * (placed + placed[mirror_map(placed, mask.faces)] * np.array([-1.0, 1.0, 1.0]))
        return HeadMesh(placed, mask.faces, self)

    def eyeball(self, side: str) -> tuple[np.ndarray, float]:
        """Centre (3,) and radius of the eyeball on ``side`` ('left' or 'right'): the
        least-squares sphere through its sclera's vertices."""
        points = self.vertices[self.part(f"eyeball_{side}")]
        a = np.column_stack([2 * points, np.ones(len(points))])
        solution = np.linalg.lstsq(a, (points**2).sum(axis=1), rcond=None)[0]
        return solution[:3], float(np.sqrt(solution[3] + solution[:3] @ solution[:3]))


class HeadMesh(FaceMesh):
    """The simulation mesh of a head, which keeps the head it drives: the renderer draws
    the head (facesim.face.figure)."""

    def __init__(self, vertices: np.ndarray, faces: np.ndarray, head: Head):
        super().__init__(vertices, faces)
        self.head = head


@lru_cache(maxsize=2)
def _archive(path: Path) -> dict:
    try:
        with np.load(path) as data:
            return {key: data[key] for key in data.files if key != "identity_deltas"}
    except (OSError, ValueError, KeyError) as exc:
        raise InputError(f"{path}: not a readable head archive ({exc})") from None


@lru_cache(maxsize=2)
def _identity_deltas(path: Path) -> np.ndarray:
    with np.load(path) as data:
        return data["identity_deltas"]


def identity_weights(identity: int | list[float] | None) -> np.ndarray:
    """(100,) weights of the identity modes: none (the generic head), a seed (weights drawn
    from the standard normal distribution, as ICT samples faces) or explicit weights
    (missing ones are 0)."""
    weights = np.zeros(IDENTITY_MODES)
    if identity is None:
        return weights
    if isinstance(identity, (int, np.integer)):
        if identity < 0:
            raise InputError(f"identity: a seed must be a non-negative integer, got {identity}")
        return np.random.default_rng(int(identity)).standard_normal(IDENTITY_MODES)
    values = np.asarray(identity, dtype=np.float64)
    if values.ndim != 1 or len(values) > IDENTITY_MODES:
        raise InputError(f"identity: expected a seed or at most {IDENTITY_MODES} finite weights, got {len(values)} values")
    problem = identity_problem(values)  # finite, and a person's
    if problem:
        raise InputError(f"identity: {problem}")
    weights[: len(values)] = values
    return weights


def load_head(path: str | Path, identity: int | list[float] | tuple[float, ...] | None = None) -> Head:
    """The head in ``path`` (a head.npz) with an identity (see :func:`identity_weights`)."""
    path = Path(path).resolve()
    if not path.is_file():
        raise InputError(f"{path}: head archive not found")
    data = _archive(path)
    weights = identity_weights(list(identity) if isinstance(identity, tuple) else identity)
    neutral = data["neutral"].astype(np.float64)
    vertices = neutral
    if weights.any():
        deltas = _identity_deltas(path)
        used = np.flatnonzero(weights)
        vertices = neutral + np.tensordot(weights[used], deltas[used].astype(np.float32), axes=1)
    parts = {str(n): (int(a), int(b)) for n, (a, b) in zip(data["part_names"], data["part_ranges"])}
    return Head(
        vertices=vertices,
        neutral=neutral,
        triangles=data["triangles"].astype(np.int64),
        triangle_material=data["triangle_material"].astype(np.int64),
        materials=tuple(str(m) for m in data["materials"]),
        parts=parts,
        uv=data["uv"],
        triangle_uv=data["triangle_uv"].astype(np.int64),
        identity=weights,
        landmarks=data["landmarks"].astype(np.int64),
        landmark_vertex=data["landmark_vertex"].astype(np.int64),
        landmark_weight=data["landmark_weight"].astype(np.float64),
    )
