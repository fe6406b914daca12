"""Building the immutable simulation model from a mesh, its muscles and a material.

``build_model`` collects everything the kernels need as contiguous read-only arrays
(in the spirit of warp.sim's ModelBuilder.finalize): springs on the unique edges with
their rest lengths (eq. 3.6), edge-repulsion pairs (eq. 3.7: each vertex against the
opposite edge of each of its triangles, rest distance the triangle's altitude), the
pinned vertices, neighbour and one-ring lists in compressed rows, and the muscles' rest
geometry in the frame they act in (the 2D projection of eq. 3.21, or 3D when the
projection is switched off). Per-step state (positions, velocities) lives elsewhere.

The 2D projection needs the head's vertical axis and a radius to turn the angle u into a
length: both come from a cylinder fitted to the mesh, so no face needs them by hand.

One material fits any mesh of a face. What depends on the size of the face is already
relative: muscle falloffs are in muscle lengths, spring rest lengths and edge-repulsion
altitudes are the mesh's own, the projection's radius is fitted. What depends on the
mesh's *resolution* is scaled by s, the skin area per vertex relative to the default
face's (``REFERENCE_VERTEX_AREA``; s = 1 there, about 1/4 on a face Loop-subdivided
once): each vertex stands for s times the default's tissue, so its mass, hypodermis and
drive springs and the muscle force it receives are multiplied by s, which keeps the force
per area and the mass per area of the skin; the springs keep k0 (a triangular spring
lattice's sheet stiffness does not depend on its edge length); the non-linearity of eq.
3.6 and 3.7 reads the stretch in units of √s (the edge length relative to the default's);
the thesis's quasi-implicit update takes 1/√s times the sub-steps, since the lighter
vertices on the same springs oscillate √(1/s) times faster and an explicit update is
stable only within their period; and the damping c goes as √s, which keeps the springs'
damping ratio c / (2 √(k0 m)). Damping as s (per area) left the finer mesh's spring
modes half as damped: measured on the default face subdivided once, happy then crept
without settling and folded three lip-corner triangles; with √s it settles and folds
none.

The implicit step (the default) is stable at any step and keeps one per frame of at most
10 ms on any mesh: on the Hopper face subdivided twice (6,990 vertices), one step where
the rule above took four moved the library's specs by 0.07-0.85 mm (1-4% of their
motion), less than four steps against one move them on the face it refines (0.2-2.3 mm,
2-12%), for a quarter of the steps (2026-12-07).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from functools import cached_property

import numpy as np

from ..cache import cached_arrays, key
from ..config import CODE_DIGEST
from ..errors import InputError
from .layout import ModelArrays, workspace
from .material import Material, resolved_material
from .mesh import FaceMesh, csr_from_pairs, inverse_permutation
from .muscles import SPHINCTER, MuscleSet
from .rig import Rig, build_rig

#: The default face's skin area per vertex (cm²): meshes/face.obj's 276.05 cm² over 468
#: vertices. A mesh's resolution scale s is its own area per vertex over this.
REFERENCE_VERTEX_AREA = 0.5898477858884484


@dataclass(frozen=True)
class Model:
    """Arrays of one face, ready for the kernels. Shapes: n vertices, t triangles,
    s springs, r repulsion pairs, M muscles."""

    rest_position: np.ndarray  # (n, 3)
    faces: np.ndarray  # (t, 3)
    rest_normal: np.ndarray  # (t, 3) unit
    rest_area: np.ndarray  # (t,)
    rest_against: np.ndarray  # (t,) bool: faces against the skin around it at rest (checks._against_surroundings)
    pinned: np.ndarray  # (n,) bool
    tie: np.ndarray  # (n,) stiffness tying a tied rim to the bones (muscles.Pinned), 0 elsewhere
    neighbour_start: np.ndarray  # (n+1,)
    neighbour_index: np.ndarray  # (2s,)
    ring_start: np.ndarray  # (n+1,) one-ring triangles (i, ring_a, ring_b), counter-clockwise
    ring_a: np.ndarray  # (3t,)
    ring_b: np.ndarray  # (3t,)
    spring_indices: np.ndarray  # (s, 2)
    spring_end: np.ndarray  # (2, s) the same by rows: the kernels' vector loops read each end's row
    corner: np.ndarray  # (3, t) the triangles' corners by rows (faces transposed), as spring_end
    spring_rest_length: np.ndarray  # (s,)
    repulsion_vertex: np.ndarray  # (r,)
    repulsion_edge: np.ndarray  # (r, 2)
    repulsion_rest_distance: np.ndarray  # (r,)
    hinge: np.ndarray  # (e, 4) interior edges' hinges: the edge's ends, then the two opposite vertices
    hinge_weight: np.ndarray  # (e, 4) their bending stencils (bending._bending_forces)
    muscle_kind: np.ndarray  # (M,) LINEAR or SPHINCTER
    muscle_axes: np.ndarray  # (M, 2) a sphincter's semi-axes in the muscle frame (cm)
    muscle_origin: np.ndarray  # (M, 3) attachment O (a sphincter's centre) at rest, in the muscle frame
    muscle_insertion_point: np.ndarray  # (M, 3) insertion I at rest, in the muscle frame
    muscle_insertion: np.ndarray  # (M,) vertex of I, where the flood fill starts
    muscle_centre_start: np.ndarray  # (M+1,) the vertices whose mean is O, compressed rows
    muscle_centre_index: np.ndarray
    muscle_cos_zone: np.ndarray  # (M,) cos α
    muscle_r: np.ndarray  # (M,) r of eq. 3.3 (cm)
    muscle_r_max: np.ndarray  # (M,) r_max of eq. 3.3 (cm)
    muscle_force: np.ndarray  # (M,) peak force f
    muscle_protrusion: np.ndarray  # (M,) the push along the rest normal per unit of its pull (muscles._Muscle)
    rest_vertex_normal: np.ndarray  # (n, 3) unit, outward: the direction a muscle's protrusion pushes
    axis_x: float
    axis_z: float
    radius: float
    material: Material
    muscles: MuscleSet
    rig: Rig
    scale: float  # bounding-box diagonal of the face, cm
    mesh: FaceMesh | None = field(default=None, repr=False, compare=False)  # a head's simulation mesh keeps its head
    resolution: float = 1.0  # s: skin area per vertex over the default face's (module docstring)
    length_unit: float = 1.0  # √s: the unit of stretch in the non-linear springs
    arrays: ModelArrays | None = field(default=None, repr=False, compare=False)  # all of the above, as the kernels read it
    factors: dict = field(default_factory=dict, repr=False, compare=False)  # the implicit step's, per step size
    # the kernels' order (``reordered``): their vertex k is the mesh's vertex_order[k], their
    # triangle k the mesh's triangle_order[k]; None: the mesh's own
    vertex_order: np.ndarray | None = field(default=None, repr=False, compare=False)
    triangle_order: np.ndarray | None = field(default=None, repr=False, compare=False)

    def preconditioner(self, h: float):
        """The implicit step's factorised preconditioner at step ``h`` for a skin with
        bending (facesim.physics.solver.rest_preconditioner), factorised the first time a run asks
        for it; empty (Jacobi, or the thesis's update) otherwise.

        Kept on disk (facesim.cache), keyed by every array and constant of the model, the
        step and facesim's code: a fresh `facesim render` of the head read it in a few ms
        where factorising took 47 ms and loading the two kernels it runs (the force terms
        and the system's entries, 1.3 MB of compiled code) 177 ms more (2026-12-03)."""
        from .solver import Factor, no_factor, rest_preconditioner

        if not (self.arrays.implicit and self.arrays.bending > 0):
            return no_factor()
        if h not in self.factors:
            parts = [CODE_DIGEST.encode(), np.float64(h).tobytes()]
            for name, value in zip(self.arrays._fields, self.arrays):
                value = np.asarray(value)
                parts.append(f"{name} {value.dtype} {value.shape}".encode() + value.tobytes())
            # 1.1-1.7 MB each on the head: 32 kept, a model's two step sizes for each of the identities a batch cycles
            stored = cached_arrays("preconditioner", key(*parts), lambda: rest_preconditioner(self, h)._asdict(),
                                   keep=32)
            self.factors[h] = Factor(**stored)
        return self.factors[h]

    def in_kernel_order(self, per_vertex: np.ndarray, axis: int = 0) -> np.ndarray:
        """Rows per mesh vertex (along ``axis``) in the kernels' vertex order."""
        return per_vertex if self.vertex_order is None else np.take(per_vertex, self.vertex_order, axis=axis)

    def in_mesh_order(self, per_vertex: np.ndarray, axis: int = 0) -> np.ndarray:
        """Rows per kernel vertex (along ``axis``) in the mesh's vertex order."""
        return per_vertex if self.vertex_order is None else np.take(per_vertex, self._vertex_place, axis=axis)

    @cached_property
    def _vertex_place(self) -> np.ndarray:
        """Where each mesh vertex sits in the kernels' order (found once: a background
        simulation maps every frame back)."""
        return inverse_permutation(self.vertex_order)

    def mesh_vertex(self, k):
        """The mesh's numbers of the kernels' vertices k (a number or an array of them)."""
        return k if self.vertex_order is None else self.vertex_order[k]

    def mesh_triangle(self, k):
        """The mesh's numbers of the kernels' triangles k."""
        return k if self.triangle_order is None else self.triangle_order[k]

    @property
    def vertex_count(self) -> int:
        return len(self.rest_position)

    @property
    def muscle_count(self) -> int:
        return len(self.muscle_force)


def against_surroundings(x: np.ndarray, faces: np.ndarray, normals: np.ndarray) -> np.ndarray:
    """Which triangles face against the skin around them (a few, in the sharpest creases),
    given the surface's vertex normals (``vertex_normals``)."""
    from .checks import _against_surroundings

    x = np.ascontiguousarray(x, dtype=np.float64)
    faces = np.ascontiguousarray(faces, dtype=np.int64)
    return np.array([_against_surroundings(x, faces, t, normals) for t in range(len(faces))], dtype=bool)


#: The strongest muscle a model takes, in centimetres of one skin spring's stretch: a
#: muscle's peak force f (eq. 3.1) over the springs' stiffness k0 is how far it would
#: stretch one spring alone. The calibrated head's strongest muscle is 6.4 cm of it (f =
#: 6,389 against k0 = 1,000). Beyond 100 cm, five faces' widths, no face's muscle pulls:
#: such forces diverged at the first frame, or, from about 1e150, overflowed into a
#: face that moved 0.0 cm while the run reported success.
MUSCLE_STRETCH_LIMIT = 100.0


def build_model(mesh: FaceMesh, muscles: MuscleSet, material: Material = Material(), reorder: bool | None = None) -> Model:
    """The model of a face; ``material`` (for a spec's: facesim.face.material's
    ``over_muscle_file``) is per vertex of the default face and is scaled to this mesh's resolution
    (``Model.material`` is the scaled one). ``reorder``: whether the kernels take the
    mesh's vertices in a cache-friendly order (``reordered``); by default a mesh of at
    least ``REORDER_FROM`` vertices does. InputError, naming the muscle file, for a
    muscle beyond ``MUSCLE_STRETCH_LIMIT`` or one that reaches no vertex."""
    if muscles.count and muscles.force.max() > MUSCLE_STRETCH_LIMIT * material.stiffness:
        m = int(np.argmax(muscles.force))
        raise InputError(f"{muscles.source}: muscle {muscles.names[m]}: force {muscles.force[m]:g} would stretch a skin "
                         f"spring (k0 = {material.stiffness:g}) {muscles.force[m] / material.stiffness:.3g} cm, beyond "
                         f"{MUSCLE_STRETCH_LIMIT:g}: no face's muscle pulls that hard")
    x = mesh.vertices
    faces = mesh.faces
    edges = mesh.edges
    n = mesh.vertex_count

    a, b, c = faces[:, 0], faces[:, 1], faces[:, 2]
    ring_start, order = csr_from_pairs(faces.reshape(-1), np.arange(3 * len(faces)), n)
    ring_a = np.stack([b, c, a], axis=1).reshape(-1)[order]
    ring_b = np.stack([c, a, b], axis=1).reshape(-1)[order]

    repulsion_vertex = faces.reshape(-1)
    repulsion_edge = np.stack([np.stack([b, c], 1), np.stack([c, a], 1), np.stack([a, b], 1)], axis=1).reshape(-1, 2)
    opposite = np.linalg.norm(x[repulsion_edge[:, 1]] - x[repulsion_edge[:, 0]], axis=1)
    altitude = 2 * np.repeat(mesh.face_areas, 3) / opposite

    resolution = float(mesh.face_areas.sum() / n / REFERENCE_VERTEX_AREA)
    pinned = np.zeros(n, dtype=bool)
    pinned[muscles.pinned] = True
    tie = np.zeros(n)  # a tied rim's springs, per vertex as the tissue's (resolved_material)
    tie[muscles.tied] = muscles.tie * resolution
    hinge, hinge_weight = bending_hinges(x, faces)
    normals = vertex_normals(x, faces)  # at rest

    axis_x, axis_z, radius = mesh.vertical_axis
    start, index = mesh.neighbours
    arrays = {key: _frozen(value) for key, value in dict(
        rest_position=x,
        faces=faces,
        rest_normal=mesh.face_normals,
        rest_against=against_surroundings(x, faces, normals),
        rest_area=mesh.face_areas,
        pinned=pinned,
        tie=tie,
        neighbour_start=start,
        neighbour_index=index,
        ring_start=ring_start,
        ring_a=ring_a,
        ring_b=ring_b,
        spring_indices=edges,
        spring_end=edges.T,
        corner=faces.T,
        spring_rest_length=np.linalg.norm(x[edges[:, 0]] - x[edges[:, 1]], axis=1),
        repulsion_vertex=repulsion_vertex,
        repulsion_edge=repulsion_edge,
        repulsion_rest_distance=altitude,
        hinge=hinge,
        hinge_weight=hinge_weight,
        muscle_kind=muscles.kind,
        muscle_insertion=muscles.insertion,
        muscle_centre_start=muscles.centre_start,
        muscle_centre_index=muscles.centre_index,
        muscle_cos_zone=np.cos(muscles.zone),
        muscle_force=muscles.force * resolution,
        muscle_protrusion=muscles.protrusion,
        rest_vertex_normal=normals,
        # the falloffs, in muscle lengths, are set below, from the muscles' ends at rest
        muscle_axes=np.zeros((muscles.count, 2)),
        muscle_r=np.zeros(muscles.count),
        muscle_r_max=np.zeros(muscles.count),
    ).items()}
    resolved = resolved_material(material, resolution)
    rig = build_rig(mesh, muscles)
    length_unit = float(np.sqrt(resolution))
    constants = dict(axis_x=float(axis_x), axis_z=float(axis_z), radius=float(radius))
    kernel_arrays = ModelArrays(
        # the kernels read the pairs' rest distances by corner, pair 3t + k at (k, t), as ``corner``
        **{key: value for key, value in arrays.items() if key != "repulsion_rest_distance"},
        corner_rest_distance=_frozen(altitude.reshape(-1, 3).T), **constants,
        **{key: _frozen(np.asarray(value)) for key, value in vars(rig).items()
           if key not in ("jaw_column", "jaw_max", "jaw_seal_column", "pressure")},
        jaw_column=int(rig.jaw_column), jaw_max=float(rig.jaw_max), jaw_seal_column=int(rig.jaw_seal_column),
        pressure=float(rig.pressure),
        **{key: float(getattr(resolved, key)) for key in ("mass", "damping", "stiffness", "nonlinearity",
                                                           "repulsion_nonlinearity", "tissue", "drive", "bending")},
        length_unit=length_unit, edge_repulsion=bool(resolved.edge_repulsion), uv_projection=bool(resolved.uv_projection),
        attached_regions=resolved.regions == "attached",
        implicit=resolved.solver == "implicit", iterations=int(resolved.iterations), tolerance=float(resolved.tolerance),
    )

    from .muscle_forces import _muscle_frame
    from .rig_control import control
    from .twins import for_mesh

    rest = control(kernel_arrays, np.zeros(len(muscles.names)))  # O and I where the bones hold them at rest
    origin, insertion = rest.origin, rest.insertion_point
    sphincter = muscles.kind == SPHINCTER
    length = np.where(sphincter, 1.0, np.linalg.norm(insertion - origin, axis=1))  # a sphincter's falloff is in ring radii
    frame = np.empty_like(x)
    for_mesh(_muscle_frame, n)(kernel_arrays, arrays["rest_position"], frame)
    axes = np.zeros((muscles.count, 2))
    for m in np.flatnonzero(sphincter):
        axes[m] = ellipse_axes(frame[muscles.ring[m], :2] - origin[m, :2], f"{muscles.source}: muscle {muscles.names[m]}: ring")
    falloffs = {key: _frozen(value) for key, value in dict(
        muscle_axes=axes, muscle_r=muscles.falloff[:, 0] * length, muscle_r_max=muscles.falloff[:, 1] * length).items()}
    arrays.update(falloffs, muscle_origin=_frozen(origin), muscle_insertion_point=_frozen(insertion))
    kernel_arrays = kernel_arrays._replace(**falloffs)
    vertex_order = triangle_order = None
    if n >= REORDER_FROM if reorder is None else reorder:
        vertex_order = cache_order(start, index)
        kernel_arrays, triangle_order = reordered(kernel_arrays, vertex_order)
    model = Model(
        **arrays, **constants, material=resolved, muscles=muscles, rig=rig, scale=mesh.scale, resolution=resolution,
        length_unit=length_unit, mesh=mesh, arrays=kernel_arrays, vertex_order=vertex_order, triangle_order=triangle_order,
    )
    for m, region in enumerate(muscle_regions(model)):
        if len(region) == 0:
            raise InputError(f"{muscles.source}: muscle {muscles.names[m]}: its zone and falloff leave it no vertex of "
                             "the mesh at rest, so it would move nothing; widen its zone or falloff")
    return model


def muscle_regions(model) -> list[np.ndarray]:
    """Each muscle's region of influence at rest (the flood fill of section 3.3), as the
    mesh's vertices."""
    from .muscle_forces import _muscle_frame, _region_of_influence
    from .rig_control import control
    from .twins import for_mesh

    work = workspace(model.arrays)
    rest = control(model.arrays, np.zeros(len(model.muscles.names)))
    for_mesh(_muscle_frame, model.vertex_count)(model.arrays, model.arrays.rest_position, work.frame)
    regions = []
    for m in range(model.muscle_count):
        count = _region_of_influence(model.arrays, m, rest.origin, rest.insertion_point, work.frame, work)
        regions.append(np.array(model.mesh_vertex(work.region[:count])))
    return regions


#: A mesh of at least this many vertices is simulated in a cache-friendly order of its
#: own (``cache_order``): below it the kernels' arrays fit in a core's second-level cache
#: (1 MB on the machines measured) and the order makes no difference.
REORDER_FROM = 4000

#: How ``reordered`` carries each field of the kernels' arrays (arrays.ModelArrays) to a
#: new vertex order: rows per vertex, vertex numbers as values, rows per spring, per
#: triangle or per hinge, compressed rows per vertex, or unchanged (per muscle, scalars).
#: Every field is named once (tests/test_model.py), so a new one cannot be forgotten.
PER_VERTEX = ("rest_position", "pinned", "tie", "rest_vertex_normal", "jaw_weight", "jaw_seal", "lip_shift", "lip_roll",
              "pressure_weight", "lid_column", "lid_centre",
              "lid_delta", "lid_raise_column", "lid_raise_delta", "lid_look_column", "lid_look_delta", "drive_column",
              "drive_weight")
VERTEX_VALUED = ("muscle_insertion", "muscle_centre_index", "contact_upper", "contact_lower")
PER_SPRING = ("spring_indices", "spring_end", "spring_rest_length")
PER_TRIANGLE = ("faces", "rest_normal", "rest_area", "rest_against", "corner", "corner_rest_distance",
                "repulsion_vertex", "repulsion_edge")
PER_HINGE = ("hinge", "hinge_weight")
PER_VERTEX_ROWS = ("neighbour_start", "neighbour_index", "ring_start", "ring_a", "ring_b")
UNCHANGED = ("muscle_kind", "muscle_axes", "muscle_centre_start", "muscle_cos_zone", "muscle_r", "muscle_r_max",
             "muscle_force", "muscle_protrusion", "axis_x", "axis_z", "radius", "jaw_column", "jaw_hinge", "jaw_axis",
             "jaw_max", "lip_shift_column", "lip_roll_column", "lip_roll_pivot", "lip_roll_angle", "gaze_column", "contact_lips", "pressure_column", "pressure", "jaw_seal_column", "jaw_glide_column", "jaw_glide", "contact_normal", "contact_gap", "mass", "damping", "stiffness",
             "nonlinearity", "repulsion_nonlinearity", "length_unit", "tissue", "drive", "bending", "edge_repulsion",
             "uv_projection", "attached_regions", "implicit", "iterations", "tolerance")


def cache_order(start: np.ndarray, index: np.ndarray) -> np.ndarray:
    """A vertex order in which neighbours sit close in memory: reverse Cuthill-McKee on
    the mesh's edge graph (scipy.sparse.csgraph), given as its neighbours in compressed
    rows. Position k of the order is the mesh's vertex ``order[k]``."""
    from scipy.sparse import csr_matrix
    from scipy.sparse.csgraph import reverse_cuthill_mckee

    n = len(start) - 1
    graph = csr_matrix((np.ones(len(index)), index, start), shape=(n, n))
    return reverse_cuthill_mckee(graph, symmetric_mode=True).astype(np.int64)


def reordered(arrays: ModelArrays, order: np.ndarray) -> tuple[ModelArrays, np.ndarray]:
    """The kernels' arrays with vertex ``order[k]`` put k-th, and the springs, triangles
    and hinges sorted by their first vertex in that order, so that a loop over them reads
    and scatters to vertices close in memory. Returns the arrays and the triangles' order
    (triangle k is the mesh's ``triangle_order[k]``). Each corner keeps its place in its
    triangle (its winding), and each vertex its neighbours' and ring's sequence."""
    place = inverse_permutation(order)
    a = arrays._asdict()
    new = {key: a[key][order] for key in PER_VERTEX}
    new.update({key: place[a[key]] for key in VERTEX_VALUED})
    ends = np.sort(place[a["spring_indices"]], axis=1)
    springs = np.lexsort((ends[:, 1], ends[:, 0]))
    new.update(spring_indices=ends[springs], spring_end=ends[springs].T, spring_rest_length=a["spring_rest_length"][springs])
    faces = place[a["faces"]]
    triangles = np.argsort(faces.min(axis=1), kind="stable")
    faces = faces[triangles]
    new.update(faces=faces, corner=faces.T, repulsion_vertex=faces.reshape(-1),
               repulsion_edge=place[a["repulsion_edge"]].reshape(-1, 3, 2)[triangles].reshape(-1, 2),
               corner_rest_distance=a["corner_rest_distance"][:, triangles],
               **{key: a[key][triangles] for key in ("rest_normal", "rest_area", "rest_against")})
    hinge = place[a["hinge"]]
    hinges = np.argsort(hinge[:, :2].min(axis=1), kind="stable")
    new.update(hinge=hinge[hinges], hinge_weight=a["hinge_weight"][hinges])
    for start, values in (("neighbour_start", ("neighbour_index",)), ("ring_start", ("ring_a", "ring_b"))):
        lengths = np.diff(a[start])[order]
        first = np.concatenate([[0], np.cumsum(lengths)])
        taken = np.repeat(a[start][order] - first[:-1], lengths) + np.arange(first[-1])
        new.update({start: first, **{key: place[a[key][taken]] for key in values}})
    return arrays._replace(**{key: _frozen(value) for key, value in new.items()}), triangles


#: The hinges' cotangents are clamped to this magnitude (angles of about 5.7 to 174 degrees):
#: a sliver triangle's near-zero angle would otherwise make its hinge stiffer without bound.
COTANGENT_LIMIT = 10.0


def bending_hinges(x: np.ndarray, faces: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Each interior edge's hinge (x0, x1 its ends, x2 and x3 the vertices opposite it)
    and the stencil of Bergou et al. (2006) at rest, ``sqrt(3 / (A0 + A1)) (c03 + c04,
    c01 + c02, -c01 - c03, -c02 - c04)``, c0k the cotangent of the angle at x0 in the
    triangle holding xk and c1k at x1 (clamped to ``COTANGENT_LIMIT``). Applied to the
    positions it is -√(3 / (A0 + A1)) |e| (n0 + n1), n0 and n1 the unit normals to the edge in
    their planes: zero on a flat hinge, whatever affine map moves it. Triangle pairs from
    edges each two triangles share, found by sorting the triangles' edges (in facesim's
    vertex order)."""
    corners = faces[:, [0, 1, 1, 2, 2, 0]].reshape(-1, 2)
    opposite = faces[:, [2, 0, 1]].ravel()  # each edge's third corner
    edge = np.sort(corners, axis=1)
    order = np.lexsort((edge[:, 1], edge[:, 0]))
    shared = np.flatnonzero(np.all(edge[order[1:]] == edge[order[:-1]], axis=1))
    first, second = order[shared], order[shared + 1]
    hinge = np.column_stack([edge[first], opposite[first], opposite[second]]).astype(np.int64)
    p = x[hinge]  # (e, 4, 3)

    def cotangent(at, a, b):
        u, v = p[:, a] - p[:, at], p[:, b] - p[:, at]
        cot = np.einsum("ij,ij->i", u, v) / np.maximum(np.linalg.norm(np.cross(u, v), axis=1), 1e-12)
        return np.clip(cot, -COTANGENT_LIMIT, COTANGENT_LIMIT)

    c01, c02 = cotangent(0, 1, 2), cotangent(0, 1, 3)
    c03, c04 = cotangent(1, 0, 2), cotangent(1, 0, 3)
    areas = 0.5 * (np.linalg.norm(np.cross(p[:, 1] - p[:, 0], p[:, 2] - p[:, 0]), axis=1)
                   + np.linalg.norm(np.cross(p[:, 1] - p[:, 0], p[:, 3] - p[:, 0]), axis=1))
    stencil = np.column_stack([c03 + c04, c01 + c02, -c01 - c03, -c02 - c04])
    return hinge, stencil * np.sqrt(3.0 / areas)[:, None]


def ellipse_axes(points: np.ndarray, where: str) -> tuple[float, float]:
    """Semi-axes (a, b) of the axis-aligned ellipse u²/a² + v²/b² = 1 closest to 2D points
    around its centre (least squares in 1/a² and 1/b²): a sphincter's ring."""
    design = points**2
    (p, q), *_ = np.linalg.lstsq(design, np.ones(len(points)), rcond=None)
    if p <= 0 or q <= 0:
        raise InputError(f"{where}: does not surround its centre")
    return 1 / np.sqrt(p), 1 / np.sqrt(q)


def vertex_normals(x: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """(n, 3) the area-weighted unit vertex normals of a surface (geometry._vertex_normals)."""
    from ..geometry import _vertex_normals

    out = np.empty((len(x), 3))
    _vertex_normals(np.ascontiguousarray(x, dtype=np.float64), np.ascontiguousarray(faces, dtype=np.int64), out)
    return out


def _frozen(a: np.ndarray) -> np.ndarray:
    """A contiguous read-only copy in the kernels' dtypes (bool, int64 or float64)."""
    dtype = bool if a.dtype == bool else np.int64 if a.dtype.kind in "iu" else np.float64
    a = np.array(a, dtype=dtype, order="C")
    a.flags.writeable = False
    return a
