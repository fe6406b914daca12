"""A face from its files: a mesh read (OBJ, anything trimesh reads, or the ICT head's
archive with an identity) and checked as `facesim mesh info` checks it, written back as
OBJ, and the model of a mesh, its muscle file and a material, built once per process.
"""

from __future__ import annotations

from functools import lru_cache
from pathlib import Path

import numpy as np

from ..config import DEGENERATE_AREA, LENGTH_EPS
from ..errors import InputError
from ..physics.mesh import FaceMesh, triangle_normals
from ..physics.model import Model
from ..physics.muscles import MuscleSet
from .material import MaterialSpec, face_model
from .muscle_file import load_muscles


def diagnose(mesh: FaceMesh) -> list[str]:
    """What stops a mesh from being a facesim face: each problem as one sentence. Run on
    every mesh before it is simulated, and by `facesim mesh info`."""
    problems = []
    v, f = mesh.vertices, mesh.faces
    if not np.isfinite(v).all():
        return [f"{int((~np.isfinite(v).all(axis=1)).sum())} vertices have non-finite coordinates (NaN or inf)"]
    repeated = (f[:, 0] == f[:, 1]) | (f[:, 1] == f[:, 2]) | (f[:, 0] == f[:, 2])
    if repeated.any():
        problems.append(f"{int(repeated.sum())} triangles repeat a corner (the first, triangle {np.flatnonzero(repeated)[0]})")
    scale = max(float(np.ptp(v, axis=0).max()), LENGTH_EPS)
    flat = (mesh.face_areas < DEGENERATE_AREA * scale**2) & ~repeated
    if flat.any():
        problems.append(f"{int(flat.sum())} triangles have no area (the first, triangle {np.flatnonzero(flat)[0]}): "
                        "a vertex lies on another or on its opposite edge")
    unused = np.setdiff1d(np.arange(len(v)), f)
    if len(unused):
        problems.append(f"{len(unused)} vertices belong to no triangle (the first, vertex {unused[0]})")
    if problems:  # the checks below assume a proper triangle mesh
        return problems
    counts = mesh.edge_face_count
    if (counts > 2).any():
        problems.append(f"{int((counts > 2).sum())} non-manifold edges (shared by more than two triangles)")
    directed = mesh.faces[:, [0, 1, 1, 2, 2, 0]].reshape(-1, 2)
    _, repeats = np.unique(directed, axis=0, return_counts=True)
    if (repeats > 1).any():
        problems.append(f"{int((repeats > 1).sum())} edges run the same way in both their triangles: "
                        "some triangles are flipped against their neighbours")
    if not mesh.boundary_loops:
        problems.append("no boundary: a closed head; facesim animates an open face mask whose rim it pins")
    pieces = mesh.connected_components()
    if pieces > 1:
        problems.append(f"{pieces} separate pieces; a face is one surface")
    height = float(np.ptp(mesh.vertices[:, 1]))
    if not 5.0 <= height <= 50.0:
        problems.append(f"{height:g} units tall: expected centimetres (a face is about 15-20 cm); wrong units?")
    normal = (triangle_normals(mesh.vertices, mesh.faces) * mesh.face_areas[:, None]).sum(axis=0)
    if normal[2] <= 0:
        problems.append("the triangles face away from +z: the face should look toward +z with +y up")
    return problems


def check_face(mesh: FaceMesh, source) -> FaceMesh:
    """The mesh, if `diagnose` finds nothing wrong with it; else an InputError naming
    ``source`` and the first problem."""
    problems = diagnose(mesh)
    if problems:
        more = f" (and {len(problems) - 1} more: facesim mesh info {source})" if len(problems) > 1 else ""
        raise InputError(f"{source}: not usable as a face: {problems[0]}{more}")
    return mesh


def load_face(path: str | Path, identity=None) -> FaceMesh:
    """A mesh to simulate: read, then checked as `facesim mesh info` checks it."""
    return check_face(load_mesh(path, identity), path)


def _read_obj(path: Path) -> tuple[np.ndarray, np.ndarray]:
    """Vertices and triangles of a Wavefront OBJ (polygons split into fans), without
    reordering: a fast path that spares importing trimesh for facesim's own meshes."""
    vertices, faces = [], []
    for line in path.read_text().splitlines():
        if line.startswith("v "):
            vertices.append([float(v) for v in line.split()[1:4]])
        elif line.startswith("f "):
            corners = [int(c.split("/")[0]) for c in line.split()[1:]]
            corners = [c - 1 if c > 0 else len(vertices) + c for c in corners]
            faces.extend([corners[0], corners[k], corners[k + 1]] for k in range(1, len(corners) - 1))
    return np.array(vertices, dtype=np.float64).reshape(-1, 3), np.array(faces, dtype=np.int64).reshape(-1, 3)


def load_mesh(path: str | Path, identity=None) -> FaceMesh:
    """Read a face mesh (OBJ, PLY, GLB, anything trimesh reads) without reordering vertices,
    or a head archive (facesim.face.head, with an ``identity``)."""
    path = Path(path)
    if not path.is_file():
        raise InputError(f"{path}: mesh file not found")
    if path.suffix.lower() == ".npz":  # a head: its simulation mesh, which keeps the head
        from ..config import HOPPER_MESH
        from .head import load_head

        return load_head(path, identity).simulation_mesh(load_mesh(HOPPER_MESH))
    if identity is not None:
        raise InputError(f"identity: only a head (.npz, such as the default) has identities, not {path}")
    try:
        if path.suffix.lower() == ".obj":
            vertices, faces = _read_obj(path)
        else:
            import trimesh

            loaded = trimesh.load(path, process=False, force="mesh")
            if path.suffix.lower() == ".stl":  # a soup of separate triangles: STL has no shared vertices to keep
                loaded.merge_vertices()
            vertices, faces = np.asarray(loaded.vertices), np.asarray(loaded.faces)
    except Exception as exc:  # unreadable files raise many kinds of error
        raise InputError(f"{path}: not a readable mesh ({type(exc).__name__}: {exc})") from None
    if len(faces) == 0 or len(vertices) < 3:
        raise InputError(f"{path}: no triangles in the mesh")
    if faces.max() >= len(vertices) or faces.min() < 0:
        raise InputError(f"{path}: a triangle refers to a vertex that does not exist")
    bad = np.flatnonzero(~np.isfinite(vertices).all(axis=1))
    if len(bad):
        raise InputError(f"{path}: {len(bad)} vertices have non-finite coordinates (NaN or inf), the first vertex {bad[0]}")
    return FaceMesh(vertices, faces)


def obj_text(mesh: FaceMesh, header: str = "") -> str:
    """A mesh as OBJ text with 9 significant digits (whatever its units: a face in metres
    or kilometres keeps its shape), a commented header first."""
    lines = [f"# {line}" for line in header.splitlines()]
    lines += [f"v {x:.9g} {y:.9g} {z:.9g}" for x, y, z in mesh.vertices]
    lines += [f"f {a + 1} {b + 1} {c + 1}" for a, b, c in mesh.faces]
    return "\n".join(lines) + "\n"


def write_obj(path: str | Path, mesh: FaceMesh, header: str = "", replace: bool = True) -> None:
    """Write an OBJ atomically (facesim.files)."""
    from ..files import atomic_path

    with atomic_path(path, replace=replace) as tmp:
        tmp.write_text(obj_text(mesh, header))


@lru_cache(maxsize=8)
def _mesh_and_muscles(mesh_path: Path, muscles_path: Path, identity=None) -> tuple[FaceMesh, MuscleSet]:
    mesh = load_face(mesh_path, identity)  # the checks of `facesim mesh info`, before any simulation
    return mesh, load_muscles(muscles_path, mesh)


@lru_cache(maxsize=8)
def load_face_model(mesh_path: Path, muscles_path: Path, material: MaterialSpec = MaterialSpec(), identity=None) -> Model:
    """The model of a mesh file, its muscle file and a material as a spec gives it (over
    the muscle file's), for an identity of a head; built once per process for each (the
    eight latest kept)."""
    return face_model(*_mesh_and_muscles(mesh_path, muscles_path, identity), material)
