"""The single-layer face mesh (thesis section 3.1.1): vertices, triangles and the
topology derived from them.

A :class:`FaceMesh` is a thin, immutable holder of two arrays; everything derived
(unique edges, boundary loops, vertex neighbours, incident triangles, the mirror map) is
computed on first use and cached read-only, in the spirit of trimesh.
"""

from __future__ import annotations

from functools import cached_property
from pathlib import Path

import numpy as np


def _readonly(a: np.ndarray) -> np.ndarray:
    a.flags.writeable = False
    return a


def csr_from_pairs(rows: np.ndarray, cols: np.ndarray, n: int) -> tuple[np.ndarray, np.ndarray]:
    """Compressed-row lists: ``cols[start[i]:start[i+1]]`` are the entries of row ``i``.

    rows, cols : (k,) int; returns start : (n+1,) int64, index : (k,) int64 sorted by row.
    """
    order = np.lexsort((cols, rows))
    start = np.zeros(n + 1, dtype=np.int64)
    np.add.at(start, rows + 1, 1)
    return np.cumsum(start), cols[order].astype(np.int64)


def inverse_permutation(order: np.ndarray) -> np.ndarray:
    """``place`` with ``place[order[k]] = k``: where each item of an order sits in it."""
    place = np.empty_like(order)
    place[order] = np.arange(len(order))
    return place


def component_labels(edges: np.ndarray, n: int) -> np.ndarray:
    """(n,) each vertex's connected component of the graph of ``edges`` (e, 2), labelled by
    its smallest vertex: each vertex takes the smallest label among its neighbours' until
    none changes (as many rounds as the graph is wide: 15 on the head's skin). Every mesh
    is checked when it loads, and SciPy's graph module took 0.05-0.07 s of a warm render
    to import for it."""
    label = np.arange(n)
    while True:
        smaller = label.copy()
        np.minimum.at(smaller, edges[:, 0], label[edges[:, 1]])
        np.minimum.at(smaller, edges[:, 1], label[edges[:, 0]])
        if np.array_equal(smaller, label):
            return label
        label = smaller


def unique_edges(faces: np.ndarray) -> np.ndarray:
    """(e, 2) int64: the unique undirected edges of triangles, smaller index first."""
    e = np.sort(np.asarray(faces)[:, [0, 1, 1, 2, 2, 0]].reshape(-1, 2), axis=1)
    return np.unique(e, axis=0).astype(np.int64)


def smooth_interpolation(edges: np.ndarray, n: int, fixed: np.ndarray, values: np.ndarray, order: int = 1) -> np.ndarray:
    """(n, d) values equal to ``values`` (f, d) on the ``fixed`` vertices and, everywhere
    else on the graph of ``edges``, harmonic (order 1: the mean of their neighbours, the
    Dirichlet problem of the graph Laplacian L) or biharmonic (order 2: minimising |L x|²,
    smooth through the fixed points). Vertices on no edge keep 0."""
    from scipy.sparse import coo_matrix, diags
    from scipy.sparse.linalg import splu

    i, j = np.concatenate([edges[:, 0], edges[:, 1]]), np.concatenate([edges[:, 1], edges[:, 0]])
    adjacency = coo_matrix((np.ones(len(i)), (i, j)), shape=(n, n)).tocsr()
    laplacian = (diags(np.asarray(adjacency.sum(axis=1)).ravel()) - adjacency).tocsr()
    system = (laplacian.T @ laplacian).tocsr() if order == 2 else laplacian
    out = np.zeros((n, values.shape[1]))
    out[fixed] = values
    free = np.setdiff1d(np.unique(edges), fixed)
    if len(free):
        out[free] = splu(system[free][:, free].tocsc()).solve(-(system[free][:, fixed] @ values))
    return out


class FaceMesh:
    """A triangle mesh of a face in centimetres, +x the subject's left, +y up, +z forward.

    vertices : (n, 3) float64; faces : (t, 3) int64, counter-clockwise seen from +z.
    """

    def __init__(self, vertices: np.ndarray, faces: np.ndarray):
        self.vertices = _readonly(np.ascontiguousarray(vertices, dtype=np.float64))
        self.faces = _readonly(np.ascontiguousarray(faces, dtype=np.int64))

    @property
    def vertex_count(self) -> int:
        return len(self.vertices)

    @cached_property
    def edges(self) -> np.ndarray:
        """(e, 2) int64: unique undirected edges, smaller index first."""
        return _readonly(unique_edges(self.faces))

    @cached_property
    def neighbours(self) -> tuple[np.ndarray, np.ndarray]:
        """Vertex one-ring in compressed rows: (start (n+1,), index (2e,))."""
        e = self.edges
        rows = np.concatenate([e[:, 0], e[:, 1]])
        cols = np.concatenate([e[:, 1], e[:, 0]])
        start, index = csr_from_pairs(rows, cols, self.vertex_count)
        return _readonly(start), _readonly(index)

    @cached_property
    def vertex_faces(self) -> tuple[np.ndarray, np.ndarray]:
        """Triangles incident to each vertex in compressed rows: (start (n+1,), face (3t,))."""
        rows = self.faces.reshape(-1)
        cols = np.repeat(np.arange(len(self.faces)), 3)
        start, index = csr_from_pairs(rows, cols, self.vertex_count)
        return _readonly(start), _readonly(index)

    @cached_property
    def edge_face_count(self) -> np.ndarray:
        """(e,) int64: how many triangles share each edge of :attr:`edges`."""
        e = np.sort(self.faces[:, [0, 1, 1, 2, 2, 0]].reshape(-1, 2), axis=1)
        _, counts = np.unique(e, axis=0, return_counts=True)
        return _readonly(counts)

    @cached_property
    def boundary_loops(self) -> list[np.ndarray]:
        """Closed loops of boundary edges (edges with one triangle), longest first."""
        directed = self.faces[:, [0, 1, 1, 2, 2, 0]].reshape(-1, 2)
        key = {tuple(sorted(d)) for d in map(tuple, self.edges[self.edge_face_count == 1])}
        nxt = {int(a): int(b) for a, b in directed if tuple(sorted((a, b))) in key}
        loops, seen = [], set()
        for first in nxt:
            if first in seen:
                continue
            loop, v = [], first
            while v not in seen and v in nxt:
                seen.add(v)
                loop.append(v)
                v = nxt[v]
            loops.append(np.array(loop, dtype=np.int64))
        return sorted(loops, key=len, reverse=True)

    @cached_property
    def face_normals(self) -> np.ndarray:
        """(t, 3) unit normals by the right-hand rule."""
        return _readonly(triangle_normals(self.vertices, self.faces))

    @cached_property
    def face_areas(self) -> np.ndarray:
        v = self.vertices[self.faces]
        return _readonly(0.5 * np.linalg.norm(np.cross(v[:, 1] - v[:, 0], v[:, 2] - v[:, 0]), axis=1))

    @cached_property
    def vertical_axis(self) -> tuple[float, float, float]:
        """(cx, cz, R): the head's vertical axis and radius, see :func:`fit_vertical_axis`."""
        return fit_vertical_axis(self.vertices)

    @cached_property
    def scale(self) -> float:
        """A size of the face in cm: the diagonal of its bounding box."""
        return float(np.linalg.norm(np.ptp(self.vertices, axis=0)))

    def connected_components(self) -> int:
        """How many separate pieces the mesh is (``component_labels``)."""
        return len(np.unique(component_labels(self.edges, self.vertex_count)))


def triangle_normals(vertices: np.ndarray, faces: np.ndarray) -> np.ndarray:
    v = vertices[faces]
    n = np.cross(v[:, 1] - v[:, 0], v[:, 2] - v[:, 0])
    length = np.linalg.norm(n, axis=1, keepdims=True)
    return n / np.where(length > 0, length, 1.0)


def mirror_map(vertices: np.ndarray, faces: np.ndarray | None = None) -> np.ndarray:
    """The landmark mirror map of a face roughly symmetric about x = 0: ``vertices[m]`` is
    the mirror image of ``vertices``.

    Found as the optimal assignment of every vertex to the nearest reflected vertex and
    checked to be an involution; given ``faces``, also checked to send every triangle to a
    triangle. Raises ValueError when a check fails. Kept on disk (facesim.cache), keyed by
    the vertices, the faces and this file: the head's simulated skin is made symmetric
    by it in every process, and the assignment, with SciPy's optimisation package it
    imports, took 0.3 s of a 2.4 s fresh render (2026-12-04).
    """
    from ..cache import cached_arrays, key

    parts = (np.ascontiguousarray(vertices, dtype=np.float64).tobytes(), b"" if faces is None else
             np.ascontiguousarray(faces, dtype=np.int64).tobytes(), Path(__file__).read_bytes())
    # a few kB each, kept for many faces: with 8 kept, a test cycling eleven identities computed each again every time
    m = cached_arrays("mirror-map", key(*parts), lambda: {"map": _assignment(vertices)}, keep=64)["map"]
    if not np.array_equal(m[m], np.arange(len(m))):
        raise ValueError("mirror map is not an involution")
    if faces is not None:
        unmatched = len(mirror_mismatched_faces(faces, m))
        if unmatched:
            raise ValueError(f"mirror map sends {unmatched} triangles to non-triangles")
    return m


def _assignment(vertices: np.ndarray) -> np.ndarray:
    """Each vertex's partner in the optimal assignment to the reflected vertices."""
    from scipy.optimize import linear_sum_assignment
    from scipy.spatial.distance import cdist

    return linear_sum_assignment(cdist(vertices, vertices * np.array([-1.0, 1.0, 1.0])))[1]


def mirror_mismatched_faces(faces: np.ndarray, mapping: np.ndarray) -> np.ndarray:
    """Indices of triangles whose mirror image is not a triangle of the mesh."""
    triangles = {tuple(sorted(t)) for t in faces.tolist()}
    return np.array([i for i, t in enumerate(mapping[faces].tolist()) if tuple(sorted(t)) not in triangles], dtype=np.int64)


def fit_vertical_axis(points: np.ndarray) -> tuple[float, float, float]:
    """Least-squares circle through the (x, z) of the points (Kåsa's fit): the head's
    vertical axis (cx, cz) and the radius R of the cylinder the face wraps around."""
    x, z = points[:, 0], points[:, 2]
    a = np.column_stack([x, z, np.ones_like(x)])
    b, c, e = np.linalg.lstsq(a, x**2 + z**2, rcond=None)[0]
    cx, cz = b / 2, c / 2
    return float(cx), float(cz), float(np.sqrt(e + cx**2 + cz**2))


def subdivide(mesh: FaceMesh, levels: int = 1) -> FaceMesh:
    """Loop subdivision (each level: four triangles per triangle, smoothed positions)."""
    import trimesh

    vertices, faces = mesh.vertices, mesh.faces
    for _ in range(levels):
        vertices, faces = trimesh.remesh.subdivide_loop(vertices, faces, iterations=1)
    return FaceMesh(vertices, faces)
