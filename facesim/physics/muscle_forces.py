"""The muscles' forces: linear muscles, eq. 3.1-3.4, and sphincters
(facesim.physics.muscles), in the 2D projection of eq. 3.21, back-projected onto the mesh
(eq. 3.22-3.25), over the region of influence found by the stack-based flood fill of
section 3.3. The regions are found on every core for a large mesh (``_find_regions``) and,
where the muscles act where the bones hold the skin, kept while the bones stay.
"""

import math

import numpy as np
from numba import njit, prange

from ..config import CHUNKS, LENGTH_EPS, NEGLIGIBLE_DELTA, NUMBA_OPTIONS, PARALLEL_OPTIONS
from .muscles import SPHINCTER
from .numerics import _chunk, _copy_rows, _frame_point


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
    _copy_rows(target, work.bones)
    work.known[0] = 1
    _forget_regions(work)
    _muscle_frame(model, target, work.attached)


@njit(**NUMBA_OPTIONS)
def _forget_regions(work):
    """Empty the store of regions (``Workspace``): every region is found again."""
    work.region_count[:] = -1
    work.kept[:] = 0
