"""Bringing a face mesh of any topology (a scan, an artist's head, a subdivided face) into
the default face's frame, so that the default muscle file fits it by position.

The user names a handful of landmarks on their mesh (``NAMED_LANDMARKS``: nose tip, eye
and mouth corners, chin, ...), as vertex indices or points; ``align`` finds the
similarity transform (scale, rotation, translation; Umeyama's least-squares fit) that
carries them onto the same landmarks of the default face and applies it to the whole mesh,
which then has the default face's units (cm) and axes (+y up, +z toward the viewer, +x the
subject's left). ``propose_landmarks`` helps pick them on a mesh that is already roughly
upright and facing +z: it matches bounding boxes and takes the nearest vertex to each of
the default face's landmarks, for the user to check and correct.

Muscles then come from the default muscle file carried by position
(``muscles.muscles_as_points``); they snap to the aligned mesh's nearest vertices, and the
outer rim is pinned from the mesh's own boundary.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from ..errors import InputError
from ..physics.mesh import FaceMesh
from ..schema import read_yaml

#: Landmarks a user can name on their mesh, with their index on the default face.
NAMED_LANDMARKS = {
    "forehead": 10, "glabella": 9, "nasion": 168, "nose_tip": 4, "subnasale": 2,
    "eye_outer_r": 33, "eye_inner_r": 133, "eye_inner_l": 362, "eye_outer_l": 263,
    "mouth_corner_r": 61, "mouth_corner_l": 291, "upper_lip": 0, "lower_lip": 17, "chin": 152,
    "cheekbone_r": 123, "cheekbone_l": 352,
}
#: Fewer landmarks than this do not pin down a rotation with any margin.
MIN_LANDMARKS = 4


def similarity(source: np.ndarray, target: np.ndarray) -> tuple[float, np.ndarray, np.ndarray]:
    """Scale s, rotation R and translation t minimising Σ |s R p + t - q|² (Umeyama 1991)."""
    mu_p, mu_q = source.mean(axis=0), target.mean(axis=0)
    p, q = source - mu_p, target - mu_q
    u, singular, vt = np.linalg.svd(q.T @ p / len(p))
    sign = np.diag([1.0, 1.0, np.sign(np.linalg.det(u @ vt)) or 1.0])
    rotation = u @ sign @ vt
    scale = float(np.trace(np.diag(singular) @ sign) / (p**2).sum(axis=1).mean())
    return scale, rotation, mu_q - scale * rotation @ mu_p


def load_landmarks(path: Path, mesh: FaceMesh) -> dict[str, np.ndarray]:
    """A YAML mapping of landmark names to vertex indices or [x, y, z] points on ``mesh``."""
    data = read_yaml(path)
    if not isinstance(data, dict):
        raise InputError(f"{path}: expected a mapping of landmark names to vertices")
    points = {}
    for name, value in data.items():
        if name not in NAMED_LANDMARKS:
            raise InputError(f"{path}: {name}: unknown landmark (known: {', '.join(NAMED_LANDMARKS)})")
        if isinstance(value, int) and not isinstance(value, bool):
            if not 0 <= value < mesh.vertex_count:
                raise InputError(f"{path}: {name}: vertex {value} does not exist (mesh has {mesh.vertex_count})")
            points[name] = mesh.vertices[value]
        elif isinstance(value, list) and len(value) == 3 and all(isinstance(c, (int, float)) for c in value):
            points[name] = np.array(value, dtype=float)
        else:
            raise InputError(f"{path}: {name}: expected a vertex index or [x, y, z], got {value!r}")
    if len(points) < MIN_LANDMARKS:
        raise InputError(f"{path}: name at least {MIN_LANDMARKS} landmarks, got {len(points)}")
    return points


def align(mesh: FaceMesh, landmarks: dict[str, np.ndarray], reference: FaceMesh) -> tuple[FaceMesh, np.ndarray]:
    """``mesh`` moved, turned and scaled onto ``reference`` (the default face) by its named
    landmarks. Returns the aligned mesh and each landmark's residual distance (cm)."""
    names = list(landmarks)
    source = np.array([landmarks[n] for n in names])
    target = reference.vertices[[NAMED_LANDMARKS[n] for n in names]]
    if np.linalg.matrix_rank(source - source.mean(axis=0), tol=1e-6 * np.ptp(source)) < 3:
        raise InputError("landmarks: they lie on a line or a plane; name some off it (nose_tip with eye and mouth corners)")
    scale, rotation, translation = similarity(source, target)
    moved = FaceMesh(mesh.vertices @ rotation.T * scale + translation, mesh.faces)
    residual = np.linalg.norm(source @ rotation.T * scale + translation - target, axis=1)
    return moved, residual


def propose_landmarks(mesh: FaceMesh, reference: FaceMesh) -> dict[str, tuple[int, float]]:
    """For a mesh roughly upright and facing +z: each named landmark's nearest vertex after
    matching the bounding boxes' centres and heights, with its distance (in the
    reference's cm) to the landmark."""
    low, high = mesh.vertices.min(axis=0), mesh.vertices.max(axis=0)
    ref_low, ref_high = reference.vertices.min(axis=0), reference.vertices.max(axis=0)
    scale = (ref_high[1] - ref_low[1]) / max(high[1] - low[1], 1e-12)
    moved = (mesh.vertices - (low + high) / 2) * scale + (ref_low + ref_high) / 2
    out = {}
    for name, index in NAMED_LANDMARKS.items():
        distance = np.linalg.norm(moved - reference.vertices[index], axis=1)
        nearest = int(np.argmin(distance))
        out[name] = (nearest, float(distance[nearest]))
    return out
