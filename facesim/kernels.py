"""Numba kernels of the simulation (thesis chapter 3). Arrays and scalars in, outputs
written into arrays passed last; no Python objects. One kernel per physical term:

- ``_spring_terms``     non-linear springs, eq. 3.6 and the g of eq. 3.17
- ``_repulsion_terms``  edge repulsion, eq. 3.7 and the h of eq. 3.17
- ``_muscle_forces``    linear muscles, eq. 3.1-3.4, and sphincters (facesim.muscles), in
                        the 2D projection of eq. 3.21, back-projected onto the mesh
                        (eq. 3.22-3.25), over the region of influence found by the
                        stack-based flood fill of section 3.3
- ``_rig_targets``      where the jaw and eyelids (facesim.rig) take the skin, and
  ``_muscle_geometry``  where the muscles' ends are as the bones move
- ``_velocity_update``  the quasi-implicit per-vertex solve of eq. 3.19 (with the Δt on
                        the spring and repulsion terms that the printed eq. 3.20 drops),
                        viscous damping eq. 3.10, positions by eq. 3.16
- ``_simulate``         predictor eq. 3.14 and the above, for every sub-step of every
                        frame (Algorithm 3.4.1), with per-frame diagnostics.

The velocity solve, for vertex i with predicted positions X* = X + Δt V (eq. 3.14):

    V' = (m V + Δt T + Δt Σ_j g_ij (X_i - X_j*) + Δt Σ_k h_ik (X_i - P_k*))
         / (m + Δt c - Δt² (Σ_j g_ij + Σ_k h_ik))

``_spring_terms`` and ``_repulsion_terms`` accumulate the sums of g and h (``stiff``) and
of the g (X_i - X_j*) and h (X_i - P_k*) products (``pull``; it also carries the
edge-repulsion reactions, explicitly).
"""

import math

import numpy as np
from numba import njit

from .config import LENGTH_EPS, NEGLIGIBLE_DELTA, NUMBA_OPTIONS

#: Status codes returned by ``_simulate``.
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
def _power(base, exponent):
    """base ** exponent, by repeated squaring when the exponent is a whole number (the
    thesis's γ = ζ = 5): several times faster than the general pow in the inner loops."""
    if exponent == math.floor(exponent) and 0.0 <= exponent <= 64.0:
        result = 1.0
        e = int(exponent)
        while e > 0:
            if e & 1:
                result *= base
            base *= base
            e >>= 1
        return result
    return base**exponent


@njit(**NUMBA_OPTIONS)
def _nonlinear_coefficient(length, rest, k0, exponent, unit):
    """-(1 + ((|X| - d) / u)²)^γ k0 (|X| - d) / |X|: the g of eq. 3.17 (h with ζ). The
    thesis's stretch is in cm (u = 1); on a finer mesh of the same face u is its edge
    length relative to the default face's, so the same strain stiffens the same way."""
    stretch = length - rest
    relative = stretch / unit
    return -_power(1.0 + relative * relative, exponent) * k0 * stretch / max(length, LENGTH_EPS)


@njit(**NUMBA_OPTIONS)
def _spring_terms(x, xp, spring_indices, spring_rest_length, k0, gamma, unit, stiff, pull):
    """Springs on the mesh edges, eq. 3.6, evaluated at the predicted positions xp."""
    for s in range(spring_indices.shape[0]):
        i = spring_indices[s, 0]
        j = spring_indices[s, 1]
        dx = xp[i, 0] - xp[j, 0]
        dy = xp[i, 1] - xp[j, 1]
        dz = xp[i, 2] - xp[j, 2]
        g = _nonlinear_coefficient(math.sqrt(dx * dx + dy * dy + dz * dz), spring_rest_length[s], k0, gamma, unit)
        stiff[i] += g
        stiff[j] += g
        for d in range(3):
            pull[i, d] += g * (x[i, d] - xp[j, d])
            pull[j, d] += g * (x[j, d] - xp[i, d])


@njit(**NUMBA_OPTIONS)
def _tissue_terms(x, target, tissue, hold, stiff, pull):
    """Hypodermis springs: each vertex tied to its target (its rest position, moved by the
    jaw and eyelids) with stiffness k_t + hold_i, the soft tissue that attaches skin to
    bone. Not in the thesis (tissue = 0 is its model); a spring mesh has no bending
    stiffness, so under muscle pull it wrinkles and creeps without ever settling, and
    these springs give every mode a restoring force. ``hold`` holds the skin over the
    mandible and the lid contours to their targets while the jaw and lids move."""
    for i in range(x.shape[0]):
        k = tissue + hold[i]
        stiff[i] -= k
        for d in range(3):
            pull[i, d] -= k * (x[i, d] - target[i, d])


@njit(**NUMBA_OPTIONS)
def _foot_on_edge(xp, i, a, b, out):
    """P_k of eq. 3.7: the projection of vertex i onto the line through edge (a, b).
    Writes P into ``out`` and returns its parameter t (P = a + t (b - a))."""
    ex = xp[b, 0] - xp[a, 0]
    ey = xp[b, 1] - xp[a, 1]
    ez = xp[b, 2] - xp[a, 2]
    t = ((xp[i, 0] - xp[a, 0]) * ex + (xp[i, 1] - xp[a, 1]) * ey + (xp[i, 2] - xp[a, 2]) * ez) / max(
        ex * ex + ey * ey + ez * ez, LENGTH_EPS
    )
    out[0] = xp[a, 0] + t * ex
    out[1] = xp[a, 1] + t * ey
    out[2] = xp[a, 2] + t * ez
    return t


@njit(**NUMBA_OPTIONS)
def _repulsion_terms(x, xp, repulsion_vertex, repulsion_edge, repulsion_rest_distance, k0, zeta, unit, stiff, pull):
    """Edge repulsion, eq. 3.7: each vertex is held at its rest altitude above the
    opposite edge of each of its triangles.

    R_ik acts on the vertex (implicitly, through h in the velocity solve) and its
    reaction -R_ik on the edge's ends, split (1 - t) : t by where the foot P_k lies. The
    thesis leaves the reaction out, but without it the term is not conservative and a
    perturbed face at rest never settles (measured: kinetic energy grows); with it the
    term derives from a potential in the point-to-line distance.
    """
    foot = np.empty(3)
    for r in range(repulsion_vertex.shape[0]):
        i = repulsion_vertex[r]
        a = repulsion_edge[r, 0]
        b = repulsion_edge[r, 1]
        t = _foot_on_edge(xp, i, a, b, foot)
        dx = xp[i, 0] - foot[0]
        dy = xp[i, 1] - foot[1]
        dz = xp[i, 2] - foot[2]
        h = _nonlinear_coefficient(math.sqrt(dx * dx + dy * dy + dz * dz), repulsion_rest_distance[r], k0, zeta, unit)
        stiff[i] += h
        pull[i, 0] += h * (x[i, 0] - foot[0])
        pull[i, 1] += h * (x[i, 1] - foot[1])
        pull[i, 2] += h * (x[i, 2] - foot[2])
        wa = -(1.0 - t) * h
        wb = -t * h
        pull[a, 0] += wa * dx
        pull[a, 1] += wa * dy
        pull[a, 2] += wa * dz
        pull[b, 0] += wb * dx
        pull[b, 1] += wb * dy
        pull[b, 2] += wb * dz


@njit(**NUMBA_OPTIONS)
def _project_uv(xp, axis_x, axis_z, radius, uv):
    """Eq. 3.21 with u scaled to arc length: u = R atan2(x - cx, z - cz), v = y (cm).
    Written as 3D points (u, v, 0) so the falloff code serves both frames."""
    for i in range(xp.shape[0]):
        _frame_point(xp, i, axis_x, axis_z, radius, True, uv[i])


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


@njit(**NUMBA_OPTIONS)
def _delta(m, muscle_kind, muscle_axes, muscle_origin, muscle_insertion_point, muscle_cos_zone, muscle_r, muscle_r_max,
           px, py, pz):
    """δ of muscle m at point P: eq. 3.4 for a linear muscle; for a sphincter, δ_R of
    eq. 3.3 in the elliptical radius ρ = |((u - u_c) / a, (v - v_c) / b)| (1 on its ring)."""
    if muscle_kind[m] == SPHINCTER:
        du = (px - muscle_origin[m, 0]) / muscle_axes[m, 0]
        dv = (py - muscle_origin[m, 1]) / muscle_axes[m, 1]
        return _radial(math.sqrt(du * du + dv * dv), muscle_r[m], muscle_r_max[m])
    return _falloff(muscle_origin[m, 0], muscle_origin[m, 1], muscle_origin[m, 2],
                    muscle_insertion_point[m, 0], muscle_insertion_point[m, 1], muscle_insertion_point[m, 2],
                    px, py, pz, muscle_cos_zone[m], muscle_r[m], muscle_r_max[m])


@njit(**NUMBA_OPTIONS)
def _back_project(i, fu, fv, uv, xp, neighbour_start, neighbour_index, ring_start, ring_a, ring_b, out):
    """Eq. 3.22-3.25: carry the 2D force (fu, fv) at vertex i onto the mesh.

    The one-ring triangle (i, a, b) whose 2D wedge contains the force is found by writing
    the force in the basis of its two 2D edges, f = α e_a + β e_b with α, β ≥ 0; the same
    combination of the 3D edges lies in the triangle's plane and projects to a vector
    parallel to f. Its length is set to |f|. A force that leaves the mesh (a vertex on a
    boundary pulled outward) keeps only its component along the boundary edge closest in
    direction. Returns False, leaving ``out`` zero, when no edge points along it.
    """
    out[0] = 0.0
    out[1] = 0.0
    out[2] = 0.0
    magnitude = math.sqrt(fu * fu + fv * fv)
    if magnitude == 0.0:
        return False
    for k in range(ring_start[i], ring_start[i + 1]):
        a = ring_a[k]
        b = ring_b[k]
        au = uv[a, 0] - uv[i, 0]
        av = uv[a, 1] - uv[i, 1]
        bu = uv[b, 0] - uv[i, 0]
        bv = uv[b, 1] - uv[i, 1]
        det = au * bv - av * bu
        if abs(det) < LENGTH_EPS:
            continue
        alpha = (fu * bv - fv * bu) / det
        beta = (au * fv - av * fu) / det
        if alpha >= 0.0 and beta >= 0.0:
            for d in range(3):
                out[d] = alpha * (xp[a, d] - xp[i, d]) + beta * (xp[b, d] - xp[i, d])
            scale = magnitude / max(math.sqrt(out[0] ** 2 + out[1] ** 2 + out[2] ** 2), LENGTH_EPS)
            for d in range(3):
                out[d] *= scale
            return True
    best = 0.0
    best_j = -1
    for k in range(neighbour_start[i], neighbour_start[i + 1]):
        j = neighbour_index[k]
        eu = uv[j, 0] - uv[i, 0]
        ev = uv[j, 1] - uv[i, 1]
        cosine = (eu * fu + ev * fv) / max(math.sqrt(eu * eu + ev * ev) * magnitude, LENGTH_EPS)
        if cosine > best:
            best = cosine
            best_j = j
    if best_j < 0:
        return False
    length = 0.0
    for d in range(3):
        out[d] = xp[best_j, d] - xp[i, d]
        length += out[d] ** 2
    scale = best * magnitude / max(math.sqrt(length), LENGTH_EPS)
    for d in range(3):
        out[d] *= scale
    return True


@njit(**NUMBA_OPTIONS)
def _region_of_influence(
    m, frame, muscle_kind, muscle_axes, muscle_origin, muscle_insertion_point, muscle_insertion, muscle_cos_zone,
    muscle_r, muscle_r_max, neighbour_start, neighbour_index, visited, stamp, stack, region, delta,
):
    """The stack-based flood fill of section 3.3 for muscle m: start at the insertion,
    pop a vertex, evaluate its δ (eq. 3.4), and push its neighbours only when δ is not
    negligible. Writes the region's vertices and their δ into ``region`` and ``delta``
    and returns how many there are. ``visited[i] == stamp`` marks vertex i as pushed."""
    count = 0
    top = 0
    stack[0] = muscle_insertion[m]
    visited[muscle_insertion[m]] = stamp
    while top >= 0:
        i = stack[top]
        top -= 1
        d = _delta(m, muscle_kind, muscle_axes, muscle_origin, muscle_insertion_point, muscle_cos_zone, muscle_r,
                   muscle_r_max, frame[i, 0], frame[i, 1], frame[i, 2])
        if d <= NEGLIGIBLE_DELTA:
            continue
        region[count] = i
        delta[count] = d
        count += 1
        for k in range(neighbour_start[i], neighbour_start[i + 1]):
            j = neighbour_index[k]
            if visited[j] != stamp:
                visited[j] = stamp
                top += 1
                stack[top] = j
    return count


@njit(**NUMBA_OPTIONS)
def _muscle_forces(
    frame, xp, activation, muscle_kind, muscle_axes, muscle_origin, muscle_insertion_point, muscle_insertion,
    muscle_cos_zone, muscle_r, muscle_r_max, muscle_force, pinned, neighbour_start, neighbour_index, ring_start,
    ring_a, ring_b, uv_projection, force, visited, stamp, stack, region, delta,
):
    """Eq. 3.1 on every vertex of each active muscle's region of influence: a pull toward
    the attachment O of a linear muscle, toward the centre of a sphincter.

    ``frame`` holds the points the muscles act in: the 2D projection (u, v, 0) of eq. 3.21
    when ``uv_projection``, the forces then back-projected onto the mesh, or the 3D
    positions themselves. ``muscle_origin`` and ``muscle_insertion_point`` are O and I at
    rest in that frame. ``force`` (n, 3) is accumulated into; ``visited``, ``stack``,
    ``region`` and ``delta`` are (n,) workspaces. Returns the next free stamp.
    """
    f3 = np.empty(3)
    for m in range(muscle_origin.shape[0]):
        a_m = activation[m]
        if a_m == 0.0:
            continue
        stamp += 1
        count = _region_of_influence(m, frame, muscle_kind, muscle_axes, muscle_origin, muscle_insertion_point,
                                     muscle_insertion, muscle_cos_zone, muscle_r, muscle_r_max, neighbour_start,
                                     neighbour_index, visited, stamp, stack, region, delta)
        for k in range(count):
            i = region[k]
            if pinned[i]:
                continue
            length = 0.0
            for d in range(3):
                f3[d] = muscle_origin[m, d] - frame[i, d]
                length += f3[d] ** 2
            scale = a_m * muscle_force[m] * delta[k] / max(math.sqrt(length), LENGTH_EPS)  # eq. 3.1
            if uv_projection:
                _back_project(i, scale * f3[0], scale * f3[1], frame, xp,
                              neighbour_start, neighbour_index, ring_start, ring_a, ring_b, f3)
            else:
                for d in range(3):
                    f3[d] *= scale
            for d in range(3):
                force[i, d] += f3[d]
    return stamp


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
def _rig_targets(rest_position, controls, jaw_column, jaw_weight, jaw_hinge, jaw_axis, jaw_max, lid_column, lid_centre,
                 lid_delta, drive_column, drive_weight, drive, target, hold):
    """Where the jaw and eyelids (facesim.rig) take each vertex under the activations
    ``controls`` (a row of the activation table): its rest position slid over the eyeball
    by the lid closure c, in cylindrical coordinates about the eye's horizontal axis,
    then turned about the jaw hinge by w θ. ``hold`` is the extra stiffness driving the
    lips and lid contours, drive * min(1, 10 a) for the activation a of their control:
    zero while the jaw and lids are at rest."""
    theta = jaw_max * controls[jaw_column] if jaw_column >= 0 else 0.0
    for i in range(rest_position.shape[0]):
        px, py, pz = rest_position[i, 0], rest_position[i, 1], rest_position[i, 2]
        hold[i] = drive * drive_weight[i] * min(1.0, 10.0 * controls[drive_column[i]]) if drive_column[i] >= 0 else 0.0
        if lid_column[i] >= 0:
            c = controls[lid_column[i]]
            if c != 0.0:
                dy = py - lid_centre[i, 1]
                dz = pz - lid_centre[i, 2]
                phi = math.atan2(dy, dz) + c * lid_delta[i, 1]
                r = math.sqrt(dy * dy + dz * dz) + c * lid_delta[i, 2]
                px += c * lid_delta[i, 0]
                py = lid_centre[i, 1] + r * math.sin(phi)
                pz = lid_centre[i, 2] + r * math.cos(phi)
        if theta != 0.0 and jaw_weight[i] > 0.0:
            px, py, pz = _rotate(px, py, pz, jaw_hinge[0], jaw_hinge[1], jaw_hinge[2],
                                 jaw_axis[0], jaw_axis[1], jaw_axis[2], jaw_weight[i] * theta)
        target[i, 0] = px
        target[i, 1] = py
        target[i, 2] = pz


@njit(**NUMBA_OPTIONS)
def _muscle_geometry(target, muscle_kind, muscle_insertion, centre_start, centre_index, axis_x, axis_z, radius,
                     uv_projection, origin, insertion_point):
    """The muscles' ends in the frame they act in (eq. 3.21's projection, or 3D), from
    where the bones hold them: O is the mean of the muscle's centre vertices (a linear
    muscle's attachment), I its insertion (a sphincter has none; I = O)."""
    for m in range(muscle_kind.shape[0]):
        for d in range(3):
            origin[m, d] = 0.0
        count = centre_start[m + 1] - centre_start[m]
        for k in range(centre_start[m], centre_start[m + 1]):
            _frame_point(target, centre_index[k], axis_x, axis_z, radius, uv_projection, insertion_point[m])
            for d in range(3):
                origin[m, d] += insertion_point[m, d] / count
        if muscle_kind[m] == LINEAR:
            _frame_point(target, muscle_insertion[m], axis_x, axis_z, radius, uv_projection, insertion_point[m])
        else:
            for d in range(3):
                insertion_point[m, d] = origin[m, d]


@njit(**NUMBA_OPTIONS)
def _frame_point(x, i, axis_x, axis_z, radius, uv_projection, out):
    """Vertex i in the muscles' frame: (R atan2(x - cx, z - cz), y, 0) of eq. 3.21, or 3D."""
    if uv_projection:
        out[0] = radius * math.atan2(x[i, 0] - axis_x, x[i, 2] - axis_z)
        out[1] = x[i, 1]
        out[2] = 0.0
    else:
        for d in range(3):
            out[d] = x[i, d]


@njit(**NUMBA_OPTIONS)
def _contacts(x, v, contact_upper, contact_lower, contact_gap, pinned):
    """Lips and lids do not pass through each other: each pair (upper, lower) is kept at
    least its gap apart vertically, by moving both half the overlap and giving them their
    mean vertical velocity (an inelastic contact; a single-layer mesh has no collisions)."""
    for k in range(contact_upper.shape[0]):
        u = contact_upper[k]
        l = contact_lower[k]
        overlap = contact_gap[k] - (x[u, 1] - x[l, 1])
        if overlap <= 0.0:
            continue
        share_u = 0.0 if pinned[u] else (1.0 if pinned[l] else 0.5)
        share_l = 0.0 if pinned[l] else 1.0 - share_u
        x[u, 1] += share_u * overlap
        x[l, 1] -= share_l * overlap
        if v[u, 1] < v[l, 1]:
            mean = 0.5 * (v[u, 1] + v[l, 1])
            v[u, 1] = 0.0 if pinned[u] else mean
            v[l, 1] = 0.0 if pinned[l] else mean


@njit(**NUMBA_OPTIONS)
def _velocity_update(x, v, force, stiff, pull, mass, damping, dt, pinned, v_out):
    """Eq. 3.19 solved for V' per vertex (see the module docstring). Compressed springs
    make g positive and shrink the denominator; it is kept at least m, the inertia of the
    explicit update, so it never reaches zero."""
    for i in range(x.shape[0]):
        if pinned[i]:
            v_out[i, 0] = 0.0
            v_out[i, 1] = 0.0
            v_out[i, 2] = 0.0
            continue
        denominator = max(mass + dt * damping - dt * dt * stiff[i], mass)
        for d in range(3):
            v_out[i, d] = (mass * v[i, d] + dt * force[i, d] + dt * pull[i, d]) / denominator


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
def _simulate(
    faces, rest_normal, rest_area, rest_against, pinned, neighbour_start, neighbour_index, ring_start, ring_a, ring_b,
    spring_indices, spring_rest_length, repulsion_vertex, repulsion_edge, repulsion_rest_distance,
    muscle_kind, muscle_axes, muscle_insertion, muscle_centre_start, muscle_centre_index, muscle_cos_zone, muscle_r,
    muscle_r_max, muscle_force, axis_x, axis_z, radius, rest_position,
    jaw_column, jaw_weight, jaw_hinge, jaw_axis, jaw_max, lid_column, lid_centre, lid_delta, drive_column,
    drive_weight, contact_upper, contact_lower, contact_gap, mass, damping, k0, gamma, zeta, length_unit, tissue, drive,
    edge_repulsion, uv_projection, activations, start, stop, dt, substeps, energy_limit, stop_on_inversion,
    x, v, positions, kinetic_energy, inverted, smallest_area,
):
    """Algorithm 3.4.1: ``substeps`` steps of Δt / substeps per frame, for frames
    ``start`` to ``stop`` of ``activations`` (frames, muscles and controls): the caller
    runs a long animation in pieces, so that Ctrl-C and SIGTERM act between them. x and v
    (n, 3) are the state, advanced in place. Within a frame the controls (jaw, eyelids) move linearly from the previous
    frame's values, so the targets never jump.

    Writes positions (frames, n, 3) and per-frame diagnostics. Returns (status, frame,
    element): OK, or the first frame that is NOT_FINITE (element: a vertex), INVERTED
    (a triangle; only when ``stop_on_inversion``) or RUNAWAY (kinetic energy above
    ``energy_limit``).
    """
    n = x.shape[0]
    h = dt / substeps
    xp = np.empty_like(x)
    frame = np.empty_like(x)
    v_new = np.empty_like(v)
    force = np.empty_like(x)
    pull = np.empty_like(x)
    stiff = np.empty(n)
    target = rest_position.copy()
    normals = np.empty_like(x)
    hold = np.zeros(n)
    controls = np.zeros(activations.shape[1])
    origin = np.empty((muscle_kind.shape[0], 3))
    insertion_point = np.empty((muscle_kind.shape[0], 3))
    _muscle_geometry(target, muscle_kind, muscle_insertion, muscle_centre_start, muscle_centre_index,
                     axis_x, axis_z, radius, uv_projection, origin, insertion_point)
    rigged = jaw_column >= 0 or lid_column.max() >= 0
    at_rest = True  # the targets are the rest positions: nothing to recompute while the controls stay at 0
    visited = np.zeros(n, dtype=np.int64)
    stack = np.empty(n, dtype=np.int64)
    region = np.empty(n, dtype=np.int64)
    delta = np.empty(n)
    stamp = 0
    for f in range(start, stop):
        for s in range(substeps):
            moving = False
            if rigged:
                blend = (s + 1.0) / substeps
                for c in range(muscle_kind.shape[0], controls.shape[0]):
                    previous = activations[f - 1, c] if f > 0 else 0.0
                    controls[c] = previous + blend * (activations[f, c] - previous)
                    moving = moving or controls[c] != 0.0 or previous != 0.0
            if moving or not at_rest:
                at_rest = not moving
                _rig_targets(rest_position, controls, jaw_column, jaw_weight, jaw_hinge, jaw_axis, jaw_max, lid_column,
                             lid_centre, lid_delta, drive_column, drive_weight, drive, target, hold)
                _muscle_geometry(target, muscle_kind, muscle_insertion, muscle_centre_start, muscle_centre_index,
                                 axis_x, axis_z, radius, uv_projection, origin, insertion_point)
            for i in range(n):
                for d in range(3):
                    if pinned[i]:
                        x[i, d] = target[i, d]  # the bone holds it
                        xp[i, d] = x[i, d]
                    else:
                        xp[i, d] = x[i, d] + h * v[i, d]  # eq. 3.14
            stiff[:] = 0.0
            pull[:] = 0.0
            force[:] = 0.0
            _spring_terms(x, xp, spring_indices, spring_rest_length, k0, gamma, length_unit, stiff, pull)
            _tissue_terms(x, target, tissue, hold, stiff, pull)
            if edge_repulsion:
                _repulsion_terms(x, xp, repulsion_vertex, repulsion_edge, repulsion_rest_distance, k0, zeta, length_unit,
                                 stiff, pull)
            if uv_projection:
                _project_uv(xp, axis_x, axis_z, radius, frame)
            else:
                frame[:] = xp
            stamp = _muscle_forces(frame, xp, activations[f], muscle_kind, muscle_axes, origin, insertion_point,
                                   muscle_insertion, muscle_cos_zone, muscle_r, muscle_r_max, muscle_force, pinned,
                                   neighbour_start, neighbour_index, ring_start, ring_a, ring_b, uv_projection, force,
                                   visited, stamp, stack, region, delta)
            _velocity_update(x, v, force, stiff, pull, mass, damping, h, pinned, v_new)
            for i in range(n):
                for d in range(3):
                    v[i, d] = v_new[i, d]
                    x[i, d] += h * v[i, d]  # eq. 3.16
            _contacts(x, v, contact_upper, contact_lower, contact_gap, pinned)
        bad = _not_finite(x)
        if bad < 0:
            bad = _not_finite(v)
        if bad >= 0:
            return NOT_FINITE, f, bad
        energy = 0.0
        for i in range(n):
            for d in range(3):
                energy += 0.5 * mass * v[i, d] * v[i, d]
                positions[f, i, d] = x[i, d]
        count, first, smallest = _triangle_checks(x, faces, rest_normal, rest_area, rest_against, normals)
        kinetic_energy[f] = energy
        inverted[f] = count
        smallest_area[f] = smallest
        if count > 0 and stop_on_inversion:
            return INVERTED, f, first
        if energy > energy_limit:
            return RUNAWAY, f, -1
    return OK, -1, -1


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
