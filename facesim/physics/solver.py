"""Solvers: from a State and the Forces the terms add, the next State (thesis section 3.4).

``_forces`` is the list of physical terms (facesim.physics), one line each: adding a
force term is one kernel there and one line here. A solver step reads the model, the
state and the frame's control, and advances the state in place:

- ``_quasi_implicit_step``: the thesis's update. Predict X* = X + Δt V (eq. 3.14), add
  every term's force F, stiffness K and damping C at X*, solve eq. 3.19 for V' vertex by
  vertex,

      V' = (m V + Δt F - Δt² K V) / (m + Δt C - Δt² K),

  which is eq. 3.19-3.20 with the thesis's Σ g (X_i - X_j*) written as F - Δt K V (and
  the Δt on the spring and repulsion terms that the printed eq. 3.20 drops); compressed
  springs make K positive, so the denominator is kept at least m. Then X' = X + Δt V'
  (eq. 3.16) and the contacts.

- ``_implicit_step`` (the default): the same prediction and terms, then the linearised
  backward-Euler step with the whole stiffness K = -∂F/∂X that the terms give as links
  (layout.Forces: 3x3 blocks between neighbours, where the thesis keeps one number per
  vertex),

      (m + Δt C + Δt² K) V' = m V + Δt F + Δt² K V,

  solved for all vertices together by preconditioned conjugate gradients from V' = V (so
  the first residual is Δt (F - C V)), until the residual has fallen by ``tolerance`` or
  after ``iterations``. The preconditioner is the diagonal of the system (Jacobi), or,
  for a skin with bending, the same system at rest, factorised once per model and step
  size (``rest_preconditioner``: SuperLU through scipy, its vertices in a minimum-degree
  order; applied by two triangular solves over 3x3 blocks, ``_factor_solve``, which
  took the head's smile 55 -> 31 ms against the same solves entry by entry in SuperLU's
  own order, side by side in one process on 2026-12-03). Bending couples each vertex to
  its neighbours' neighbours and makes the system too stiff for Jacobi: on the head's
  smile that took 46 iterations a step, the rest system (1.6% from the moving one)
  about 4, and the whole run 40 ms instead of 88. Without bending Jacobi takes about 8
  and costs 3n a product where the factor's fill-in grows faster than n (the Hopper
  face subdivided twice: 3.3 million entries, a run 3.6 times slower).

  With K whole (and positive semi-definite: the links clamp a compressed spring's
  sideways term) the step is stable at one step per frame where the per-vertex update
  needs four; at the apex of the eight thesis expressions the two agree within 2% of
  the largest displacement (tests/test_solver.py).

``_simulate`` runs Algorithm 3.4.1: ``substeps`` steps per frame, the jaw and eyelids
moving linearly within a frame, and per-frame diagnostics (finiteness, inverted
triangles, kinetic energy).
"""

from collections import namedtuple

import numpy as np
from numba import njit, prange

from ..config import NUMBA_OPTIONS, PARALLEL_OPTIONS
from . import (
    bending,
    checks,
    contacts,
    damping,
    layout,
    muscle_forces,
    numerics,
    pressure,
    repulsion,
    rig_control,
    springs,
    tissue,
    twins,
)
from .layout import INVERTED, NOT_FINITE, OK, RUNAWAY
from .mesh import inverse_permutation

#: The preconditioner of the implicit step: P A Pᵀ = L U for the system A at rest
#: (``rest_preconditioner``), P putting vertex ``order[J]`` J-th with its three
#: coordinates together, so that L and U are made of 3x3 blocks (I, J) between vertices.
#: Block column J of L: its blocks below the diagonal, rows ``lower_vertex[k]`` for k from
#: ``lower_start[J]`` to ``lower_start[J + 1]``, each stored transposed as ``lower_block[k]``
#: (k, 3, 3), and the inverse of its diagonal block, ``lower_pivot[J]`` (n, 3, 3); U's
#: alike, its blocks above the diagonal.
Factor = namedtuple("Factor", ["lower_start", "lower_vertex", "lower_block", "lower_pivot", "upper_start", "upper_vertex",
                               "upper_block", "upper_pivot", "order"])
#: Scratch of the conjugate gradients: residual r, preconditioned z, direction p, q = A p
#: and the Jacobi preconditioner (the diagonal of A), (n, 3) each; the triangular
#: solves' ``scratch`` (3n,) and the rest system's ``factor``, used when it has columns.
Krylov = namedtuple("Krylov", ["r", "z", "p", "q", "diagonal", "scratch", "factor"])
#: Per-frame output of ``_simulate``: positions (frames, n, 3), kinetic_energy and
#: smallest_area (frames,) float, inverted (frames,) int.
Diagnostics = namedtuple("Diagnostics", ["positions", "kinetic_energy", "inverted", "smallest_area"])


@njit(**NUMBA_OPTIONS)
def _forces(model, xp, control, work, forces):
    """Every physical term at the predicted positions ``xp``, added into ``forces``."""
    forces.force[:] = 0.0
    forces.stiffness[:] = 0.0
    forces.damping[:] = 0.0
    forces.diagonal[:] = 0.0
    springs._spring_forces(model, xp, forces)  # eq. 3.6
    repulsion._edge_repulsion_forces(model, xp, forces)  # eq. 3.7
    bending._bending_forces(model, xp, control, forces)  # Bergou et al. 2006, on the displacement
    damping._damping_forces(model, forces)  # eq. 3.10
    tissue._tissue_forces(model, xp, control, forces)  # hypodermis, and the rig's drive
    muscle_forces._muscle_forces(model, xp, control, work, forces)  # eq. 3.1-3.4, 3.21-3.25
    pressure._pressure_forces(model, xp, control, forces)  # air in the mouth on its wall (AU34)


@njit(**PARALLEL_OPTIONS)
def _predict(model, state, control, h, xp):
    """X* = X + Δt V (eq. 3.14); a pinned vertex is where its bone holds it."""
    x, v, pinned, target = state.x, state.v, model.pinned, control.target
    for i in prange(x.shape[0]):
        for d in range(3):
            if pinned[i]:
                x[i, d] = target[i, d]
                xp[i, d] = x[i, d]
            else:
                xp[i, d] = x[i, d] + h * v[i, d]


@njit(**PARALLEL_OPTIONS)
def _quasi_implicit_step(model, state, control, h, xp, work, forces):
    """One step of the thesis's update (module docstring), in place."""
    _predict(model, state, control, h, xp)
    _forces(model, xp, control, work, forces)
    x, v, m, pinned = state.x, state.v, model.mass, model.pinned
    force, stiffness, damping = forces.force, forces.stiffness, forces.damping
    for i in prange(x.shape[0]):
        if pinned[i]:
            for d in range(3):
                v[i, d] = 0.0
            continue
        k = stiffness[i]
        denominator = max(m + h * damping[i] - h * h * k, m)  # eq. 3.19
        for d in range(3):
            v[i, d] = (m * v[i, d] + h * force[i, d] - h * h * k * v[i, d]) / denominator
            x[i, d] += h * v[i, d]  # eq. 3.16
    contacts._contacts(model, state, control)


@njit(**NUMBA_OPTIONS)
def _stiffness_product(forces, p, out):
    """out = K p for the stiffness the terms wrote (layout.Forces): the isotropic diagonal,
    then each link's blocks w_p w_q B applied to its extension u = Σ w_k p_k."""
    for i in range(p.shape[0]):
        for d in range(3):
            out[i, d] = forces.diagonal[i] * p[i, d]
    for l in range(forces.along.shape[0]):
        ux, uy, uz = numerics._link_extension(forces.node, forces.weight, l, p)
        ax, ay, az = forces.axis[l, 0], forces.axis[l, 1], forces.axis[l, 2]
        across = forces.across[l]
        projection = (forces.along[l] - across) * (ax * ux + ay * uy + az * uz)
        bx = across * ux + projection * ax
        by = across * uy + projection * ay
        bz = across * uz + projection * az
        numerics._link_spread(forces.node, forces.weight, l, 1.0, bx, by, bz, out)


@njit(**NUMBA_OPTIONS)
def _system_product(model, forces, h, p, out):
    """out = A p with A = m + Δt C + Δt² K, zero at the pinned vertices."""
    _stiffness_product(forces, p, out)
    for i in range(p.shape[0]):
        a = model.mass + h * forces.damping[i]
        for d in range(3):
            out[i, d] = 0.0 if model.pinned[i] else a * p[i, d] + h * h * out[i, d]


@njit(**NUMBA_OPTIONS)
def _link_block(forces, l, d, e):
    """Entry (d, e) of link l's 3x3 block B = along a aᵀ + across (I - a aᵀ) (layout.Forces)."""
    across = forces.across[l]
    return (forces.along[l] - across) * forces.axis[l, d] * forces.axis[l, e] + (across if d == e else 0.0)


@njit(**NUMBA_OPTIONS)
def _jacobi(model, forces, h, out):
    """The diagonal of A = m + Δt C + Δt² K, per coordinate."""
    for i in range(out.shape[0]):
        for d in range(3):
            out[i, d] = model.mass + h * forces.damping[i] + h * h * forces.diagonal[i]
    for l in range(forces.along.shape[0]):
        for k in range(4):
            w2 = h * h * forces.weight[l, k] * forces.weight[l, k]
            node = forces.node[l, k]
            for d in range(3):
                out[node, d] += w2 * _link_block(forces, l, d, d)


@njit(**NUMBA_OPTIONS)
def _system_entries(model, forces, h, place, rows, columns, values):
    """The entries of A = m + Δt C + Δt² K as triplets (duplicates to be summed), 3n for
    the diagonal then 144 per link (its 4x4 blocks w_p w_q B, ``layout.Forces``), vertex
    i's coordinates in rows and columns 3 place[i] to 3 place[i] + 2; a pinned vertex's
    rows and columns are the identity's. Returns how many were written."""
    count = 0
    for i in range(model.rest_position.shape[0]):
        for d in range(3):
            rows[count] = columns[count] = 3 * place[i] + d
            free = model.mass + h * forces.damping[i] + h * h * forces.diagonal[i]
            values[count] = 1.0 if model.pinned[i] else free
            count += 1
    for l in range(forces.along.shape[0]):
        for a in range(4):
            p = forces.node[l, a]
            for b in range(4):
                q = forces.node[l, b]
                if model.pinned[p] or model.pinned[q]:
                    continue
                w = h * h * forces.weight[l, a] * forces.weight[l, b]
                for d in range(3):
                    for e in range(3):
                        rows[count] = 3 * place[p] + d
                        columns[count] = 3 * place[q] + e
                        values[count] = w * _link_block(forces, l, d, e)
                        count += 1
    return count


def rest_preconditioner(model, h: float) -> Factor:
    """The implicit step's preconditioner for ``model`` (facesim.physics.model.Model) at step ``h``: its
    system A (``_system_entries``) with the terms at rest and the bones at rest, factorised
    by SuperLU (scipy.sparse.linalg.splu). A is symmetric positive definite, so the
    diagonal is kept as pivot; the order is minimum degree on the graph of the vertices
    (SuperLU's, on a diagonally dominant matrix of that graph), each vertex's three
    coordinates kept together, so that the factors are made of 3x3 blocks (``Factor``).
    Applied by blocks, the two triangular solves take 55-70 µs on the head's skin against
    170 µs for the factors entry by entry in SuperLU's own order (180,000 entries either
    way; ``_factor_solve``); entry by entry, rows instead of columns took 310 µs, and
    float32 values or int32 indices gained nothing (measured on 2026-12-03)."""
    from scipy.sparse import coo_matrix, diags
    from scipy.sparse.linalg import splu

    n, arrays = model.vertex_count, model.arrays
    control = rig_control.control(arrays, np.zeros(len(model.muscles.names)))
    forces = layout.forces(arrays)
    twins.for_mesh(_forces, n)(arrays, np.array(control.target), control, layout.workspace(arrays), forces)
    # the graph of the vertices that A couples: the pairs of each link's nodes, pinned ones left out
    node, free = forces.node, ~arrays.pinned
    first, second = np.repeat(node, 4, axis=1).ravel(), np.tile(node, (1, 4)).ravel()
    coupled = free[first] & free[second] & (first != second)
    graph = coo_matrix((np.ones(coupled.sum()), (first[coupled], second[coupled])), shape=(n, n)).tocsr()
    graph.data[:] = 1.0
    dominant = (diags(np.asarray(graph.sum(axis=1)).ravel() + 1.0) - graph).tocsc()
    order = np.argsort(splu(dominant, permc_spec="MMD_AT_PLUS_A", diag_pivot_thresh=0.0,
                            options=dict(SymmetricMode=True)).perm_c)
    place = inverse_permutation(order)
    size = 3 * n + 144 * forces.along.shape[0]
    rows, columns, values = np.empty(size, dtype=np.int64), np.empty(size, dtype=np.int64), np.empty(size)
    count = _system_entries(arrays, forces, h, place, rows, columns, values)
    system = coo_matrix((values[:count], (rows[:count], columns[:count])), shape=(3 * n, 3 * n)).tocsc()
    lu = splu(system, permc_spec="NATURAL", diag_pivot_thresh=0.0, options=dict(SymmetricMode=True))
    identity = np.arange(3 * n)
    if not (np.array_equal(lu.perm_r, identity) and np.array_equal(lu.perm_c, identity)):
        raise FloatingPointError("the system at rest is not positive definite: SuperLU pivoted off its diagonal")
    return Factor(*_block_columns(lu.L, n), *_block_columns(lu.U, n), order.astype(np.int64))


def _block_columns(factor, n: int):
    """A triangular factor (3n x 3n) by its 3x3 blocks (``Factor``): the start of each
    block column, the vertex and the transposed block of each block off the diagonal, and
    the inverse of each diagonal block."""
    by_rows = factor.T.tobsr(blocksize=(3, 3))  # block row J of the transpose: block column J
    by_rows.sort_indices()
    column = np.repeat(np.arange(n), np.diff(by_rows.indptr))
    diagonal = by_rows.indices == column
    if diagonal.sum() != n:
        raise FloatingPointError("a factor of the system at rest lacks a diagonal block")
    pivot = np.linalg.inv(np.transpose(by_rows.data[diagonal], (0, 2, 1)))
    off = ~diagonal
    start = np.concatenate([[0], np.cumsum(np.bincount(column[off], minlength=n))]).astype(np.int64)
    return start, by_rows.indices[off].astype(np.int64), np.ascontiguousarray(by_rows.data[off]), np.ascontiguousarray(pivot)


def no_factor() -> Factor:
    """An empty Factor: the Jacobi preconditioner is used (no bending), or none is (the
    thesis's update)."""
    start, index, blocks = np.zeros(1, dtype=np.int64), np.zeros(0, dtype=np.int64), np.zeros((0, 3, 3))
    return Factor(start, index, blocks, blocks, start, index, blocks, blocks, index)


@njit(**dict(NUMBA_OPTIONS, inline="always"))
def _block_substitution(start, vertex, block, pivot, y, J):
    """One block column J of a triangular solve over ``y`` (n, 3): y_J = pivot_J y_J, then
    y_I -= B_IJ y_J for the column's blocks (``Factor``: stored transposed). Inlined: a
    call per column, handing over four arrays, costs about what the column does."""
    y0 = pivot[J, 0, 0] * y[J, 0] + pivot[J, 0, 1] * y[J, 1] + pivot[J, 0, 2] * y[J, 2]
    y1 = pivot[J, 1, 0] * y[J, 0] + pivot[J, 1, 1] * y[J, 1] + pivot[J, 1, 2] * y[J, 2]
    y2 = pivot[J, 2, 0] * y[J, 0] + pivot[J, 2, 1] * y[J, 1] + pivot[J, 2, 2] * y[J, 2]
    y[J, 0] = y0
    y[J, 1] = y1
    y[J, 2] = y2
    for k in range(start[J], start[J + 1]):
        I = vertex[k]
        for d in range(3):
            y[I, d] -= block[k, 0, d] * y0 + block[k, 1, d] * y1 + block[k, 2, d] * y2


@njit(**NUMBA_OPTIONS)
def _factor_solve(factor, r, scratch, z):
    """z = A⁻¹ r for the factorised A (``Factor``): z = Pᵀ U⁻¹ L⁻¹ P r, by forward then
    backward substitution over the blocks' columns. r and z are (n, 3); ``scratch`` (3n,)."""
    y = scratch.reshape((r.shape[0], 3))
    order = factor.order
    for J in range(order.shape[0]):
        for d in range(3):
            y[J, d] = r[order[J], d]
    for J in range(order.shape[0]):  # L y = P r
        _block_substitution(factor.lower_start, factor.lower_vertex, factor.lower_block, factor.lower_pivot, y, J)
    for J in range(order.shape[0] - 1, -1, -1):  # U y = y
        _block_substitution(factor.upper_start, factor.upper_vertex, factor.upper_block, factor.upper_pivot, y, J)
    for J in range(order.shape[0]):
        for d in range(3):
            z[order[J], d] = y[J, d]


@njit(**NUMBA_OPTIONS)
def _factored(krylov):
    """Whether the step has the rest system's factor (else Jacobi)."""
    return krylov.factor.lower_start.shape[0] > 1


@njit(**NUMBA_OPTIONS)
def _precondition(krylov, r, z):
    """z = M⁻¹ r for the step's preconditioner (module docstring)."""
    if _factored(krylov):
        _factor_solve(krylov.factor, r, krylov.scratch, z)
    else:
        for i in range(r.shape[0]):
            for d in range(3):
                z[i, d] = r[i, d] / krylov.diagonal[i, d]


@njit(**NUMBA_OPTIONS)
def _dot(a, b):
    total = 0.0
    for i in range(a.shape[0]):
        for d in range(3):
            total += a[i, d] * b[i, d]
    return total


#: Inlined into ``_simulate``, its one caller: compiled on its own as well, it was machine
#: code emitted twice, and a render compiling from nothing took 8 s longer (63-65 -> 55.5 s, 2026-12-08)
@njit(**dict(NUMBA_OPTIONS, inline="always"))
def _implicit_step(model, state, control, h, xp, work, forces, krylov):
    """One linearised backward-Euler step (module docstring), in place. Returns the
    conjugate-gradient iterations it took."""
    _predict(model, state, control, h, xp)
    _forces(model, xp, control, work, forces)
    x, v = state.x, state.v
    r, z, p, q = krylov.r, krylov.z, krylov.p, krylov.q
    if not _factored(krylov):
        _jacobi(model, forces, h, krylov.diagonal)
    for i in range(x.shape[0]):  # V' = V to start: r = b - A V = Δt (F - C V)
        for d in range(3):
            if model.pinned[i]:
                v[i, d] = 0.0
                r[i, d] = 0.0
            else:
                r[i, d] = h * (forces.force[i, d] - forces.damping[i] * v[i, d])
    _precondition(krylov, r, z)
    numerics._copy_rows(z, p)
    rz = _dot(r, z)
    residual = _dot(r, r)
    threshold = model.tolerance * model.tolerance * residual
    iteration = 0
    while iteration < model.iterations and residual > threshold:
        _system_product(model, forces, h, p, q)
        curvature = _dot(p, q)
        if curvature <= 0.0:
            break
        alpha = rz / curvature
        residual = 0.0
        for i in range(x.shape[0]):
            for d in range(3):
                v[i, d] += alpha * p[i, d]
                r[i, d] -= alpha * q[i, d]
                residual += r[i, d] * r[i, d]
        _precondition(krylov, r, z)
        following = _dot(r, z)
        beta = following / rz
        rz = following
        for i in range(x.shape[0]):
            for d in range(3):
                p[i, d] = z[i, d] + beta * p[i, d]
        iteration += 1
    for i in range(x.shape[0]):
        for d in range(3):
            x[i, d] += h * v[i, d]  # eq. 3.16
    contacts._contacts(model, state, control)
    return iteration


@njit(**NUMBA_OPTIONS)
def _simulate(model, activations, start, stop, dt, substeps, energy_limit, stop_on_inversion, state, control, work,
              forces, factor, out):
    """Algorithm 3.4.1: ``substeps`` steps of Δt / substeps per frame, for frames
    ``start`` to ``stop`` of ``activations`` (frames, muscles and controls): the caller
    runs a long animation in pieces, so that Ctrl-C and SIGTERM act between them. The
    state is advanced in place; ``control`` holds the previous step's bones; ``factor`` is
    the implicit step's factorised preconditioner (``rest_preconditioner``), or empty.
    Within a frame the controls (jaw, eyelids) move linearly from the previous frame's
    values, so the targets never jump.

    Writes ``out`` (Diagnostics): frame f's positions into ``out.positions[f - start]``
    (the caller hands over rows for this piece alone: a streamed run keeps only a few),
    the rest at f. Returns (status, frame, element): OK, or the first frame
    that is NOT_FINITE (element: a vertex), INVERTED (a triangle; only when
    ``stop_on_inversion``) or RUNAWAY (kinetic energy above ``energy_limit``).
    """
    x, v = state.x, state.v
    n = x.shape[0]
    muscles = model.muscle_kind.shape[0]
    h = dt / substeps
    xp = np.empty_like(x)
    normals = np.empty_like(x)
    krylov = Krylov(np.empty_like(x), np.empty_like(x), np.empty_like(x), np.empty_like(x), np.empty_like(x), np.empty(3 * n),
                    factor)
    rigged = model.jaw_column >= 0 or model.lid_column.max() >= 0
    at_rest = True  # the bones at rest: nothing to recompute while the controls stay at 0
    for c in range(muscles, activations.shape[1]):
        at_rest = at_rest and control.activation[c] == 0.0
    for f in range(start, stop):
        for c in range(muscles):
            control.activation[c] = activations[f, c]
        for s in range(substeps):
            moving = False
            if rigged:
                blend = (s + 1.0) / substeps
                for c in range(muscles, activations.shape[1]):
                    previous = activations[f - 1, c] if f > 0 else 0.0
                    control.activation[c] = previous + blend * (activations[f, c] - previous)
                    moving = moving or control.activation[c] != 0.0 or previous != 0.0
            if moving or not at_rest:
                at_rest = not moving
                rig_control._rig_control(model, control)
            if model.implicit:
                _implicit_step(model, state, control, h, xp, work, forces, krylov)
            else:
                _quasi_implicit_step(model, state, control, h, xp, work, forces)
        bad = numerics._not_finite(x)
        if bad < 0:
            bad = numerics._not_finite(v)
        if bad >= 0:
            return NOT_FINITE, f, bad
        energy = 0.0
        for i in range(n):
            for d in range(3):
                energy += 0.5 * model.mass * v[i, d] * v[i, d]
                out.positions[f - start, i, d] = x[i, d]
        count, first, smallest = checks._triangle_checks(x, model.faces, model.rest_normal, model.rest_area,
                                                          model.rest_against, normals)
        out.kinetic_energy[f] = energy
        out.inverted[f] = count
        out.smallest_area[f] = smallest
        if count > 0 and stop_on_inversion:
            return INVERTED, f, first
        if energy > energy_limit:
            return RUNAWAY, f, -1
    return OK, -1, -1
