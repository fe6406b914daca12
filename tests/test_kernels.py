"""Every Numba kernel against its NumPy reference in tests/naive.py, on perturbed states,
with the switches on and off, including degenerate inputs."""

import naive
import numba
import numpy as np
import pytest
import yaml
from conftest import material, spec

from facesim.animation.simulate import model_for
from facesim.animation.spec import activation_table
from facesim.config import HOPPER_MESH, HOPPER_MUSCLES, PARALLEL_FROM
from facesim.face.loading import load_mesh, write_obj
from facesim.face.muscle_file import MuscleFile, muscles_as_points
from facesim.physics import (
    bending,
    checks,
    layout,
    muscle_forces,
    numerics,
    repulsion,
    rig_control,
    solver,
    springs,
    tissue,
)
from facesim.physics.mesh import subdivide
from facesim.physics.run import run
from facesim.schema import load_model

RTOL = 1e-9


def perturbed(model, rng, scale=0.2):
    x = model.rest_position + scale * rng.standard_normal(model.rest_position.shape)
    xp = x + 0.05 * rng.standard_normal(x.shape)
    return x, xp


def assert_close(actual, expected, rtol=RTOL):
    scale = max(np.abs(expected).max(), 1e-300)
    assert np.abs(actual - expected).max() <= rtol * scale


@pytest.mark.parametrize("implicit", [True, False])  # with the links of K, and the thesis's g alone
@pytest.mark.parametrize("unit", [1.0, 0.5])
def test_springs_match_reference(model, rng, unit, implicit):
    x, xp = perturbed(model, rng)
    m = model.material
    forces = layout.forces(model.arrays)
    springs._spring_forces(model.arrays._replace(length_unit=unit, implicit=implicit), xp, forces)
    # the thesis's Σ g (X_i - X_j*) at X = X* is the force at X*
    ref_stiff, ref_force = naive.spring_terms(xp, xp, model.spring_indices, model.spring_rest_length, m.stiffness,
                                              m.nonlinearity, unit)
    assert_close(forces.stiffness, ref_stiff)
    assert_close(forces.force, ref_force)


@pytest.mark.parametrize("implicit", [True, False])
@pytest.mark.parametrize("zeta", [5.0, 2.5, 0.0])
def test_edge_repulsion_matches_reference(model, rng, zeta, implicit):
    x, xp = perturbed(model, rng)
    k0 = model.material.stiffness
    forces = layout.forces(model.arrays)
    repulsion._edge_repulsion_forces(model.arrays._replace(repulsion_nonlinearity=zeta, length_unit=1.0, implicit=implicit), xp,
                             forces)
    ref_stiff, ref_force = naive.repulsion_terms(xp, xp, model.repulsion_vertex, model.repulsion_edge,
                                                 model.repulsion_rest_distance, k0, zeta)
    assert_close(forces.stiffness, ref_stiff)
    assert_close(forces.force, ref_force)


def test_edge_repulsion_is_zero_at_rest(model):
    forces = layout.forces(model.arrays)
    repulsion._edge_repulsion_forces(model.arrays, model.rest_position.copy(), forces)
    assert np.abs(forces.force).max() < 1e-9


@pytest.mark.parametrize("kb", [0.0, 40.0])
def test_bending_matches_reference(model, rng, kb):
    x, target = perturbed(model, rng, scale=0.05)
    forces = layout.forces(model.arrays)
    control = rig_control.control(model.arrays, np.zeros(len(model.muscles.names)))._replace(target=target)
    bending._bending_forces(model.arrays._replace(bending=kb), x, control, forces)
    ref_stiff, ref_force = naive.bending_terms(x, target, model.hinge, model.hinge_weight, kb)
    assert_close(forces.stiffness, ref_stiff)
    assert_close(forces.force, ref_force)
    if kb:  # the force is the energy's downhill gradient: E(X + εp) - E(X - εp) = -2ε F·p
        p, eps = rng.standard_normal(x.shape), 1e-6

        def energy(at):
            bend = np.einsum("ek,ekd->ed", model.hinge_weight, (at - target)[model.hinge])
            return 0.5 * kb * (bend**2).sum()

        slope = (energy(x + eps * p) - energy(x - eps * p)) / (2 * eps)
        assert abs(slope + (forces.force * p).sum()) <= 1e-6 * abs(slope)


def test_bending_stencil_measures_the_hinges_bend(model, rng):
    """Each hinge's stencil (model.bending_hinges) applied to positions is -√(3 / (A0 + A1))
    |e| (n0 + n1), n0 and n1 the unit normals to the shared edge in each triangle's
    plane, pointing to the opposite vertex: zero for a flat hinge, after any affine map."""
    from facesim.physics.model import COTANGENT_LIMIT, bending_hinges

    p = model.rest_position[model.hinge]  # (e, 4, 3)
    edge = p[:, 1] - p[:, 0]
    length = np.linalg.norm(edge, axis=1)

    def towards(k):
        a = p[:, k] - p[:, 0]
        n = a - (np.einsum("ij,ij->i", a, edge) / length**2)[:, None] * edge
        return n / np.linalg.norm(n, axis=1)[:, None], 0.5 * np.linalg.norm(np.cross(edge, a), axis=1)

    (n0, a0), (n1, a1) = towards(2), towards(3)
    expected = -np.sqrt(3 / (a0 + a1))[:, None] * length[:, None] * (n0 + n1)
    measured = np.einsum("ek,ekd->ed", model.hinge_weight, p)

    def cot(at, a, b):
        u, v = p[:, a] - p[:, at], p[:, b] - p[:, at]
        return np.einsum("ij,ij->i", u, v) / np.linalg.norm(np.cross(u, v), axis=1)

    sliver = np.max(np.abs([cot(0, 1, 2), cot(0, 1, 3), cot(1, 0, 2), cot(1, 0, 3)]), axis=0) > COTANGENT_LIMIT
    assert sliver.mean() < 0.05  # hinges with an angle past the cotangent clamp are few
    assert_close(measured[~sliver], expected[~sliver], rtol=1e-9)

    flat = np.array([[0, 0, 0], [1, 0.1, 0], [0.4, 0.8, 0], [0.6, -0.9, 0]], float)
    hinge, weight = bending_hinges(flat, np.array([[0, 1, 2], [1, 0, 3]]))
    affine = flat @ rng.standard_normal((3, 3)).T + rng.standard_normal(3)
    assert np.abs(weight[0] @ affine[hinge[0]]).max() < 1e-12
    assert np.abs(weight[0] @ flat[hinge[0]]).max() < 1e-12


def test_bending_is_zero_where_the_bones_hold_the_skin(model):
    """No bending force at rest, nor when the skin is where the jaw and lids take it."""
    activation = np.zeros(len(model.muscles.names))
    activation[model.muscle_count:] = 1.0
    for a in (np.zeros_like(activation), activation):
        control = rig_control.control(model.arrays, a)
        forces = layout.forces(model.arrays)
        bending._bending_forces(model.arrays._replace(bending=40.0), control.target.copy(), control, forces)
        assert np.abs(forces.force).max() < 1e-9


def test_tissue_matches_reference(model, rng):
    x, target = perturbed(model, rng)
    hold = rng.uniform(0, 1000, len(x)) * (rng.uniform(size=len(x)) > 0.8)
    control = rig_control.control(model.arrays, np.zeros(len(model.muscles.names)))._replace(target=target, hold=hold)
    forces = layout.forces(model.arrays)
    assert model.tie.max() > 0  # the default head's rim is tied (muscles.Pinned)
    tissue._tissue_forces(model.arrays._replace(tissue=300.0), x, control, forces)
    ref_stiff, ref_force = naive.tissue_terms(x, target, 300.0 + model.tie, hold)
    assert_close(forces.stiffness, ref_stiff)
    assert_close(forces.force, ref_force)


def test_uv_projection_matches_reference(model, rng):
    x, _ = perturbed(model, rng)
    assert model.material.uv_projection
    uv = np.empty_like(x)
    muscle_forces._muscle_frame(model.arrays, x, uv)
    assert_close(uv, naive.project_uv(x, model.axis_x, model.axis_z, model.radius))


@numba.njit
def _atan2_all(y, x, out):
    for i in range(y.shape[0]):
        out[i] = numerics._atan2(y[i], x[i])


def test_branch_free_arctangent_matches_numpy_in_every_octant_and_on_the_axes(rng):
    """The muscles' frame (eq. 3.21) takes its angle from facesim's own atan2 (no call to
    libm, no branch): it must be numpy's to rounding, at any scale."""
    size = 200_000
    y = rng.standard_normal(size) * 10.0 ** rng.uniform(-6, 6, size)
    x = rng.standard_normal(size) * 10.0 ** rng.uniform(-6, 6, size)
    axes = np.array([[0.0, 1.0], [0.0, -1.0], [1.0, 0.0], [-1.0, 0.0], [0.0, 0.0], [2.0, 2.0], [-2.0, -2.0],
                     [1.0, -1e-300], [np.tan(np.pi / 8), 1.0], [1.0, np.tan(np.pi / 8)]])
    y, x = np.concatenate([y, axes[:, 0]]), np.concatenate([x, axes[:, 1]])
    out = np.empty_like(y)
    _atan2_all(y, x, out)
    expected = np.arctan2(y, x)
    assert np.all(np.abs(out - expected) <= 4e-15 * np.maximum(np.abs(expected), 1e-300))


def test_falloff_matches_reference_including_degenerate_points(rng):
    origin, insertion = np.array([0.0, 0.0, 0.0]), np.array([3.0, 1.0, 0.5])
    points = np.vstack([rng.uniform(-2, 6, (500, 3)), origin, insertion, 2 * insertion, -insertion])
    for cos_zone, r, r_max in [(np.cos(0.7), 3.2, 4.0), (np.cos(1.2), 2.0, 2.0 + 1e-9), (-1.0, 5.0, 6.0)]:
        got = np.array([muscle_forces._falloff(*origin, *insertion, *p, cos_zone, r, r_max) for p in points])
        ref = naive.falloff(origin, insertion, points, cos_zone, r, r_max)
        assert_close(got, ref)
    assert muscle_forces._falloff(*origin, *insertion, *origin, 0.5, 3.0, 4.0) == 0.0
    assert muscle_forces._falloff(*origin, *insertion, *insertion, 0.5, np.linalg.norm(insertion), 4.0) == pytest.approx(1.0)


def cross2(a, b):
    return a[0] * b[1] - a[1] * b[0]


@pytest.mark.parametrize("uv", [True, False])
def test_flood_fill_finds_the_brute_force_region(uv, rng):
    model = model_for(spec("happy", material=material(uv_projection=uv)))
    x, xp = perturbed(model, rng, scale=0.1)
    frame = naive.project_uv(xp, model.axis_x, model.axis_z, model.radius) if uv else xp
    work = layout.workspace(model.arrays)
    work.frame[:] = frame
    region, delta = work.region, work.delta
    for m in range(model.muscle_count):
        count = muscle_forces._region_of_influence(model.arrays, m, model.muscle_origin, model.muscle_insertion_point, work.frame, work)
        ref_delta = naive.delta(model, m, frame)
        expected = naive.region_of_influence(ref_delta, model.muscle_insertion[m], model.spring_indices, model.vertex_count)
        assert count >= 3, model.muscles.names[m]
        assert sorted(region[:count]) == sorted(expected), model.muscles.names[m]
        assert_close(delta[:count], ref_delta[region[:count]])


@pytest.mark.parametrize("uv", [True, False])
def test_muscle_forces_match_reference(uv, rng):
    model = model_for(spec("happy", material=material(uv_projection=uv)))
    x, xp = perturbed(model, rng, scale=0.05)
    activation = rng.uniform(0, 1, model.muscle_count) * (rng.uniform(size=model.muscle_count) > 0.3)
    # the head's pucker pushes its lips forward, its buccinator the lip corners in (muscles._Muscle.protrusion)
    assert model.muscle_protrusion.max() > 0 and model.muscle_protrusion.min() < 0
    activation[model.muscle_protrusion != 0] = 0.8
    control = rig_control.control(model.arrays, np.concatenate([activation, np.zeros(len(model.muscles.names) - len(activation))]))
    forces = layout.forces(model.arrays)
    muscle_forces._muscle_forces(model.arrays, xp, control, layout.workspace(model.arrays), forces)
    force = forces.force
    expected = naive.muscle_forces(model, xp, activation)
    assert np.abs(expected).max() > 1.0
    assert_close(force, expected)


def test_back_projected_force_lies_in_its_triangle_and_keeps_its_2d_direction(model, rng):
    x, _ = perturbed(model, rng, scale=0.02)
    uv = naive.project_uv(x, model.axis_x, model.axis_z, model.radius)
    f3 = np.empty(3)

    def unfolded(i):
        """Interior vertex whose projected one-ring keeps its orientation: its 2D wedges
        tile the circle, so every direction has a triangle (near the nose the
        projection folds and the boundary rule applies instead)."""
        ring = range(model.ring_start[i], model.ring_start[i + 1])
        closed = len(ring) == model.neighbour_start[i + 1] - model.neighbour_start[i]
        return closed and all(cross2(uv[model.ring_a[k]] - uv[i], uv[model.ring_b[k]] - uv[i]) > 0 for k in ring)

    interior = [i for i in range(model.vertex_count) if not model.pinned[i] and unfolded(i)]
    assert len(interior) > 300
    checked = 0
    for i in rng.choice(interior, 60, replace=False):
        angle = rng.uniform(0, 2 * np.pi)
        f2 = 3.0 * np.array([np.cos(angle), np.sin(angle)])
        assert muscle_forces._back_project(muscle_forces._ring_fields(model.arrays), i, f2[0], f2[1], uv, x, f3)
        assert np.linalg.norm(f3) == pytest.approx(3.0)
        for k in range(model.ring_start[i], model.ring_start[i + 1]):
            a, b = model.ring_a[k], model.ring_b[k]
            normal = np.cross(x[a] - x[i], x[b] - x[i])
            if abs(f3 @ normal) > 1e-9 * np.linalg.norm(normal) * 3.0:
                continue  # not in this triangle's plane
            # the force in the triangle's edge basis, mapped to 2D by the same affine map
            alpha, beta = np.linalg.lstsq(np.column_stack([x[a] - x[i], x[b] - x[i]]), f3, rcond=None)[0]
            if alpha < -1e-9 or beta < -1e-9:
                continue
            image = alpha * (uv[a, :2] - uv[i, :2]) + beta * (uv[b, :2] - uv[i, :2])
            assert abs(image[0] * f2[1] - image[1] * f2[0]) < 1e-9 * np.linalg.norm(image) * 3.0
            assert image @ f2 > 0
            checked += 1
            break
        else:
            pytest.fail(f"force at vertex {i} lies in none of its triangles")
    assert checked == 60


def test_back_projection_of_a_force_leaving_the_mesh_keeps_its_component_along_the_edge(mesh, model):
    uv = naive.project_uv(model.rest_position, model.axis_x, model.axis_z, model.radius)
    centre = uv.mean(axis=0)
    for i in mesh.boundary_loops[0][::6]:
        f2 = 2.0 * (uv[i] - centre) / np.linalg.norm(uv[i] - centre)  # outward: no triangle holds it
        f3 = np.empty(3)
        found = muscle_forces._back_project(muscle_forces._ring_fields(model.arrays), i, f2[0], f2[1], uv, model.rest_position, f3)
        expected = naive.back_project(i, f2, uv, model.rest_position, model.faces, model.spring_indices)
        assert found == bool(np.any(expected))
        assert_close(f3, expected)
        assert np.linalg.norm(f3) < 2.0


@pytest.mark.parametrize("switches", [{}, {"edge_repulsion": False}, {"uv_projection": False}])
@pytest.mark.parametrize("bones", ["at rest", "moved"])
def test_step_matches_reference(switches, bones, rng):
    """One quasi-implicit step against the thesis's form of eq. 3.19 (tests/naive.py),
    with the jaw and lids at rest or moved (the rig's targets and the muscles' ends)."""
    model = model_for(spec("happy", material=material(**switches)))
    x, _ = perturbed(model, rng, scale=0.05)
    x[model.pinned] = model.rest_position[model.pinned]
    v = rng.standard_normal(x.shape)
    v[model.pinned] = 0
    activation = np.zeros(len(model.muscles.names))
    activation[:model.muscle_count] = rng.uniform(0.2, 1, model.muscle_count)
    if bones == "moved":
        activation[model.muscle_count:] = rng.uniform(0.3, 1, len(activation) - model.muscle_count)
    ref_x, ref_v = naive.step(model, x, v, activation, 0.0025)
    state = layout.State(x.copy(), v.copy())
    solver._quasi_implicit_step(model.arrays, state, rig_control.control(model.arrays, activation), 0.0025, np.empty_like(x),
                                layout.workspace(model.arrays), layout.forces(model.arrays))
    assert_close(state.v, ref_v)
    assert_close(state.x, ref_x)


@pytest.mark.parametrize("name", ["happy", "surprise"])
def test_rig_targets_match_reference(name, rng):
    model = model_for(spec(name))
    assert model.rig.jaw_column >= 0 and (model.rig.lid_column >= 0).any()
    for _ in range(3):
        activation = np.zeros(len(model.muscles.names))
        activation[model.muscle_count:] = rng.uniform(0, 1, len(activation) - model.muscle_count)
        control = rig_control.control(model.arrays, activation)
        target, hold = naive.rig_targets(model, activation)
        assert np.abs(target - model.rest_position).max() > 0.1
        assert_close(control.target, target)
        assert_close(control.hold, hold)
        origin, insertion = naive.muscle_geometry(model, target)
        assert_close(control.origin, origin)
        assert_close(control.insertion_point, insertion)


@pytest.mark.parametrize("name", ["happy", "surprise"])  # surprise opens the jaw
def test_whole_run_matches_reference(name):
    """The thesis's model, on the Hopper face with its own muscles (the head's are
    calibrated with bending, which the thesis's update cannot carry)."""
    s = spec(name, mesh=HOPPER_MESH, muscles=None, material=material(name, preset="thesis"))
    model = model_for(s)
    table = activation_table(s, model.muscles)
    positions, *_ = run(model, table, s.dt)
    expected = naive.simulate(model, table, s.dt)
    assert np.abs(positions - expected).max() < 1e-6
    assert np.abs(positions[-1] - model.rest_position).max() > 0.1


def test_a_triangle_is_inverted_when_folded_against_the_skin_around_it_not_when_turned_as_a_whole(model):
    def inverted(x):
        x = np.ascontiguousarray(x)
        return checks._triangle_checks(x, model.faces, model.rest_normal, model.rest_area, model.rest_against,
                                  np.empty_like(x))[0]

    rest = model.rest_position
    assert inverted(rest) == 0
    a = np.radians(150.0)
    turn = np.array([[1, 0, 0], [0, np.cos(a), -np.sin(a)], [0, np.sin(a), np.cos(a)]])
    assert inverted(rest @ turn.T) == 0  # every normal is against its rest normal, yet nothing folded
    for i in (151, 50):  # a forehead and a cheek vertex pushed across a neighbour: its fan folds over
        j = model.neighbour_index[model.neighbour_start[i]]
        pushed = rest.copy()
        pushed[i] = rest[j] + 0.5 * (rest[j] - rest[i])
        assert inverted(pushed) >= 2


@pytest.mark.parametrize("bad", [np.nan, np.inf, -np.inf])
def test_non_finite_values_are_found_under_fastmath(bad):
    """`fastmath` lets the compiler drop math.isfinite (an @njit(fastmath=True) isfinite
    finds no NaN in [1, nan, inf]); the kernels' check reads the exponent bits instead."""
    from facesim.physics.numerics import _not_finite

    rows = np.arange(30.0).reshape(10, 3)
    assert _not_finite(rows) == -1
    rows[7, 2] = bad
    assert _not_finite(rows) == 7



def dense_stiffness(links, n):
    """K (3n, 3n) assembled from the links the terms wrote (arrays.Forces), plainly."""
    k = np.kron(np.diag(links.diagonal), np.eye(3))
    for node, weight, a, along, across in zip(links.node, links.weight, links.axis, links.along, links.across):
        block = along * np.outer(a, a) + across * (np.eye(3) - np.outer(a, a))
        for p in range(4):
            for q in range(4):
                k[3 * node[p]:3 * node[p] + 3, 3 * node[q]:3 * node[q] + 3] += weight[p] * weight[q] * block
    return k


def test_links_are_the_jacobian_of_the_springs_tissue_and_bending(model, rng):
    """Where every spring is stretched (nothing clamped), K p from the links is the
    derivative of the forces along p: -(F(X + εp) - F(X - εp)) / 2ε."""
    arrays = model.arrays._replace(edge_repulsion=False, bending=40.0)
    centre = model.rest_position.mean(axis=0)
    x = centre + 1.08 * (model.rest_position - centre) + 0.002 * rng.standard_normal(model.rest_position.shape)
    control = rig_control.control(arrays, np.zeros(len(model.muscles.names)))
    forces = layout.forces(arrays)

    def force(at):
        forces.force[:] = 0.0
        forces.diagonal[:] = 0.0
        springs._spring_forces(arrays, np.ascontiguousarray(at), forces)
        tissue._tissue_forces(arrays, np.ascontiguousarray(at), control, forces)
        bending._bending_forces(arrays, np.ascontiguousarray(at), control, forces)
        return forces.force.copy()

    p = rng.standard_normal(x.shape)
    eps = 1e-6
    derivative = -(force(x + eps * p) - force(x - eps * p)) / (2 * eps)
    force(x)
    assert (forces.across[:len(model.spring_indices)] > 0).all()
    product = np.empty_like(x)
    solver._stiffness_product(forces, p, product)
    assert_close(product, derivative, rtol=1e-6)
    assert_close(product.reshape(-1), dense_stiffness(forces, len(x)) @ p.reshape(-1))


@pytest.mark.parametrize("face", ["head", "hopper"])
@pytest.mark.parametrize("bending", [0.0, 100.0], ids=["jacobi", "rest-factor"])
def test_implicit_step_solves_its_system(rng, bending, face):
    """The conjugate gradients reach the solution of (m + Δt C + Δt² K) V' = m V + Δt F +
    Δt² K V (solver docstring), solved densely from the same terms, at the free vertices,
    with either preconditioner: Jacobi, or the factorised rest system (a skin with bending),
    on the head (its rim tied, nothing pinned) and on the Hopper face (its rim pinned:
    those vertices keep still)."""
    where = {} if face == "head" else dict(mesh=HOPPER_MESH, muscles="thesis")
    model = model_for(spec("happy", **where, material=material(tolerance=1e-10, iterations=2000, bending=bending)))
    assert model.pinned.any() == (face == "hopper")
    x, _ = perturbed(model, rng, scale=0.03)
    x[model.pinned] = model.rest_position[model.pinned]
    v = 0.3 * rng.standard_normal(x.shape)
    v[model.pinned] = 0
    activation = np.zeros(len(model.muscles.names))
    activation[:model.muscle_count] = rng.uniform(0.2, 1, model.muscle_count)
    control = rig_control.control(model.arrays, activation)
    h, n = 0.01, model.vertex_count
    state, work, forces = layout.State(x.copy(), v.copy()), layout.workspace(model.arrays), layout.forces(model.arrays)
    krylov = solver.Krylov(*(np.empty_like(x) for _ in range(5)), np.empty(3 * n), model.preconditioner(h))
    assert (krylov.factor.lower_start.size > 1) == (bending > 0)
    iterations = solver._implicit_step(model.arrays, state, control, h, np.empty_like(x), work, forces, krylov)
    assert 1 < iterations < 2000

    # the terms at the same prediction, then the system solved densely
    xp = np.empty_like(x)
    solver._predict(model.arrays, layout.State(x.copy(), v.copy()), control, h, xp)
    solver._forces(model.arrays, xp, control, work, forces)
    free = np.repeat(~model.pinned, 3)
    m = model.material.mass
    a = np.diag(np.repeat(m + h * forces.damping, 3)) + h * h * dense_stiffness(forces, n)
    b = m * v.reshape(-1) + h * forces.force.reshape(-1) + h * h * dense_stiffness(forces, n) @ v.reshape(-1)
    expected = np.zeros(3 * n)
    expected[free] = np.linalg.solve(a[np.ix_(free, free)], b[free])
    contact = np.isin(np.arange(n), np.r_[model.arrays.contact_upper, model.arrays.contact_lower])
    moved = state.x - x - h * state.v  # only the lips' and lids' contacts move positions after the step
    assert np.abs(moved[~contact]).max() < 1e-12
    keep = np.repeat(~contact, 3) & free
    assert_close(state.v.reshape(-1)[keep], expected[keep], rtol=1e-6)
    assert np.abs(state.v[model.pinned]).max(initial=0.0) == 0.0


def test_back_projection_turns_continuously_with_the_force(model):
    """A force turned once around any vertex gives a 3D force that turns without a jump:
    where it leaves the mesh (the mouth's and the eyes' rims), and where the projected
    one-ring folds (the lips' rolled edge, beside the nose). A jump at the rim made the
    inner lower lip rattle between its two boundary edges under AU12, and picking the
    first of a folded ring's wedges made mirror-image vertices pull differently."""
    uv = naive.project_uv(model.rest_position, model.axis_x, model.axis_z, model.radius)
    free = [i for i in range(model.vertex_count) if not model.pinned[i]]
    f3 = np.empty(3)

    def turned(i, angles):
        out = []
        for angle in angles:
            muscle_forces._back_project(muscle_forces._ring_fields(model.arrays), i, np.cos(angle), np.sin(angle), uv, model.rest_position, f3)
            out.append(f3.copy())
        return np.linalg.norm(np.diff(out, axis=0), axis=1)

    worst = 0.0
    angles = np.linspace(0, 2 * np.pi, 1441)
    for i in free:
        jumps = turned(i, angles)
        k = int(jumps.argmax())
        if jumps[k] > 0.05:  # steep (two edges nearly parallel in 2D, not in 3D) or a jump: look 1000 times closer
            jumps = turned(i, np.linspace(angles[k], angles[k + 1], 1001))
        worst = max(worst, jumps.max())
    assert worst < 0.05


def test_muscle_regions_kept_between_steps_follow_the_bones(rng):
    """A workspace keeps each muscle's region while the bones stay (arrays.Workspace):
    the forces through a reused workspace, after the jaw and lids have moved, are those of
    a fresh one, and while the bones stay the kept regions are used, not found again."""
    model = model_for(spec("surprise"))
    arrays = model.arrays
    _, xp = perturbed(model, rng, scale=0.05)
    activation = np.zeros(len(model.muscles.names))
    activation[:model.muscle_count] = rng.uniform(0.2, 1, model.muscle_count)
    work = layout.workspace(arrays)
    for bones in (0.0, 0.8, 0.3):
        activation[model.muscle_count:] = bones
        control = rig_control.control(arrays, activation)
        kept, fresh = layout.forces(arrays), layout.forces(arrays)
        muscle_forces._muscle_forces(arrays, xp, control, work, kept)
        assert (work.region_count >= 0).all() and work.region_count.sum() > 100
        muscle_forces._muscle_forces(arrays, xp, control, layout.workspace(arrays), fresh)
        assert_close(kept.force, fresh.force)
        stamps = work.stamp.copy()
        muscle_forces._muscle_forces(arrays, xp, control, work, kept)
        assert np.array_equal(work.stamp, stamps)  # no flood fill: every region was kept


@pytest.mark.parametrize("preset", [None, "thesis"], ids=["attached regions", "the thesis's moving regions"])
def test_parallel_loops_give_the_same_bits_on_one_thread_as_on_two(tmp_path, preset):
    """The springs, pairs and hinges scatter by fixed slices and sum them in slice order,
    and the flood fills split the muscles by fixed slices (facesim.config.CHUNKS), so a
    mesh large enough for every core (PARALLEL_FROM) gives the same positions, to the
    bit, whatever the thread count: with regions kept while the bones stay, and with the
    thesis's, found again at every step."""
    base = load_mesh(HOPPER_MESH)
    write_obj(tmp_path / "face.obj", subdivide(base, 2))
    carried = muscles_as_points(load_model(HOPPER_MUSCLES, MuscleFile), base)
    (tmp_path / "face.muscles.yaml").write_text(yaml.safe_dump(carried.model_dump(mode="json")))
    s = spec("happy", frames=6, mesh=tmp_path / "face.obj", muscles=tmp_path / "face.muscles.yaml",
             material=None if preset is None else material("happy", preset=preset))
    if numba.config.NUMBA_NUM_THREADS < 2:
        pytest.skip("one core: nothing to compare")
    model = model_for(s)
    assert model.vertex_count >= PARALLEL_FROM and model.vertex_order is not None  # simulated in its cache order
    table = activation_table(s, model.muscles)
    one = run(model, table, s.dt, threads=1)[0]
    both = run(model, table, s.dt, threads=2)[0]
    assert np.abs(one[-1] - model.rest_position).max() > 0.01
    assert np.array_equal(one, both)


def test_a_small_mesh_runs_the_serial_twins_and_they_move_the_face_as_the_parallel_kernels_do():
    """The head's 468-vertex skin runs the kernels' serial twins (facesim.physics.twins:
    compiled without parallel loops, a minute less to compile): the simulation that
    ``run`` calls by default is ``_simulate``'s twin, whose calls reach no parallel kernel,
    and it moves the face as the parallel kernels on one thread do, to rounding."""
    from facesim.physics import solver, twins

    s = spec("happy", frames=8)
    model = model_for(s)
    assert model.vertex_count < PARALLEL_FROM
    twin = twins.serial(solver._simulate)
    assert twin is not solver._simulate and twins.for_mesh(solver._simulate, model.vertex_count) is twin
    assert not twins.parallel(twin) and twins.parallel(solver._simulate)
    assert twins.for_mesh(solver._simulate, 30_000) is solver._simulate
    table = activation_table(s, model.muscles)
    serial = run(model, table, s.dt)[0]
    parallel = run(model, table, s.dt, threads=1)[0]
    moved = np.abs(serial[-1] - model.rest_position).max()
    assert moved > 0.05
    assert np.abs(serial - parallel).max() < 1e-9 * moved
