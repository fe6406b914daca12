"""Slow, obviously correct NumPy versions of every simulation kernel, written from the
thesis's equations without looking at the Numba loops: vectorised where that is clearer,
brute force where the kernels are clever (the region of influence is a connected
component of a full scan instead of a flood fill). Tests compare the kernels to these.
"""

import numpy as np
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components

from facesim.config import NEGLIGIBLE_DELTA


def nonlinear(length, rest, k0, exponent, unit=1.0):
    """g (or h) of eq. 3.17, the stretch read in units of ``unit`` inside the power."""
    stretch = length - rest
    return -((1 + (stretch / unit) ** 2) ** exponent) * k0 * stretch / length


def spring_terms(x, xp, springs, rest, k0, gamma, unit=1.0):
    """Σ_j g_ij and Σ_j g_ij (X_i - X_j*) per vertex (eq. 3.6, 3.17)."""
    i, j = springs[:, 0], springs[:, 1]
    g = nonlinear(np.linalg.norm(xp[i] - xp[j], axis=1), rest, k0, gamma, unit)
    stiff = np.zeros(len(x))
    pull = np.zeros_like(x)
    np.add.at(stiff, i, g)
    np.add.at(stiff, j, g)
    np.add.at(pull, i, g[:, None] * (x[i] - xp[j]))
    np.add.at(pull, j, g[:, None] * (x[j] - xp[i]))
    return stiff, pull


def repulsion_terms(x, xp, vertex, edge, rest, k0, zeta, unit=1.0):
    """Σ_k h_ik and Σ_k h_ik (X_i - P_k*) per vertex (eq. 3.7, 3.17), plus the reactions
    -R_ik on the edge ends split by the foot's position."""
    a, b = xp[edge[:, 0]], xp[edge[:, 1]]
    e = b - a
    t = ((xp[vertex] - a) * e).sum(1) / (e * e).sum(1)
    foot = a + t[:, None] * e
    h = nonlinear(np.linalg.norm(xp[vertex] - foot, axis=1), rest, k0, zeta, unit)
    stiff = np.zeros(len(x))
    pull = np.zeros_like(x)
    np.add.at(stiff, vertex, h)
    np.add.at(pull, vertex, h[:, None] * (x[vertex] - foot))
    reaction = -h[:, None] * (xp[vertex] - foot)
    np.add.at(pull, edge[:, 0], (1 - t)[:, None] * reaction)
    np.add.at(pull, edge[:, 1], t[:, None] * reaction)
    return stiff, pull


def bending_terms(xp, target, hinge, weight, kb):
    """The bending energy E = ½ k_b Σ_e |Σ_k w_ek (X_k - target_k)|² (bending._bending_forces):
    its force -∂E/∂X and the scalar stiffness of eq. 3.19, -k_b Σ_e w_ek² at each vertex."""
    bend = np.einsum("ek,ekd->ed", weight, (xp - target)[hinge])
    force = np.zeros_like(xp)
    stiff = np.zeros(len(xp))
    np.add.at(force, hinge.ravel(), -kb * (weight[:, :, None] * bend[:, None, :]).reshape(-1, 3))
    np.add.at(stiff, hinge.ravel(), -kb * weight.ravel() ** 2)
    return stiff, force


def tissue_terms(x, target, tissue, hold=0.0):
    """Springs of stiffness tissue + hold tying each vertex to its target."""
    k = tissue + np.broadcast_to(hold, (len(x),))
    return -k, -k[:, None] * (x - target)


def project_uv(x, cx, cz, radius):
    """Eq. 3.21, u as arc length."""
    return np.column_stack([radius * np.arctan2(x[:, 0] - cx, x[:, 2] - cz), x[:, 1], np.zeros(len(x))])


def falloff(origin, insertion, points, cos_zone, r, r_max):
    """δ of eq. 3.2-3.4 for every point."""
    oi = insertion - origin
    op = points - origin
    dist = np.linalg.norm(op, axis=1)
    with np.errstate(invalid="ignore", divide="ignore"):
        cos_beta = op @ oi / (dist * np.linalg.norm(oi))
        angular = np.where(cos_beta >= cos_zone, (cos_beta - cos_zone) / (1 - cos_zone), 0.0)
    return np.where(dist > 0, angular * radial(dist, r, r_max), 0.0)


def radial(dist, r, r_max):
    """δ_R of eq. 3.3."""
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.where(
            dist <= r,
            np.cos(np.pi / 2 * (r - dist) / r),
            np.where(dist <= r_max, np.cos(np.pi / 2 * (dist - r) / (r_max - r)), 0.0),
        )


def delta(model, m, frame, origin=None, insertion=None):
    """δ of muscle m at every point: eq. 3.4 for a linear muscle; for a sphincter, δ_R of
    eq. 3.3 in the elliptical radius about its centre. The muscle's ends at rest unless
    ``origin`` and ``insertion`` (M, 3) say where the bones have taken them."""
    origin = (model.muscle_origin if origin is None else origin)[m]
    insertion = (model.muscle_insertion_point if insertion is None else insertion)[m]
    if model.muscle_kind[m] == 1:
        a, b = model.muscle_axes[m]
        rho = np.hypot((frame[:, 0] - origin[0]) / a, (frame[:, 1] - origin[1]) / b)
        return radial(rho, model.muscle_r[m], model.muscle_r_max[m])
    return falloff(origin, insertion, frame, model.muscle_cos_zone[m], model.muscle_r[m], model.muscle_r_max[m])


def region_of_influence(delta, insertion, edges, n):
    """Vertices with δ above negligible that connect to the insertion through such
    vertices: a brute-force scan, then a connected component."""
    inside = delta > NEGLIGIBLE_DELTA
    if not inside[insertion]:
        return np.zeros(0, dtype=int)
    keep = inside[edges[:, 0]] & inside[edges[:, 1]]
    e = edges[keep]
    graph = coo_matrix((np.ones(len(e)), (e[:, 0], e[:, 1])), shape=(n, n))
    _, label = connected_components(graph, directed=False)
    return np.flatnonzero(inside & (label == label[insertion]))


def back_project(i, force_2d, uv, x, faces, edges):
    """Eq. 3.22-3.25 by the affine map of each one-ring triangle whose 2D wedge holds the
    force, their unit directions averaged with weights sin φ sin(θ - φ) (f at angle φ in a
    wedge of angle θ; one wedge unless the ring folds); a force no wedge holds goes along the edges nearest it on either side,
    blended by the angle between them."""
    f = force_2d[:2]
    magnitude = np.linalg.norm(f)
    if magnitude == 0:
        return np.zeros(3)
    total = np.zeros(3)
    for face in faces[(faces == i).any(axis=1)]:
        k = list(face).index(i)
        a, b = face[(k + 1) % 3], face[(k + 2) % 3]
        basis = np.column_stack([uv[a, :2] - uv[i, :2], uv[b, :2] - uv[i, :2]])
        if abs(np.linalg.det(basis)) < 1e-12:
            continue
        alpha, beta = np.linalg.solve(basis, f)
        if alpha >= 0 and beta >= 0:
            f3 = alpha * (x[a] - x[i]) + beta * (x[b] - x[i])
            weight = alpha * beta * np.linalg.det(basis) ** 2 / (np.prod(np.linalg.norm(basis, axis=0)) * magnitude**2)
            total += weight * f3 / np.linalg.norm(f3)
    if np.linalg.norm(total) > 0:
        return total * magnitude / np.linalg.norm(total)

    neighbours = np.unique(np.concatenate([edges[edges[:, 0] == i, 1], edges[edges[:, 1] == i, 0]]))
    angle = {j: np.arctan2(*(uv[j, :2] - uv[i, :2])[::-1]) - np.arctan2(f[1], f[0]) for j in neighbours}
    to_q = {j: a % (2 * np.pi) for j, a in angle.items()}  # counter-clockwise from f to the edge
    from_p = {j: -a % (2 * np.pi) for j, a in angle.items()}  # counter-clockwise from the edge to f
    q, p = min(to_q, key=to_q.get), min(from_p, key=from_p.get)
    t = from_p[p] / (from_p[p] + to_q[q]) if from_p[p] + to_q[q] > 0 else 0.0

    def kept(j):
        e = uv[j, :2] - uv[i, :2]
        return max(0.0, e @ f / (np.linalg.norm(e) * magnitude)) * magnitude * (x[j] - x[i]) / np.linalg.norm(x[j] - x[i])

    return (1 - t) * kept(p) + t * kept(q)


def muscle_forces(model, xp, activation, target=None):
    """Eq. 3.1-3.4 on every vertex of every active muscle's region, the muscles' ends
    where ``target`` (the bones' positions; rest by default) holds them, δ and the
    regions where it attaches the skin (or at the moving skin: ``regions: moving``)."""
    force = np.zeros_like(xp)
    use_uv = model.material.uv_projection
    target = model.rest_position if target is None else target

    def in_frame(x):
        return project_uv(x, model.axis_x, model.axis_z, model.radius) if use_uv else x

    frame = in_frame(xp)
    attached = in_frame(target) if model.material.regions == "attached" else frame  # where δ is evaluated
    origins, insertions = muscle_geometry(model, target)
    edges = model.spring_indices
    for m in np.flatnonzero(activation[:model.muscle_count]):
        origin = origins[m]
        d = delta(model, m, attached, origins, insertions)
        for i in region_of_influence(d, model.muscle_insertion[m], edges, len(xp)):
            if model.pinned[i]:
                continue
            direction = origin - frame[i]
            f = activation[m] * model.muscle_force[m] * d[i] * direction / np.linalg.norm(direction)
            force[i] += back_project(i, f, frame, xp, model.faces, edges) if use_uv else f
            force[i] += activation[m] * model.muscle_force[m] * d[i] * model.muscle_protrusion[m] * model.rest_vertex_normal[i]
    return force


def muscle_geometry(model, target):
    """Each muscle's O (the mean of its centre vertices) and I (its insertion; a
    sphincter's is O) in the muscles' frame, from the bones' positions ``target``."""
    frame = project_uv(target, model.axis_x, model.axis_z, model.radius) if model.material.uv_projection else target
    muscles = model.muscles
    origin = np.array([frame[muscles.centre_index[a:b]].mean(axis=0)
                       for a, b in zip(muscles.centre_start[:-1], muscles.centre_start[1:])])
    insertion = np.where((model.muscle_kind == 1)[:, None], origin, frame[model.muscle_insertion])
    return origin, insertion


def rig_targets(model, activation):
    """Where the jaw and eyelids take each vertex (facesim.physics.rig): the lid closure c and the
    levator's raise a slide a vertex in cylindrical coordinates (x, φ, r) about its eye's
    horizontal axis by c Δ_close + a (1 - c) Δ_raise; then the jaw turns it by its weight w times θ = activation × max
    angle about the hinge axis (each lip rolled in about its own horizontal axis first),
    turns the lips drawn to a side about the face's vertical
    axis, and carries it by w times its glide (the glide columns' activations times their
    glides). And the drive holding the lips and lid contours:
    drive × weight × min(1, 10 a) for the activation a of their control (the jaw's: its
    largest of opening and glides)."""
    from scipy.spatial.transform import Rotation

    rig, p = model.rig, model.rest_position.copy()
    c = np.where(rig.lid_column >= 0, activation[np.maximum(rig.lid_column, 0)], 0.0)
    a = np.where(rig.lid_raise_column >= 0, activation[np.maximum(rig.lid_raise_column, 0)], 0.0)
    look = np.where(rig.lid_look_column >= 0, activation[np.maximum(rig.lid_look_column, 0)], 0.0)  # (n, 4)
    delta = (c[:, None] * rig.lid_delta + (a * (1 - c))[:, None] * rig.lid_raise_delta
             + (1 - c)[:, None] * np.einsum("ng,ngd->nd", look, rig.lid_look_delta))
    d = p - rig.lid_centre
    phi = np.arctan2(d[:, 1], d[:, 2]) + delta[:, 1]
    r = np.hypot(d[:, 1], d[:, 2]) + delta[:, 2]
    slid = np.column_stack([p[:, 0] + delta[:, 0], rig.lid_centre[:, 1] + r * np.sin(phi), rig.lid_centre[:, 2] + r * np.cos(phi)])
    p = np.where(((c != 0) | (a != 0) | look.any(axis=1))[:, None], slid, p)
    if rig.jaw_column >= 0:
        for k in range(2):  # each lip rolled in about the horizontal axis through its pivot, before the jaw turns
            turn = activation[rig.lip_roll_column[k]] * rig.lip_roll[:, k] * rig.lip_roll_angle[k]
            p = rig.lip_roll_pivot[k] + Rotation.from_rotvec(turn[:, None] * [1.0, 0.0, 0.0]).apply(p - rig.lip_roll_pivot[k])
        w = rig.jaw_weight + activation[rig.jaw_seal_column] * rig.jaw_seal  # the lips' seal changes the weight
        p = rig.jaw_hinge + Rotation.from_rotvec((w * rig.jaw_max * activation[rig.jaw_column])[:, None] * rig.jaw_axis
                                                 ).apply(p - rig.jaw_hinge)
        slide = rig.lip_shift @ (activation[rig.lip_shift_column] * [1.0, -1.0])  # the lips to one side, cm
        centre = np.array([model.arrays.axis_x, 0.0, model.arrays.axis_z])  # the face's vertical axis
        p = centre + Rotation.from_rotvec((slide / model.arrays.radius)[:, None] * [0.0, 1.0, 0.0]).apply(p - centre)
        p = p + rig.jaw_weight[:, None] * (activation[rig.jaw_glide_column] @ rig.jaw_glide)  # sealed lips glide too
    driven = rig.drive_column >= 0
    a = np.maximum(activation[np.maximum(rig.drive_column, 0)], a)
    if rig.jaw_column >= 0:
        jaw = max(activation[rig.jaw_glide_column].max(), activation[rig.lip_shift_column].max(),
                  activation[rig.lip_roll_column].max())
        a = np.where(rig.drive_column == rig.jaw_column, np.maximum(a, jaw), a)
    a = np.where((rig.drive_column >= 0) & (rig.drive_column == rig.lid_column), np.maximum(a, look.max(axis=1)), a)
    hold = np.where(driven, model.material.drive * rig.drive_weight * np.minimum(1.0, 10.0 * a), 0.0)
    return p, hold


def pressure_forces(model, xp, activation):
    """The air in the mouth on its wall (facesim.physics.pressure): each triangle's area
    vector ½ (X_j - X_i) × (X_k - X_i), a third to each corner at that corner's pressure,
    less the net across the face (x, y), taken from each vertex by its share of the pressure."""
    rig, out = model.rig, np.zeros_like(xp)
    if rig.pressure_column[0] < 0:
        return out
    p = rig.pressure * (rig.pressure_weight @ activation[rig.pressure_column])
    f = model.faces
    area = 0.5 * np.cross(xp[f[:, 1]] - xp[f[:, 0]], xp[f[:, 2]] - xp[f[:, 0]])
    for c in range(3):
        np.add.at(out, f[:, c], (p[f[:, c]] / 3)[:, None] * area)
    if p.sum() != 0:
        out[:, :2] -= np.outer(p / p.sum(), out[:, :2].sum(axis=0))
    return out


def step(model, x, v, activation, h):
    """One step: the bones placed for ``activation`` (muscles, then jaw and lids),
    predictor eq. 3.14 (pinned vertices on their targets), forces at the prediction, eq.
    3.19 solved for V' (denominator kept at least m), positions eq. 3.16, contacts."""
    mat = model.material
    free = ~model.pinned
    target, hold = rig_targets(model, activation)
    x = np.where(free[:, None], x, target)
    xp = np.where(free[:, None], x + h * v, x)
    unit = model.length_unit
    stiff, pull = spring_terms(x, xp, model.spring_indices, model.spring_rest_length, mat.stiffness, mat.nonlinearity, unit)
    s, p = tissue_terms(x, target, mat.tissue + model.tie, hold)
    stiff, pull = stiff + s, pull + p
    if mat.edge_repulsion:
        s, p = repulsion_terms(x, xp, model.repulsion_vertex, model.repulsion_edge, model.repulsion_rest_distance,
                               mat.stiffness, mat.repulsion_nonlinearity, unit)
        stiff, pull = stiff + s, pull + p
    if mat.bending:
        s, p = bending_terms(xp, target, model.hinge, model.hinge_weight, mat.bending)
        stiff, pull = stiff + s, pull + p - h * s[:, None] * v  # eq. 3.19's form: each vertex's own term at X, not X*
    force = muscle_forces(model, xp, activation, target) + pressure_forces(model, xp, activation)
    denominator = np.maximum(mat.mass + h * mat.damping - h * h * stiff, mat.mass)
    v_new = (mat.mass * v + h * force + h * pull) / denominator[:, None]
    v_new[~free] = 0
    return contacts(model, x + h * v_new, v_new, activation, target)


def contacts(model, x, v, activation, target):
    """Each lip and lid pair (upper, lower) kept its gap apart along its contact normal n;
    both share the correction (a pinned one keeps still) and their mean velocity along n.
    Lips sealed (s > 0) are kept within the gap and (1 - s) of a centimetre of where their
    targets put one relative to the other, moved together along that difference."""
    x, v = x.copy(), v.copy()
    rig = model.rig
    sealed = activation[rig.jaw_seal_column] if rig.jaw_seal_column >= 0 else 0.0
    rolled = activation[rig.lip_roll_column].max() if rig.lip_roll_column[0] >= 0 else 0.0  # a rolled lip may pass 2 cm
    for u, l, n, gap, lips in zip(rig.contact_upper, rig.contact_lower, rig.contact_normal, rig.contact_gap,
                                  rig.contact_lips):
        e = (x[u] - x[l]) - (target[u] - target[l])
        excess = np.linalg.norm(e) - (max(gap, 0.0) + (1 - sealed) * 1.0)
        if sealed > 0 and lips and excess > 0:
            e = e / np.linalg.norm(e)
            moving = [k for k in (u, l) if not model.pinned[k]]
            for k in moving:
                x[k] -= (1 if k == u else -1) * excess / len(moving) * e
            mean = (e @ v[u] + e @ v[l]) / 2  # held, they move together along e
            for k in (u, l):
                v[k] += ((mean if not model.pinned[k] else 0.0) - e @ v[k]) * e
        overlap = gap - (2.0 * rolled if lips else 0.0) - n @ (x[u] - x[l])
        if overlap <= 0:
            continue
        moving = [k for k in (u, l) if not model.pinned[k]]
        for k in moving:
            x[k] += (1 if k == u else -1) * overlap / len(moving) * n
        if n @ v[u] < n @ v[l]:
            mean = (n @ v[u] + n @ v[l]) / 2
            for k in (u, l):
                v[k] += ((mean if not model.pinned[k] else 0.0) - n @ v[k]) * n
    return x, v


def simulate(model, activations, dt):
    """Every frame's positions, ``substeps`` steps per frame; within a frame the jaw and
    lids move linearly from the previous frame's values."""
    x = model.rest_position.copy()
    v = np.zeros_like(x)
    substeps = model.material.substeps
    h = dt / substeps
    out = []
    previous = np.zeros(activations.shape[1])
    for row in activations:
        for s in range(substeps):
            blended = row.copy()
            blended[model.muscle_count:] = previous[model.muscle_count:] + (s + 1) / substeps * (row - previous)[model.muscle_count:]
            x, v = step(model, x, v, blended, h)
        out.append(x.copy())
        previous = row
    return np.array(out)
