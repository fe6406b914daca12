"""Numba kernels of the simulation (thesis chapter 3), one per physical term, in the
shape of warp.sim: an immutable :data:`ModelArrays` (what ``facesim.model.build_model``
makes), a :data:`State` (positions x and velocities v, what a step reads and writes), a
:data:`Control` per frame (activations, and where the bones put the skin and the muscles'
ends), and a :data:`Forces` accumulator every term adds into. ``facesim.solver`` calls
them, one line per term.

- ``_spring_forces``         non-linear springs, eq. 3.6 (their g, eq. 3.17, as stiffness)
- ``_edge_repulsion_forces`` edge repulsion, eq. 3.7 (its h, eq. 3.17, as stiffness)
- ``_bending_forces``        bending of the skin's displacement (not in the thesis: the
                             quadratic bending energy of Bergou et al. 2006)
- ``_damping_forces``        viscous damping, eq. 3.10 (taken implicitly by the solvers)
- ``_tissue_forces``         hypodermis springs to the rig's targets, and the rig's drive
- ``_muscle_forces``         linear muscles, eq. 3.1-3.4, and sphincters (facesim.muscles),
                             in the 2D projection of eq. 3.21, back-projected onto the
                             mesh (eq. 3.22-3.25), over the region of influence found by
                             the stack-based flood fill of section 3.3
- ``_rig_control``           where the jaw and eyelids (facesim.rig) take the skin, and
                             where the muscles' ends are as the bones move
- ``_contacts``              lips and lids kept apart (a position projection after a step)

The springs and the edge repulsion take two passes: a loop over their springs or
triangles that computes each one's force into arrays of its own, then a loop adding
those forces to the vertices. On one core at 27,614 vertices that made the springs
35 -> 31 ns a vertex and the edge repulsion 103 -> 51 (2026-12-02, an Intel Xeon). That
first loop, reading the ends' positions through an index, stayed scalar (no packed
square root or division in the code LLVM makes; its remark: "cannot identify array
bounds"). For the thesis's update it now runs on vector lanes (2026-12-03, AMD EPYC,
8 doubles a lane): the ends or corners are gathered into rows first (``spring_delta``,
``corner_position``), and the loop then reads and writes rows alone, every array handed
to it as an argument of its own. LLVM checks every pair of arrays it cannot prove apart
before it vectorises a loop, and gives up past a few ("too many memory checks needed");
an array reached through a tuple is one it cannot prove apart, a separate argument of a
parallel loop is one it can (``_spring_tensions``, ``_repulsion_corners``). Springs 56 ->
41 ns a vertex, edge repulsion 168 -> 97, at 27,614 vertices on one thread; 60 -> 45 and
129 -> 51 on the Hopper face. The implicit step's loops write the links of K as well
(``_spring_links``, ``_repulsion_triangle`` with its links), stay scalar and read the
positions where they are: a gathering pass made them slower. On the Hopper face the
implicit step's force terms took 112 µs a step so, 129 with the g-only loop and a
second loop for the links, and 106 as one scalar loop per term that also scattered
(measured on 2026-12-02).
Numba's cache does not see a change in a callee's file (facesim.config keys it by a hash
of facesim's code).

The springs, the edge repulsion, the bending, the hypodermis, the muscles' frame, their
flood fills and each muscle's region run on every core for a large mesh (``prange``,
facesim.config.PARALLEL_FROM): a link term scatters by ``CHUNKS`` fixed slices of its
links into buffers of their own, summed per vertex in slice order (``_gather_parts``), and
the fills split the muscles by fixed slices (``_find_regions``), so the bits do not
depend on the thread count. Inside a parallel loop every array is written through a local
name: Numba 0.68 drops writes made there through a tuple's field (``forces.force[i] =
...``; measured), and takes no tuple nested in another (so ``Forces`` is flat). Nor does
a parallel loop read the model: Numba hands a loop every tuple its body names, whole,
and the model's 67 fields cost each loop about 3 s of compiling (a one-line loop: 3.9 s
against 1.0 with its one array taken out first) and 0.6 µs at each start. A term takes
out what it reads before its loop, as locals or as a small tuple of its own
(``_spring_fields``, ``_repulsion_fields``, ``_muscle_fields``, ``_ring_fields``,
``_links``): compiling every kernel went 143 -> 79 s (2026-12-03, AMD EPYC). Those are
plain tuples, read by position as each one's docstring lists: named tuples built inside
a parallel kernel and handed to its loop crash Numba 0.68's array analysis (IndexError
in _gen_shape_call; tried).

A term adds, at the predicted positions X* (eq. 3.14), its force F_i and, where its force
depends on X_i, the scalar stiffness K_i = Σ ∂F_i/∂X_i along the spring (the Σ g + Σ h of
eq. 3.19; negative for a stretched spring), and damping terms their C_i = -∂F_i/∂V_i.
A solver turns these into new velocities.
"""

from collections import namedtuple

import math

import numpy as np
from numba import njit, prange

from .config import CHUNKS, LENGTH_EPS, NEGLIGIBLE_DELTA, NUMBA_OPTIONS, PARALLEL_OPTIONS

#: The model's arrays and constants, as the kernels read them (facesim.model.Model.arrays).
#: Shapes: n vertices, t triangles, s springs, r repulsion pairs, M muscles; the jaw and
#: eyelid fields are facesim.rig.Rig's, the material's are facesim.model.Material's. The
#: pairs' rest distances are Model.repulsion_rest_distance by corner (3, t), pair 3t + k
#: at (k, t), for the vector loop of ``_repulsion_corners``.
ModelArrays = namedtuple("ModelArrays", [
    "rest_position", "faces", "rest_normal", "rest_area", "rest_against", "pinned", "tie",
    "neighbour_start", "neighbour_index", "ring_start", "ring_a", "ring_b",
    "spring_indices", "spring_end", "corner", "spring_rest_length", "repulsion_vertex", "repulsion_edge",
    "corner_rest_distance",
    "hinge", "hinge_weight",
    "muscle_kind", "muscle_axes", "muscle_insertion", "muscle_centre_start", "muscle_centre_index",
    "muscle_cos_zone", "muscle_r", "muscle_r_max", "muscle_force", "muscle_protrusion", "rest_vertex_normal", "axis_x", "axis_z", "radius",
    "jaw_column", "jaw_weight", "jaw_hinge", "jaw_axis", "jaw_max", "lid_column", "lid_centre", "lid_delta",
    "lid_raise_column", "lid_raise_delta", "drive_column", "drive_weight", "contact_upper", "contact_lower", "contact_normal", "contact_gap",
    "mass", "damping", "stiffness", "nonlinearity", "repulsion_nonlinearity", "length_unit", "tissue", "drive",
    "bending", "edge_repulsion", "uv_projection", "attached_regions", "implicit", "iterations", "tolerance",
])
#: What a step reads and advances: positions x and velocities v, (n, 3) each.
State = namedtuple("State", ["x", "v"])
#: A frame's controls: ``activation`` (muscles then jaw and lids, one row of the
#: activation table); ``target`` (n, 3) where the bones take each vertex and ``hold`` (n,)
#: the drive holding it there; the muscles' ends ``origin`` and ``insertion_point`` (M, 3)
#: in the frame they act in, from the same bones (``_rig_control``).
Control = namedtuple("Control", ["activation", "target", "hold", "origin", "insertion_point"])
#: What the force terms add into: ``force`` (n, 3), ``stiffness`` (n,) the K_i and
#: ``damping`` (n,) the C_i of the module docstring; and the links of the whole stiffness
#: K = -∂F/∂X that an implicit solver needs, where the K_i keep one number per vertex:
#: link l joins the vertices ``node[l]`` (4) with weights ``weight[l]``, its extension
#: u = Σ_k w_k X_node[l, k] (a spring: X_i - X_j; edge repulsion: X_i - P_k; a bending
#: hinge: its four vertices' stencil), and adds w_p w_q B to the 3x3 block (p, q) of K,
#: with B = along a aᵀ + across (I - a aᵀ) for its unit ``axis`` a; ``diagonal`` (n,) adds
#: an isotropic stiffness per vertex (the hypodermis). B is positive semi-definite: along
#: is the derivative of the tension, across the tension over the length, and 0 when
#: compressed (the usual clamp: a compressed spring's sideways instability is left out);
#: a hinge's B is isotropic (along = across). The link terms scatter into ``part``
#: (CHUNKS, n, 4), one slice of the links each, a vertex's force and its stiffness side by
#: side (one cache line: the springs' and corners' scatter and the sums 36.0 -> 33.3 ns a
#: vertex at 27,614), summed per vertex and zeroed after each term (``_gather_parts``). A term's per-link values
#: wait there between its two passes (module docstring): each spring's g in ``tension``
#: (s,), each triangle's corner forces and h in ``corner_force`` (9, t) and
#: ``corner_stiffness`` (3, t); for the thesis's update, what those loops read, gathered
#: into rows first: each spring's X_i* - X_j* in ``spring_delta`` (3, s) and each
#: triangle's corners' positions in ``corner_position`` (9, t). One flat tuple: Numba's
#: parallel loops take no tuple nested in another.
Forces = namedtuple("Forces", ["force", "stiffness", "damping", "node", "weight", "axis", "along", "across", "diagonal",
                               "part", "tension", "corner_force", "corner_stiffness", "spring_delta", "corner_position"])
#: Scratch arrays of the muscle terms: the points in the muscles' frame (n, 3); the flood
#: fills' marks and stacks, one row per slice of the muscles (CHUNKS, n), and the mark of
#: each slice's latest fill (CHUNKS,); a region and its δ (n,) for a fill that finds no
#: room in the store. Each step's regions are found on every core (``_find_regions``)
#: into the store: muscle m's region the ``region_count[m]`` entries of ``kept_vertex``
#: and ``kept_delta`` from ``region_first[m]`` (a count of -1: not found), slice c
#: writing only its share of the store, ``kept[c]`` entries of it in use. Where the
#: regions are evaluated where the bones hold the skin (``attached_regions``), they change
#: only when the bones move, and are kept between steps: ``bones`` (n, 3) the targets
#: they were found at (``known`` (1,): 0 until the first). A workspace serves one model.
Workspace = namedtuple("Workspace", ["frame", "attached", "visited", "stack", "region", "delta", "stamp", "bones", "known",
                                     "region_first", "region_count", "kept_vertex", "kept_delta", "kept"])
#: Room for the regions, in vertices per mesh vertex: a region that does not fit in its
#: slice's share is found alone, on one core, at every step.
KEPT_REGIONS = 8


def workspace(model: ModelArrays) -> Workspace:
    n, muscles = model.rest_position.shape[0], model.muscle_kind.shape[0]
    room = KEPT_REGIONS * n
    return Workspace(np.empty((n, 3)), np.empty((n, 3)), np.zeros((CHUNKS, n), dtype=np.int64),
                     np.empty((CHUNKS, n), dtype=np.int64), np.empty(n, dtype=np.int64), np.empty(n),
                     np.zeros(CHUNKS, dtype=np.int64), np.empty((n, 3)), np.zeros(1, dtype=np.int64),
                     np.zeros(muscles, dtype=np.int64), np.full(muscles, -1, dtype=np.int64),
                     np.empty(room, dtype=np.int64), np.empty(room), np.zeros(CHUNKS, dtype=np.int64))


def forces(model: ModelArrays) -> Forces:
    """Zeroed accumulators for a model: one link per spring, then one per repulsion pair,
    then one per bending hinge."""
    n = model.rest_position.shape[0]
    count = model.spring_indices.shape[0] + model.repulsion_vertex.shape[0] + model.hinge.shape[0]
    triangles = model.faces.shape[0]
    return Forces(np.zeros((n, 3)), np.zeros(n), np.zeros(n), np.zeros((count, 4), dtype=np.int64), np.zeros((count, 4)),
                  np.zeros((count, 3)), np.zeros(count), np.zeros(count), np.zeros(n), np.zeros((CHUNKS, n, 4)),
                  np.zeros(model.spring_indices.shape[0]), np.zeros((9, triangles)),
                  np.zeros((3, triangles)), np.zeros((3, model.spring_indices.shape[0])), np.zeros((9, triangles)))


def control(model: ModelArrays, activation: np.ndarray) -> Control:
    """The controls of one activation row (copied: a solver writes the controls it blends
    into it), the bones placed by ``_rig_control``."""
    muscles = model.muscle_kind.shape[0]
    c = Control(np.array(activation, dtype=np.float64), model.rest_position.copy(),
                np.zeros(model.rest_position.shape[0]), np.empty((muscles, 3)), np.empty((muscles, 3)))
    _rig_control(model, c)
    return c


#: Status codes returned by ``facesim.solver._simulate``.
OK, NOT_FINITE, INVERTED, RUNAWAY = 0, 1, 2, 3
#: Muscle kinds (facesim.muscles.LINEAR, SPHINCTER).
LINEAR, SPHINCTER = 0, 1
#: The exponent bits of a float64: all set for inf and NaN.
EXPONENT = np.int64(0x7FF0000000000000)


@njit(**NUMBA_OPTIONS)
def _not_finite(a):
    """The first row of ``a`` (rows, 3), C-contiguous float64, holding an inf or a NaN, or
    -1. Reads the exponent bits: ``fastmath`` lets the compiler assume every float is
    finite and drop ``math.isfinite``, but not an integer test."""
    bits = a.reshape(-1).view(np.int64)
    for k in range(bits.shape[0]):
        if bits[k] & EXPONENT == EXPONENT:
            return k // a.shape[1]
    return -1


@njit(**NUMBA_OPTIONS)
def _squarable(exponent):
    """Whether ``_power`` raises to ``exponent`` by squaring: a whole number, 0 to 127."""
    return exponent == math.floor(exponent) and 0.0 <= exponent <= 127.0


@njit(**NUMBA_OPTIONS)
def _power(base, exponent, squarable):
    """base ** exponent, by repeated squaring when ``squarable`` (``_squarable``: the
    thesis's γ = ζ = 5), several times faster than the general pow in the inner loops.
    The squarings are a fixed count of steps without a branch, and ``squarable`` is the
    same for a whole loop, so the compiler can take the test out of the loop (measured
    on 2026-12-02, the springs' loop alone at 27,614 vertices: 8 ns a vertex)."""
    if squarable:
        result = 1.0
        e = int(exponent)
        for _ in range(7):
            result *= base if e & 1 else 1.0
            base *= base
            e >>= 1
        return result
    return base**exponent


@njit(**NUMBA_OPTIONS)
def _nonlinear_coefficient(length, rest, k0, exponent, unit, squarable):
    """The g of eq. 3.17 (h with ζ), -(1 + ((|X| - d) / u)²)^γ k0 (|X| - d) / |X|, and the
    derivative of the tension φ = -g |X| = k0 (1 + s²)^γ (|X| - d), s = (|X| - d) / u:
    dφ/d|X| = k0 (1 + s²)^(γ-1) (1 + (2γ + 1) s²), the stiffness along the link. The
    thesis's stretch is in cm (u = 1); on a finer mesh of the same face u is its edge
    length relative to the default face's, so the same strain stiffens the same way.
    ``squarable``: ``_squarable(exponent - 1)``, found once per loop."""
    stretch = length - rest
    relative = stretch / unit
    square = relative * relative
    factor = _power(1.0 + square, exponent - 1.0, squarable)
    g = -factor * (1.0 + square) * k0 * stretch / max(length, LENGTH_EPS)
    return g, k0 * factor * (1.0 + (2.0 * exponent + 1.0) * square)


@njit(**dict(NUMBA_OPTIONS, inline="always"))
def _links(forces):
    """The arrays of K's links (``Forces``), as the link terms' loops are handed them
    (module docstring)."""
    return forces.node, forces.weight, forces.axis, forces.along, forces.across


@njit(**NUMBA_OPTIONS)
def _set_link(links, l, i, j, k, wi, wj, wk, dx, dy, dz, length, g, along):
    """Link l of K (``_links``): nodes i, j, k with weights (the fourth node unused),
    axis (dx, dy, dz) / length, the tension's derivative ``along`` and -g (the tension
    over the length, eq. 3.17's g with its sign turned) across, clamped at 0."""
    node, weight, axis, along_of, across_of = links
    node[l, 0] = i
    node[l, 1] = j
    node[l, 2] = k
    node[l, 3] = k
    weight[l, 0] = wi
    weight[l, 1] = wj
    weight[l, 2] = wk
    weight[l, 3] = 0.0
    inverse = 1.0 / max(length, LENGTH_EPS)
    axis[l, 0] = dx * inverse
    axis[l, 1] = dy * inverse
    axis[l, 2] = dz * inverse
    along_of[l] = along
    across_of[l] = max(-g, 0.0)


@njit(**NUMBA_OPTIONS)
def _link_extension(node, weight, l, p):
    """Σ_k w_k p_node[l, k], link l's extension (``Forces``) in the vectors ``p`` (n, 3)."""
    ux = 0.0
    uy = 0.0
    uz = 0.0
    for k in range(4):
        w = weight[l, k]
        n = node[l, k]
        ux += w * p[n, 0]
        uy += w * p[n, 1]
        uz += w * p[n, 2]
    return ux, uy, uz


@njit(**NUMBA_OPTIONS)
def _link_spread(node, weight, l, scale, bx, by, bz, out):
    """out[node[l, k]] += scale w_k b for link l's nodes: a vector b acting on its
    extension, carried back to the vertices (the transpose of ``_link_extension``)."""
    for k in range(4):
        w = scale * weight[l, k]
        n = node[l, k]
        out[n, 0] += w * bx
        out[n, 1] += w * by
        out[n, 2] += w * bz


@njit(**NUMBA_OPTIONS)
def _chunk(c, count):
    """Slice c of ``CHUNKS`` of range(count): its first and its end."""
    return c * count // CHUNKS, (c + 1) * count // CHUNKS


@njit(**PARALLEL_OPTIONS)
def _gather_parts(forces):
    """Add the link terms' slices into ``force`` and ``stiffness`` in slice order, and
    zero them: the same sums on any number of threads."""
    force, stiffness, part = forces.force, forces.stiffness, forces.part
    for i in prange(force.shape[0]):
        for c in range(CHUNKS):
            for d in range(3):
                force[i, d] += part[c, i, d]
            stiffness[i] += part[c, i, 3]
            for d in range(4):
                part[c, i, d] = 0.0


@njit(**dict(NUMBA_OPTIONS, inline="always"))
def _spring_fields(model):
    """What the springs read of the model (module docstring): k0, exponent and length
    unit, in this order (the rest lengths reach the loops as an array of their own, as
    the edge repulsion's: ``_repulsion_fields``)."""
    return model.stiffness, model.nonlinearity, model.length_unit


@njit(**dict(NUMBA_OPTIONS, inline="always"))
def _spring(springs, rest_length, s, dx, dy, dz, squarable):
    """Spring s of eq. 3.6 at the predicted positions, X_i* - X_j* = (dx, dy, dz): its
    length, its g (eq. 3.17) and its stiffness along (``_nonlinear_coefficient``)."""
    k0, exponent, unit = springs
    length = math.sqrt(dx * dx + dy * dy + dz * dz)
    g, along = _nonlinear_coefficient(length, rest_length[s], k0, exponent, unit, squarable)
    return length, g, along


@njit(**PARALLEL_OPTIONS)
def _spring_forces(model, xp, forces):
    """Springs on the mesh edges, eq. 3.6, at the predicted positions: F_i = g (X_i* - X_j*),
    its g into both ends' stiffness (eq. 3.17), and, for the implicit step, spring s as
    link s of K. Every spring's g into ``tension``, then each spring's force added to its
    ends (``_scatter_springs``).

    The thesis's update gathers the ends first and then takes every g in a loop over
    rows alone (``_spring_tensions``), which LLVM puts on vector lanes; the implicit step
    gathers them in the loop that also writes the links (``_spring_links``), which stays
    scalar: a pass of its own for the gathering made that loop slower, not faster
    (measured on 2026-12-03: 56 -> 41 ns a vertex for the thesis's update, 68 -> 84 for
    the implicit step, at 27,614 vertices on one thread)."""
    end, tension, delta, springs = model.spring_end, forces.tension, forces.spring_delta, _spring_fields(model)
    rest_length = model.spring_rest_length
    squarable = _squarable(model.nonlinearity - 1.0)
    if model.implicit:
        _spring_links(springs, rest_length, end, xp, squarable, forces)
    else:
        for s in prange(tension.shape[0]):  # the ends gathered, so that the next loop reads rows
            i = end[0, s]
            j = end[1, s]
            for d in range(3):
                delta[d, s] = xp[i, d] - xp[j, d]
        _spring_tensions(springs, rest_length, delta, squarable, tension)
    _scatter_springs(model, xp, forces)


@njit(**PARALLEL_OPTIONS)
def _spring_tensions(springs, rest_length, delta, squarable, tension):
    """Every spring's g into ``tension`` from the rows of ``delta``, for the thesis's
    update: one loop per kind of exponent, so that no call to pow is left in it, and
    every array handed to it alone (an array inside a tuple costs the loop its vector
    lanes: ``_repulsion_fields``)."""
    if squarable:
        for s in prange(tension.shape[0]):
            tension[s] = _spring(springs, rest_length, s, delta[0, s], delta[1, s], delta[2, s], True)[1]
    else:
        for s in prange(tension.shape[0]):
            tension[s] = _spring(springs, rest_length, s, delta[0, s], delta[1, s], delta[2, s], False)[1]


@njit(**PARALLEL_OPTIONS)
def _spring_links(springs, rest_length, end, xp, squarable, forces):
    """Every spring's g into ``tension`` and spring s as link s of K (``Forces``), for the
    implicit step: a loop of its own, so that the thesis's update, which needs only the
    g, does not write the links."""
    tension, links = forces.tension, _links(forces)
    for s in prange(tension.shape[0]):
        i = end[0, s]
        j = end[1, s]
        dx = xp[i, 0] - xp[j, 0]
        dy = xp[i, 1] - xp[j, 1]
        dz = xp[i, 2] - xp[j, 2]
        length, g, along = _spring(springs, rest_length, s, dx, dy, dz, squarable)
        tension[s] = g
        _set_link(links, s, i, j, j, 1.0, -1.0, 0.0, dx, dy, dz, length, g, along)


@njit(**PARALLEL_OPTIONS)
def _scatter_springs(model, xp, forces):
    """Each spring's force g (X_i* - X_j*) added to its ends and g to their stiffness, by
    ``CHUNKS`` fixed slices of the springs (``_gather_parts``). X_i* - X_j* is taken again
    here rather than read from ``spring_delta``, which the implicit step does not write
    (writing it there made that step's springs slower)."""
    end, tension, parts = model.spring_end, forces.tension, forces.part
    for c in prange(CHUNKS):
        part = parts[c]
        first, stop = _chunk(c, end.shape[1])
        for s in range(first, stop):
            i = end[0, s]
            j = end[1, s]
            g = tension[s]
            for d in range(3):
                pull = g * (xp[i, d] - xp[j, d])
                part[i, d] += pull
                part[j, d] -= pull
            part[i, 3] += g
            part[j, 3] += g
    _gather_parts(forces)


@njit(**PARALLEL_OPTIONS)
def _tissue_forces(model, xp, control, forces):
    """Hypodermis springs: each vertex tied to its target (its rest position, moved by the
    jaw and eyelids) with stiffness k_t + tie_i + hold_i, the soft tissue that attaches
    skin to bone (tie_i: a tied rim's, the skin beyond the cut, muscles.Pinned). Not in
    the thesis (tissue = 0 is its model); a spring mesh has no bending stiffness, so under
    muscle pull it wrinkles and creeps without ever settling, and these springs give
    every mode a restoring force. ``hold`` holds the skin over the
    mandible and the lid contours to their targets while the jaw and lids move."""
    force, stiffness, diagonal = forces.force, forces.stiffness, forces.diagonal
    tissue, tie, hold, target = model.tissue, model.tie, control.hold, control.target
    for i in prange(xp.shape[0]):
        k = tissue + tie[i] + hold[i]
        stiffness[i] -= k
        diagonal[i] += k
        for d in range(3):
            force[i, d] -= k * (xp[i, d] - target[i, d])


@njit(**dict(NUMBA_OPTIONS, inline="always"))
def _repulsion_fields(model):
    """What the edge repulsion reads of the model (module docstring): k0, exponent and
    length unit, in this order (the rest distances, ``corner_rest_distance``, reach the
    loops as an array of their own: an array inside a tuple costs a loop its vector
    lanes, LLVM then checking it against every other for overlap)."""
    return model.stiffness, model.repulsion_nonlinearity, model.length_unit


@njit(**dict(NUMBA_OPTIONS, inline="always"))
def _repulsion_pair(pairs, rest_distance, k, triangle, squarable, ix, iy, iz, ax, ay, az, bx, by, bz):
    """Eq. 3.7 for pair k of a triangle: the vertex at (ix, iy, iz) against the line through
    the edge from (ax, ay, az) to (bx, by, bz), its foot P_k = a + t (b - a). Returns h
    (eq. 3.17) and the stiffness along, t, X_i - P_k and its length. Inlined: passing the
    model's tuple to a call per pair costs more than the pair (measured: 18 times slower)."""
    k0, exponent, unit = pairs
    ex = bx - ax
    ey = by - ay
    ez = bz - az
    t = ((ix - ax) * ex + (iy - ay) * ey + (iz - az) * ez) / max(ex * ex + ey * ey + ez * ez, LENGTH_EPS)
    dx = ix - ax - t * ex
    dy = iy - ay - t * ey
    dz = iz - az - t * ez
    distance = math.sqrt(dx * dx + dy * dy + dz * dz)
    h, along = _nonlinear_coefficient(distance, rest_distance[k, triangle], k0, exponent, unit, squarable)
    return h, along, t, dx, dy, dz, distance


@njit(**dict(NUMBA_OPTIONS, inline="always"))
def _repulsion_triangle(pairs, rest_distance, t, ax, ay, az, bx, by, bz, cx, cy, cz, squarable, out, stiffness, links,
                        first_link, a, b, c, write_links):
    """Triangle t's three pairs of eq. 3.7 (``_edge_repulsion_forces``), its corners a, b,
    c at (ax, ay, az), (bx, by, bz) and (cx, cy, cz): each corner's own R and its shares of
    the reactions on the two edges it ends, into ``out`` (9, t) and its h into
    ``stiffness`` (3, t); with ``write_links``, the pairs as links of K too (``_links``),
    from link ``first_link`` + 3t."""
    ha, la, ta, rax, ray, raz, da = _repulsion_pair(pairs, rest_distance, 0, t, squarable, ax, ay, az, bx, by, bz, cx, cy, cz)
    hb, lb, tb, rbx, rby, rbz, db = _repulsion_pair(pairs, rest_distance, 1, t, squarable, bx, by, bz, cx, cy, cz, ax, ay, az)
    hc, lc, tc, rcx, rcy, rcz, dc = _repulsion_pair(pairs, rest_distance, 2, t, squarable, cx, cy, cz, ax, ay, az, bx, by, bz)
    if write_links:  # pair r as link s + r of K, u = X_i - (1 - t) X_a - t X_b with the foot's t held
        l = first_link + 3 * t
        _set_link(links, l, a, b, c, 1.0, ta - 1.0, -ta, rax, ray, raz, da, ha, la)
        _set_link(links, l + 1, b, c, a, 1.0, tb - 1.0, -tb, rbx, rby, rbz, db, hb, lb)
        _set_link(links, l + 2, c, a, b, 1.0, tc - 1.0, -tc, rcx, rcy, rcz, dc, hc, lc)
    stiffness[0, t] = ha
    stiffness[1, t] = hb
    stiffness[2, t] = hc
    # a: its R, and its shares of b's reaction on (c, a) and of c's on (a, b); b and c alike
    out[0, t] = ha * rax - tb * hb * rbx - (1.0 - tc) * hc * rcx
    out[1, t] = ha * ray - tb * hb * rby - (1.0 - tc) * hc * rcy
    out[2, t] = ha * raz - tb * hb * rbz - (1.0 - tc) * hc * rcz
    out[3, t] = hb * rbx - tc * hc * rcx - (1.0 - ta) * ha * rax
    out[4, t] = hb * rby - tc * hc * rcy - (1.0 - ta) * ha * ray
    out[5, t] = hb * rbz - tc * hc * rcz - (1.0 - ta) * ha * raz
    out[6, t] = hc * rcx - ta * ha * rax - (1.0 - tb) * hb * rbx
    out[7, t] = hc * rcy - ta * ha * ray - (1.0 - tb) * hb * rby
    out[8, t] = hc * rcz - ta * ha * raz - (1.0 - tb) * hb * rbz


@njit(**PARALLEL_OPTIONS)
def _edge_repulsion_forces(model, xp, forces):
    """Edge repulsion, eq. 3.7: each vertex is held at its rest altitude above the
    opposite edge of each of its triangles.

    R_ik acts on the vertex (with h as its stiffness, eq. 3.17) and its reaction -R_ik on
    the edge's ends, split (1 - t) : t by where the foot P_k lies. The thesis leaves the
    reaction out, but without it the term is not conservative and a perturbed face at
    rest never settles (measured: kinetic energy grows); with it the term derives from a
    potential in the point-to-line distance. Pair r is link s + r of K (s springs).

    Two passes, as the springs': triangle t's three pairs (3t, 3t + 1, 3t + 2: its
    corners a, b, c against (b, c), (c, a), (a, b), facesim.model) give each corner its
    own R and its shares of the reactions on the two edges it ends, into
    ``corner_force`` (9, t) and ``corner_stiffness`` (3, t); then the corners' sums are
    added to the vertices (``_scatter_corners``). As the springs' (``_spring_forces``),
    the thesis's update gathers the corners into the rows of ``corner_position`` first,
    and its loop over the triangles, reading and writing rows alone, runs on vector lanes
    (``_repulsion_corners``: 168 -> 97 ns a vertex at 27,614 vertices, one thread,
    2026-12-03); the implicit step's loop, which also writes the links, reads the corners
    where they are.
    """
    if not model.edge_repulsion:
        return
    corner, out, stiffness = model.corner, forces.corner_force, forces.corner_stiffness
    rest_distance = model.corner_rest_distance
    pairs, links, first_link = _repulsion_fields(model), _links(forces), model.spring_end.shape[1]
    squarable = _squarable(model.repulsion_nonlinearity - 1.0)
    if model.implicit:  # a loop that also writes the links
        for t in prange(corner.shape[1]):
            a = corner[0, t]
            b = corner[1, t]
            c = corner[2, t]
            _repulsion_triangle(pairs, rest_distance, t, xp[a, 0], xp[a, 1], xp[a, 2], xp[b, 0], xp[b, 1], xp[b, 2],
                                xp[c, 0], xp[c, 1], xp[c, 2], squarable, out, stiffness, links, first_link, a, b, c, True)
    else:
        position = forces.corner_position
        for t in prange(corner.shape[1]):  # the corners gathered, so that the next loop reads rows
            for k in range(3):
                v = corner[k, t]
                for d in range(3):
                    position[3 * k + d, t] = xp[v, d]
        _repulsion_corners(pairs, rest_distance, position, squarable, out, stiffness)
    _scatter_corners(model, forces)


@njit(**PARALLEL_OPTIONS)
def _repulsion_corners(pairs, rest_distance, position, squarable, out, stiffness):
    """Every triangle's corner forces and h (``_repulsion_triangle``) from the rows of
    ``position`` (9, t), for the thesis's update: a loop that reads and writes rows
    alone, one per kind of exponent (``_spring_tensions``)."""
    if squarable:
        for t in prange(position.shape[1]):
            _repulsion_row(pairs, rest_distance, position, t, True, out, stiffness)
    else:
        for t in prange(position.shape[1]):
            _repulsion_row(pairs, rest_distance, position, t, False, out, stiffness)


@njit(**dict(NUMBA_OPTIONS, inline="always"))
def _repulsion_row(pairs, rest_distance, position, t, squarable, out, stiffness):
    """``_repulsion_triangle`` for triangle t, its corners read from the rows of
    ``position`` (9, t), without links (the thesis's update: no link is written, so the
    links' arguments are placeholders)."""
    _repulsion_triangle(pairs, rest_distance, t, position[0, t], position[1, t], position[2, t], position[3, t],
                        position[4, t], position[5, t], position[6, t], position[7, t], position[8, t], squarable, out,
                        stiffness, pairs, 0, 0, 0, 0, False)


@njit(**PARALLEL_OPTIONS)
def _scatter_corners(model, forces):
    """Each triangle's corner forces and stiffness (``_edge_repulsion_forces``) added to
    its vertices, by ``CHUNKS`` fixed slices of the triangles (``_gather_parts``)."""
    corner, out, corner_stiffness, parts = model.corner, forces.corner_force, forces.corner_stiffness, forces.part
    for c in prange(CHUNKS):
        part = parts[c]
        first, stop = _chunk(c, corner.shape[1])
        for t in range(first, stop):
            for k in range(3):
                v = corner[k, t]
                for d in range(3):
                    part[v, d] += out[3 * k + d, t]
                part[v, 3] += corner_stiffness[k, t]
    _gather_parts(forces)


@njit(**PARALLEL_OPTIONS)
def _bending_forces(model, xp, control, forces):
    """Bending: each interior edge's hinge (its two triangles' four vertices) resists a
    change of the skin's curvature, with the quadratic energy of Bergou, Wardetzky, Harmon,
    Zorin and Grinspun, "A quadratic bending model for inextensible surfaces" (2006),

        E = ½ k_b Σ_e (Σ_k w_ek U_k)²,  U = X - target (each coordinate),

    where w_e is the hinge's cotangent stencil scaled by √(3 / (A_0 + A_1)) at rest
    (facesim.model), so Σ_k w_ek X_k measures the hinge's bend and vanishes on a flat one.
    Bergou et al. apply it to the positions of a flat sheet; a face is curved at rest, so
    here it acts on the displacement from where the bones hold the skin (the rest shape
    moved by the jaw and lids): zero at rest and under the rig, and for the small turns
    of skin under muscles the change of the hinge's bend. Not in the thesis (k_b = 0 is
    its model): a spring lattice has no bending stiffness, so where muscles compress the
    skin it buckles into lumps and its sliver triangles turn over (issue 16). The energy
    is quadratic, so its stiffness k_b w wᵀ (link s + r + e of K) is constant and exact.
    """
    if model.bending == 0.0:
        return
    offset = model.spring_indices.shape[0] + model.repulsion_vertex.shape[0]
    kb, hinge, hinge_weight, target = model.bending, model.hinge, model.hinge_weight, control.target
    node_of, weight_of, axis, along, across = _links(forces)
    parts = forces.part
    for c in prange(CHUNKS):
        part = parts[c]
        first, end = _chunk(c, hinge.shape[0])
        for e in range(first, end):
            l = offset + e
            # the bend w · U summed over the differences U = X - target, not as w · X - w · target
            # (``_link_extension`` twice): the weights reach 100 and the positions 10 cm, and the
            # two sums would cancel to 1e-9
            bx = 0.0
            by = 0.0
            bz = 0.0
            for k in range(4):
                node = hinge[e, k]
                w = hinge_weight[e, k]
                part[node, 3] -= kb * w * w
                node_of[l, k] = node
                weight_of[l, k] = w
                bx += w * (xp[node, 0] - target[node, 0])
                by += w * (xp[node, 1] - target[node, 1])
                bz += w * (xp[node, 2] - target[node, 2])
            axis[l, 0] = 1.0
            axis[l, 1] = 0.0
            axis[l, 2] = 0.0
            along[l] = kb
            across[l] = kb
            _link_spread(node_of, weight_of, l, -kb, bx, by, bz, part)  # F = -k_b w (w · U)
    _gather_parts(forces)


@njit(**NUMBA_OPTIONS)
def _damping_forces(model, forces):
    """Viscous damping, eq. 3.10: F = -c V, left to the solver as C_i = c, which it takes
    at the new velocity (implicitly, as eq. 3.19 does)."""
    for i in range(forces.damping.shape[0]):
        forces.damping[i] += model.damping


@njit(**NUMBA_OPTIONS)
def _radial(dist, r, r_max):
    """δ_R of eq. 3.3: rising from 0 at the origin to 1 at r, falling to 0 at r_max."""
    if dist > r_max:
        return 0.0
    if dist <= r:
        return math.cos(0.5 * math.pi * (r - dist) / r)
    return math.cos(0.5 * math.pi * (dist - r) / (r_max - r))


@njit(**NUMBA_OPTIONS)
def _falloff(ox, oy, oz, ix, iy, iz, px, py, pz, cos_zone, r, r_max):
    """δ = δ_A δ_R of eq. 3.2-3.4 for point P, muscle O -> I (2D points have z = 0)."""
    oix = ix - ox
    oiy = iy - oy
    oiz = iz - oz
    opx = px - ox
    opy = py - oy
    opz = pz - oz
    dist = math.sqrt(opx * opx + opy * opy + opz * opz)
    length = math.sqrt(oix * oix + oiy * oiy + oiz * oiz)
    if dist < LENGTH_EPS or dist > r_max:
        return 0.0
    cos_beta = (oix * opx + oiy * opy + oiz * opz) / (length * dist)
    if cos_beta < cos_zone:
        return 0.0
    return (cos_beta - cos_zone) / (1.0 - cos_zone) * _radial(dist, r, r_max)


@njit(**dict(NUMBA_OPTIONS, inline="always"))
def _muscle_fields(model):
    """What the muscles' flood fills read of the model (module docstring): kind, axes,
    insertion, cos_zone, r, r_max, neighbour_start, neighbour_index, in this order."""
    return (model.muscle_kind, model.muscle_axes, model.muscle_insertion, model.muscle_cos_zone, model.muscle_r,
            model.muscle_r_max, model.neighbour_start, model.neighbour_index)


@njit(**dict(NUMBA_OPTIONS, inline="always"))
def _ring_fields(model):
    """What the back-projection reads of the model, each vertex's one-ring (module
    docstring): ring_start, ring_a, ring_b, neighbour_start, neighbour_index, in this
    order."""
    return model.ring_start, model.ring_a, model.ring_b, model.neighbour_start, model.neighbour_index


@njit(**NUMBA_OPTIONS)
def _delta(muscles, m, origin, insertion_point, px, py, pz):
    """δ of muscle m (``_muscle_fields``) at point P: eq. 3.4 for a linear muscle; for a
    sphincter, δ_R of eq. 3.3 in the elliptical radius ρ = |((u - u_c) / a, (v - v_c) / b)|
    (1 on its ring)."""
    kind, axes, cos_zone, r, r_max = muscles[0], muscles[1], muscles[3], muscles[4], muscles[5]
    if kind[m] == SPHINCTER:
        du = (px - origin[m, 0]) / axes[m, 0]
        dv = (py - origin[m, 1]) / axes[m, 1]
        return _radial(math.sqrt(du * du + dv * dv), r[m], r_max[m])
    return _falloff(origin[m, 0], origin[m, 1], origin[m, 2], insertion_point[m, 0], insertion_point[m, 1],
                    insertion_point[m, 2], px, py, pz, cos_zone[m], r[m], r_max[m])


@njit(**dict(NUMBA_OPTIONS, inline="always"))
def _back_project(ring, i, fu, fv, uv, xp, out):
    """Eq. 3.22-3.25: carry the 2D force (fu, fv) at vertex i onto the mesh, its one-ring
    in ``ring`` (``_ring_fields``).

    The one-ring triangle (i, a, b) whose 2D wedge contains the force is found by writing
    the force in the basis of its two 2D edges, f = α e_a + β e_b with α, β ≥ 0; the same
    combination of the 3D edges lies in the triangle's plane and projects to a vector
    parallel to f. Its length is set to |f|. Where the projected one-ring folds (the lips'
    rolled edge, beside the nose), several wedges hold the force: their directions are
    averaged with the weight sin φ sin(θ - φ) = α β det² / (|f|² |e_a| |e_b|), f at angle
    φ in a wedge of angle θ, which vanishes on a wedge's edges and stays small in a
    sliver, so the result turns continuously with the force and does not depend
    on which triangle the ring lists first (taking the first made mirror-image vertices
    pull differently: 4e-3 of the depressor labii's force at the upper lip). A force no
    wedge holds leaves the mesh (``_between_edges``). Returns False, leaving ``out``
    zero, when nothing of it is kept.

    Inlined into the muscles' loop (``_pull_region``): a call per region vertex, handing
    over the ring's arrays, cost 8-17% of the muscles' time. The muscles at frame
    12 of happy, looped, 99.6 -> 91.7 ns a vertex on the Hopper face and 85.9 -> 71.4 at
    27,614 vertices on one thread (46.3 -> 37.4 on two), medians side by side in one
    process (2026-12-03). Taking a lone wedge's direction without its weight (99% of
    happy's region vertices) was slower, not faster: tried, not kept.
    """
    out[0] = 0.0
    out[1] = 0.0
    out[2] = 0.0
    magnitude = math.sqrt(fu * fu + fv * fv)
    if magnitude == 0.0:
        return False
    ring_start, ring_a, ring_b = ring[0], ring[1], ring[2]
    ui, vi = uv[i, 0], uv[i, 1]
    for k in range(ring_start[i], ring_start[i + 1]):
        a = ring_a[k]
        b = ring_b[k]
        au = uv[a, 0] - ui
        av = uv[a, 1] - vi
        bu = uv[b, 0] - ui
        bv = uv[b, 1] - vi
        det = au * bv - av * bu
        along_a = fu * bv - fv * bu  # α det
        along_b = au * fv - av * fu  # β det
        if min(along_a * det, along_b * det) < 0.0 or abs(det) < LENGTH_EPS:
            continue
        # det g = α det (X_a - X_i) + β det (X_b - X_i), weighed by α β det² / (|e_a| |e_b|):
        # the common 1 / |f|² goes with the normalisation below, and only a wedge that holds
        # the force divides (tests first on signs, one branch: 69 -> 59 ns a region vertex)
        gx = along_a * (xp[a, 0] - xp[i, 0]) + along_b * (xp[b, 0] - xp[i, 0])
        gy = along_a * (xp[a, 1] - xp[i, 1]) + along_b * (xp[b, 1] - xp[i, 1])
        gz = along_a * (xp[a, 2] - xp[i, 2]) + along_b * (xp[b, 2] - xp[i, 2])
        extent = (au * au + av * av) * (bu * bu + bv * bv) * (gx * gx + gy * gy + gz * gz)
        scale = math.copysign(1.0, det) * along_a * along_b / max(math.sqrt(extent), LENGTH_EPS * LENGTH_EPS)
        out[0] += scale * gx
        out[1] += scale * gy
        out[2] += scale * gz
    norm = math.sqrt(out[0] ** 2 + out[1] ** 2 + out[2] ** 2)
    if norm > 0.0:
        for d in range(3):
            out[d] *= magnitude / norm
        return True
    return _between_edges(ring, i, fu, fv, uv, xp, out)  # no wedge, or exactly along an edge


@njit(**NUMBA_OPTIONS)
def _between_edges(ring, i, fu, fv, uv, xp, out):
    """A force f at vertex i that no 2D wedge holds (it leaves the mesh at the boundary,
    or points into the gap of a folded one-ring), between the edges nearest it on either
    side, e_p clockwise and e_q counter-clockwise (2D): kept as
    |f| ((1 - t) max(0, cos(f, e_p)) Ê_p + t max(0, cos(f, e_q)) Ê_q) along the 3D edges'
    directions Ê, t running from 0 at e_p to 1 at e_q with the angle. It meets the
    wedges' rule on both edges and changes continuously in between: taking only the
    closer edge flips between the two as the vertex moves, and a lip pulled outward
    rattled between them (measured: a period-2 cycle of 0.3 mm a frame at the inner
    lower lip under AU12)."""
    to_q = 2.0 * math.pi
    from_p = 2.0 * math.pi
    p = -1
    q = -1
    neighbour_start, neighbour_index = ring[3], ring[4]
    for k in range(neighbour_start[i], neighbour_start[i + 1]):
        j = neighbour_index[k]
        eu = uv[j, 0] - uv[i, 0]
        ev = uv[j, 1] - uv[i, 1]
        turn = _turn(fu, fv, eu, ev)
        if turn < to_q:
            to_q = turn
            q = j
        turn = _turn(eu, ev, fu, fv)
        if turn < from_p:
            from_p = turn
            p = j
    if p < 0:
        return False
    t = from_p / max(from_p + to_q, LENGTH_EPS)
    magnitude = math.sqrt(fu * fu + fv * fv)
    kept_p = (1.0 - t) * max(0.0, _cosine(uv[p, 0] - uv[i, 0], uv[p, 1] - uv[i, 1], fu, fv)) * magnitude
    kept_q = t * max(0.0, _cosine(uv[q, 0] - uv[i, 0], uv[q, 1] - uv[i, 1], fu, fv)) * magnitude
    _add_along_edge(xp, i, p, kept_p, out)
    _add_along_edge(xp, i, q, kept_q, out)
    return kept_p > 0.0 or kept_q > 0.0


@njit(**NUMBA_OPTIONS)
def _cosine(au, av, bu, bv):
    return (au * bu + av * bv) / max(math.sqrt((au * au + av * av) * (bu * bu + bv * bv)), LENGTH_EPS)


@njit(**NUMBA_OPTIONS)
def _turn(au, av, bu, bv):
    """The angle from 2D vector a to b turning counter-clockwise, in [0, 2π)."""
    angle = math.atan2(au * bv - av * bu, au * bu + av * bv)
    return angle + 2.0 * math.pi if angle < 0.0 else angle


@njit(**NUMBA_OPTIONS)
def _add_along_edge(xp, i, j, length, out):
    """out += ``length`` along the unit 3D edge from vertex i to j."""
    norm = math.sqrt((xp[j, 0] - xp[i, 0]) ** 2 + (xp[j, 1] - xp[i, 1]) ** 2 + (xp[j, 2] - xp[i, 2]) ** 2)
    scale = length / max(norm, LENGTH_EPS)
    for d in range(3):
        out[d] += scale * (xp[j, d] - xp[i, d])


@njit(**NUMBA_OPTIONS)
def _fill(muscles, m, origin, insertion_point, points, visited, stack, stamp, region, delta):
    """The stack-based flood fill of section 3.3 for muscle m (``_muscle_fields``), over
    ``points`` (in the muscles' frame): start at the insertion, pop a vertex, evaluate its δ (eq. 3.4), and
    push its neighbours only when δ is not negligible. Writes the region's vertices and
    their δ into ``region`` and ``delta``, as many as they hold, and returns how many there
    are (more than they hold: the region did not fit); ``visited`` and ``stack`` (n,) are
    the fill's own, its vertices marked with a new ``stamp[0]``."""
    stamp[0] += 1
    mark = stamp[0]
    room = region.shape[0]
    neighbour_start, neighbour_index = muscles[6], muscles[7]
    start = muscles[2][m]
    count = 0
    top = 0
    stack[0] = start
    visited[start] = mark
    while top >= 0:
        i = stack[top]
        top -= 1
        d = _delta(muscles, m, origin, insertion_point, points[i, 0], points[i, 1], points[i, 2])
        if d <= NEGLIGIBLE_DELTA:
            continue
        if count < room:
            region[count] = i
            delta[count] = d
        count += 1
        for k in range(neighbour_start[i], neighbour_start[i + 1]):
            j = neighbour_index[k]
            if visited[j] != mark:
                visited[j] = mark
                top += 1
                stack[top] = j
    return count


@njit(**NUMBA_OPTIONS)
def _region_of_influence(model, m, origin, insertion_point, points, work):
    """Muscle m's region (``_fill``) into ``work.region`` and ``work.delta``, with the
    first slice's marks; returns its size."""
    return _fill(_muscle_fields(model), m, origin, insertion_point, points, work.visited[0], work.stack[0], work.stamp[0:1],
                 work.region, work.delta)


@njit(**PARALLEL_OPTIONS)
def _find_regions(model, control, points, work):
    """The region of every active muscle not yet found (``region_count`` -1), on every
    core: muscle m falls to slice m mod CHUNKS (a muscle's two sides, listed one after the
    other, to two slices), which fills its muscles one after another with marks and a
    stack of its own into its share of the store (``Workspace``). Each fill is the same
    on any thread, so the regions, and the forces pulled from them in the muscles' order,
    do not depend on the thread count. A region too large for what is left of its share
    keeps its count of -1 (``_muscle_forces`` finds it alone)."""
    visited, stack, stamp, kept = work.visited, work.stack, work.stamp, work.kept  # written by local names (module docstring)
    first, count, vertices, deltas = work.region_first, work.region_count, work.kept_vertex, work.kept_delta
    muscles, activation, origin, insertion_point = _muscle_fields(model), control.activation, control.origin, control.insertion_point
    share = vertices.shape[0] // CHUNKS
    for c in prange(CHUNKS):
        base = c * share
        for m in range(c, muscles[0].shape[0], CHUNKS):
            if activation[m] == 0.0 or count[m] >= 0:
                continue
            used = kept[c]
            found = _fill(muscles, m, origin, insertion_point, points, visited[c], stack[c],
                          stamp[c:c + 1], vertices[base + used:base + share], deltas[base + used:base + share])
            if found <= share - used:
                first[m] = base + used
                count[m] = found
                kept[c] = used + found


@njit(**PARALLEL_OPTIONS)
def _muscle_frame(model, xp, frame):
    """The points the muscles act in: the 2D projection of eq. 3.21 with u scaled to arc
    length, u = R atan2(x - cx, z - cz), v = y (cm), written as 3D points (u, v, 0) so the
    falloff code serves both frames; or the 3D positions."""
    cx, cz, radius, uv_projection = model.axis_x, model.axis_z, model.radius, model.uv_projection
    for i in prange(xp.shape[0]):  # no call to libm in it (``_atan2``)
        _frame_point(xp, i, cx, cz, radius, uv_projection, frame, i)


@njit(**NUMBA_OPTIONS)
def _muscle_forces(model, xp, control, work, forces):
    """Eq. 3.1 on every vertex of each active muscle's region of influence: a pull toward
    the attachment O of a linear muscle, toward the centre of a sphincter, with O and I
    where the bones hold them (``control``). In the 2D projection of eq. 3.21 when
    ``uv_projection``, the forces then back-projected onto the mesh (eq. 3.22-3.25); else
    in 3D. Muscle forces do not depend on the skin's velocity and add no stiffness.

    The falloff δ (eq. 3.2-3.4) and the flood fill's region are evaluated where the skin
    is attached (``attached_regions``: where the bones hold it, ``control.target``), not
    where it has moved: a muscle pulls the same patch of skin however far it carries it.
    The thesis evaluates them at the moving skin, so a lip drawn toward one side's
    muscles falls deeper into their falloff and is pulled harder still; at the forces of
    a full smile that feedback outweighs the skin and the mouth slides sideways (measured:
    happy held, the lower lip 1 cm off the midline from a 1e-16 asymmetry).
    ``regions: moving`` in the material keeps the thesis's form.

    A muscle with a ``protrusion`` p also pushes its region along the skin's rest normal
    n, with p a f δ: outward as incompressible tissue squeezed by a contraction bulges
    forward (the incisivi pouting the lips in a pucker, AU18), inward for p < 0 as a
    muscle over the teeth presses the skin onto them (the buccinator drawing the lip
    corners back into the cheek, AU14). Not in the thesis (p = 0 is its model), where a
    muscle only pulls in its own plane and cannot move the skin off the face's surface.
    The push keeps its direction, so it adds no stiffness.

    The regions not kept are found first, on every core (``_find_regions``); attached
    regions change only when the bones move, so each muscle's is kept in the workspace
    until they do (``Workspace``)."""
    _muscle_frame(model, xp, work.frame)
    frame = work.frame
    if model.attached_regions:
        _bones_moved(model, control.target, work)
    else:  # the thesis's regions move with the skin: found again at every step
        _forget_regions(work)
    points = work.attached if model.attached_regions else frame
    _find_regions(model, control, points, work)
    for m in range(model.muscle_kind.shape[0]):
        a_m = control.activation[m]
        if a_m == 0.0:
            continue
        if work.region_count[m] >= 0:
            first, count = work.region_first[m], work.region_count[m]
            region, delta = work.kept_vertex[first:first + count], work.kept_delta[first:first + count]
        else:  # no room for it in the store
            count = _region_of_influence(model, m, control.origin, control.insertion_point, points, work)
            region, delta = work.region[:count], work.delta[:count]
        _pull_region(model, m, a_m, region, delta, count, frame, xp, control, forces.force)


@njit(**PARALLEL_OPTIONS)
def _pull_region(model, m, a_m, region, delta, count, frame, xp, control, force):
    """Eq. 3.1 at the ``count`` vertices of muscle m's region (``region``, with their δ),
    at activation a_m, back-projected (eq. 3.22-3.25) when the muscles act in the 2D
    projection, and the muscle's push along the rest normal (``_muscle_forces``). Each
    vertex is in a region once, so the slices write apart."""
    pinned, normal, uv_projection, ring = model.pinned, model.rest_vertex_normal, model.uv_projection, _ring_fields(model)
    origin = control.origin[m]
    pull = a_m * model.muscle_force[m]
    protrusion = model.muscle_protrusion[m]
    for c in prange(CHUNKS):
        f3 = np.empty(3)
        first, end = _chunk(c, count)
        for k in range(first, end):
            i = region[k]
            if pinned[i]:
                continue
            length = 0.0
            for d in range(3):
                f3[d] = origin[d] - frame[i, d]
                length += f3[d] ** 2
            scale = pull * delta[k] / max(math.sqrt(length), LENGTH_EPS)  # eq. 3.1
            if uv_projection:
                _back_project(ring, i, scale * f3[0], scale * f3[1], frame, xp, f3)
            else:
                for d in range(3):
                    f3[d] *= scale
            push = pull * delta[k] * protrusion
            for d in range(3):
                force[i, d] += f3[d] + push * normal[i, d]


@njit(**NUMBA_OPTIONS)
def _bones_moved(model, target, work):
    """If the bones hold the skin elsewhere than where the kept regions were found
    (``Workspace``), forget the regions and put the points where the skin is attached
    into the muscles' frame (``work.attached``) for the flood fills to come."""
    same = work.known[0] == 1
    if same:
        for i in range(target.shape[0]):
            for d in range(3):
                if target[i, d] != work.bones[i, d]:
                    same = False
                    break
            if not same:
                break
    if same:
        return
    work.bones[:] = target
    work.known[0] = 1
    _forget_regions(work)
    _muscle_frame(model, target, work.attached)


@njit(**NUMBA_OPTIONS)
def _forget_regions(work):
    """Empty the store of regions (``Workspace``): every region is found again."""
    work.region_count[:] = -1
    work.kept[:] = 0


@njit(**NUMBA_OPTIONS)
def _rotate(px, py, pz, hx, hy, hz, ax, ay, az, angle):
    """Point P turned by ``angle`` about the axis through H with unit direction A
    (Rodrigues' formula)."""
    vx, vy, vz = px - hx, py - hy, pz - hz
    c, s = math.cos(angle), math.sin(angle)
    dot = (ax * vx + ay * vy + az * vz) * (1.0 - c)
    return (hx + vx * c + (ay * vz - az * vy) * s + ax * dot,
            hy + vy * c + (az * vx - ax * vz) * s + ay * dot,
            hz + vz * c + (ax * vy - ay * vx) * s + az * dot)


@njit(**NUMBA_OPTIONS)
def _rig_control(model, control):
    """Where the jaw and eyelids (facesim.rig) take each vertex under the activations of
    ``control``: its rest position slid over the eyeball by the lid closure c and the
    levator's raise a (c Δ_close + a (1 - c) Δ_raise in cylindrical coordinates about the
    eye's horizontal axis), then turned about the jaw hinge by w θ, into ``control.target``.
    ``control.hold`` is the extra stiffness driving the lips and lid contours,
    drive * min(1, 10 a) for the activation a of their control (a lid's: the larger of its
    closure and its raise): zero while the jaw and lids are at rest. Then the muscles'
    ends, from where the bones hold them (``_muscle_geometry``)."""
    activation = control.activation
    theta = model.jaw_max * activation[model.jaw_column] if model.jaw_column >= 0 else 0.0
    for i in range(model.rest_position.shape[0]):
        px, py, pz = model.rest_position[i, 0], model.rest_position[i, 1], model.rest_position[i, 2]
        column = model.drive_column[i]
        a = activation[model.lid_raise_column[i]] if model.lid_raise_column[i] >= 0 else 0.0
        driving = max(activation[column], a) if column >= 0 else 0.0
        control.hold[i] = model.drive * model.drive_weight[i] * min(1.0, 10.0 * driving)
        if model.lid_column[i] >= 0:
            c = activation[model.lid_column[i]]
            a *= 1.0 - c  # the levator lets go as the lid closes: a blink closes a raised lid
            if c != 0.0 or a != 0.0:
                dy = py - model.lid_centre[i, 1]
                dz = pz - model.lid_centre[i, 2]
                phi = math.atan2(dy, dz) + c * model.lid_delta[i, 1] + a * model.lid_raise_delta[i, 1]
                r = math.sqrt(dy * dy + dz * dz) + c * model.lid_delta[i, 2] + a * model.lid_raise_delta[i, 2]
                px += c * model.lid_delta[i, 0] + a * model.lid_raise_delta[i, 0]
                py = model.lid_centre[i, 1] + r * math.sin(phi)
                pz = model.lid_centre[i, 2] + r * math.cos(phi)
        if theta != 0.0 and model.jaw_weight[i] > 0.0:
            h, a = model.jaw_hinge, model.jaw_axis
            px, py, pz = _rotate(px, py, pz, h[0], h[1], h[2], a[0], a[1], a[2], model.jaw_weight[i] * theta)
        control.target[i, 0] = px
        control.target[i, 1] = py
        control.target[i, 2] = pz
    _muscle_geometry(model, control.target, control.origin, control.insertion_point)


@njit(**NUMBA_OPTIONS)
def _muscle_geometry(model, target, origin, insertion_point):
    """The muscles' ends in the frame they act in (eq. 3.21's projection, or 3D), from
    where the bones hold them (``target``): O is the mean of the muscle's centre vertices
    (a linear muscle's attachment), I its insertion (a sphincter has none; I = O)."""
    for m in range(model.muscle_kind.shape[0]):
        for d in range(3):
            origin[m, d] = 0.0
        count = model.muscle_centre_start[m + 1] - model.muscle_centre_start[m]
        for k in range(model.muscle_centre_start[m], model.muscle_centre_start[m + 1]):
            _frame_point(target, model.muscle_centre_index[k], model.axis_x, model.axis_z, model.radius,
                         model.uv_projection, insertion_point, m)
            for d in range(3):
                origin[m, d] += insertion_point[m, d] / count
        if model.muscle_kind[m] == LINEAR:
            _frame_point(target, model.muscle_insertion[m], model.axis_x, model.axis_z, model.radius,
                         model.uv_projection, insertion_point, m)
        else:
            for d in range(3):
                insertion_point[m, d] = origin[m, d]


def _arctangent_series(degree=10):
    """Coefficients c of atan(r) = r Σ c_k r^2k on |r| ≤ tan(π/8), interpolated at
    Chebyshev points in r² (numpy.polynomial): within 2e-15 of numpy's arctan there."""
    from numpy.polynomial import Chebyshev, Polynomial

    def over_r(s):
        r = np.sqrt(s)
        return np.where(r > 0.0, np.arctan(r) / np.where(r > 0.0, r, 1.0), 1.0)

    bound = math.tan(math.pi / 8.0) ** 2
    return tuple(float(c) for c in Chebyshev.interpolate(over_r, degree, domain=[0.0, bound]).convert(kind=Polynomial).coef)


ARCTANGENT_SERIES = _arctangent_series()
TAN_PI_8 = math.tan(math.pi / 8.0)


@njit(**NUMBA_OPTIONS)
def _atan2(y, x):
    """atan2(y, x) without a branch or a call (math.atan2 is a call to libm, and Numba's
    vector maths library is not in its wheels), written for vector lanes, although LLVM
    compiles the muscles' frame loop to scalar arithmetic (read from its code on
    2026-12-03): the gain is the call and the branches saved:
    the ratio of the smaller to the larger magnitude, reduced to |r| ≤ tan(π/8) by
    atan r = π/4 + atan((r - 1) / (r + 1)), ``ARCTANGENT_SERIES``, then the octant.
    Within 4e-15 (relative) of numpy's arctan2, signed zeros aside."""
    ax, ay = abs(x), abs(y)
    low, high = min(ax, ay), max(ax, ay)
    r = low / high if high > 0.0 else 0.0
    reduced = r > TAN_PI_8
    r = (r - 1.0) / (r + 1.0) if reduced else r
    s = r * r
    series = 0.0
    for k in range(len(ARCTANGENT_SERIES) - 1, -1, -1):
        series = series * s + ARCTANGENT_SERIES[k]
    angle = r * series + (0.25 * math.pi if reduced else 0.0)
    angle = 0.5 * math.pi - angle if ay > ax else angle
    angle = math.pi - angle if x < 0.0 else angle
    return math.copysign(angle, y)


@njit(**NUMBA_OPTIONS)
def _frame_point(x, i, axis_x, axis_z, radius, uv_projection, out, row):
    """Vertex i in the muscles' frame, into ``out[row]``: (R atan2(x - cx, z - cz), y, 0)
    of eq. 3.21, or 3D. With ``_atan2`` instead of libm's (the muscles' frame, one core
    at 27,614 vertices: 11 -> 4.5 ns a vertex, 2026-12-02)."""
    if uv_projection:
        out[row, 0] = radius * _atan2(x[i, 0] - axis_x, x[i, 2] - axis_z)
        out[row, 1] = x[i, 1]
        out[row, 2] = 0.0
    else:
        for d in range(3):
            out[row, d] = x[i, d]


@njit(**NUMBA_OPTIONS)
def _contacts(model, state):
    """Lips and lids do not pass through each other: each pair (upper, lower) is kept at
    least its gap apart along its contact normal n (straight up for the lids, turned back
    for the lips: facesim.rig), by moving both half the overlap along n and giving them
    their mean velocity along n (an inelastic contact; a single-layer mesh has no
    collisions). Across n they slide freely."""
    x, v, pinned = state.x, state.v, model.pinned
    for k in range(model.contact_upper.shape[0]):
        u = model.contact_upper[k]
        l = model.contact_lower[k]
        n = model.contact_normal[k]
        overlap = model.contact_gap[k]
        for d in range(3):
            overlap -= n[d] * (x[u, d] - x[l, d])
        if overlap <= 0.0:
            continue
        share_u = 0.0 if pinned[u] else (1.0 if pinned[l] else 0.5)
        share_l = 0.0 if pinned[l] else 1.0 - share_u
        vn_u = 0.0
        vn_l = 0.0
        for d in range(3):
            x[u, d] += share_u * overlap * n[d]
            x[l, d] -= share_l * overlap * n[d]
            vn_u += n[d] * v[u, d]
            vn_l += n[d] * v[l, d]
        if vn_u < vn_l:
            mean = 0.5 * (vn_u + vn_l)
            for d in range(3):
                v[u, d] += ((0.0 if pinned[u] else mean) - vn_u) * n[d]
                v[l, d] += ((0.0 if pinned[l] else mean) - vn_l) * n[d]


@njit(**NUMBA_OPTIONS)
def _triangle_normal(x, faces, t):
    """(b - a) x (c - a) of triangle t: its normal, twice its area long."""
    a = faces[t, 0]
    b = faces[t, 1]
    c = faces[t, 2]
    ux = x[b, 0] - x[a, 0]
    uy = x[b, 1] - x[a, 1]
    uz = x[b, 2] - x[a, 2]
    wx = x[c, 0] - x[a, 0]
    wy = x[c, 1] - x[a, 1]
    wz = x[c, 2] - x[a, 2]
    return uy * wz - uz * wy, uz * wx - ux * wz, ux * wy - uy * wx


@njit(**NUMBA_OPTIONS)
def _against_surroundings(x, faces, t, normals):
    """Whether triangle t faces against the skin around it: its normal against the sum
    of its corners' vertex normals (``normals``, from ``_vertex_normals``)."""
    nx, ny, nz = _triangle_normal(x, faces, t)
    around = 0.0
    for k in range(3):
        v = faces[t, k]
        around += nx * normals[v, 0] + ny * normals[v, 1] + nz * normals[v, 2]
    return around <= 0.0


@njit(**NUMBA_OPTIONS)
def _triangle_checks(x, faces, rest_normal, rest_area, rest_against, normals):
    """Inverted triangles, the first of them, and the smallest area relative to rest.

    A triangle is inverted when it has turned over (its normal against its rest normal)
    and folded over the skin around it: it now faces against its surroundings where it
    faced with them at rest (``_against_surroundings``; or the other way round for the
    few triangles in the sharpest creases). That is the overlap of elements that edge
    repulsion exists to prevent (thesis fig. 3.16). Turning over alone is not enough: a
    patch of skin that turns as a whole (a lip rolling at the mouth corner, a lid sliding
    over the eyeball) keeps facing with its surroundings, and a sliver triangle turns over
    its long edge when its short vertex moves a fraction of a millimetre out of the surface.
    """
    inverted = 0
    first = -1
    smallest = np.inf
    have_normals = False
    for t in range(faces.shape[0]):
        nx, ny, nz = _triangle_normal(x, faces, t)
        smallest = min(smallest, 0.5 * math.sqrt(nx * nx + ny * ny + nz * nz) / rest_area[t])
        if nx * rest_normal[t, 0] + ny * rest_normal[t, 1] + nz * rest_normal[t, 2] > 0.0:
            continue
        if not have_normals:
            _vertex_normals(x, faces, normals)
            have_normals = True
        if _against_surroundings(x, faces, t, normals) == rest_against[t]:
            continue
        inverted += 1
        if first < 0:
            first = t
    return inverted, first, smallest


@njit(**NUMBA_OPTIONS)
def _vertex_normals(x, faces, out):
    """Area-weighted vertex normals for smooth shading, written into ``out`` (n, 3)."""
    out[:] = 0.0
    for t in range(faces.shape[0]):
        nx, ny, nz = _triangle_normal(x, faces, t)
        for k in range(3):
            v = faces[t, k]
            out[v, 0] += nx
            out[v, 1] += ny
            out[v, 2] += nz
    for i in range(x.shape[0]):
        length = math.sqrt(out[i, 0] ** 2 + out[i, 1] ** 2 + out[i, 2] ** 2)
        if length > 0.0:
            for d in range(3):
                out[i, d] /= length
