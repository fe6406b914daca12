"""The simulation's behaviour: rest, symmetry, the eight expressions, settling, the
thesis's ablations and divergence reporting."""

import numpy as np
import pytest
from conftest import THESIS_EXPRESSIONS, material, spec

import facesim
from facesim.animation.simulate import model_for
from facesim.animation.spec import activation_table
from facesim.config import HOPPER_MESH
from facesim.errors import SimulationError
from facesim.face.loading import load_mesh
from facesim.physics.mesh import mirror_map
from facesim.physics.run import run

MOUTH_CORNERS = (61, 291)
BROWS = (105, 334, 70, 300)
INNER_BROWS = (107, 336)
GLABELLA = 9
UPPER_LIP = (39, 269)  # right, left


def lift(rest, final, i):
    return final[i, 1] - rest[i, 1]


def mouth_widening(rest, final):
    a, b = MOUTH_CORNERS
    width = np.linalg.norm(rest[a] - rest[b])
    return (np.linalg.norm(final[a] - final[b]) - width) / width


#: What each expression must do to the face, and the muscles without which it must not.
CHECKS = {
    "happy": (lambda r, f: min(lift(r, f, i) for i in MOUTH_CORNERS) > 0.1 and mouth_widening(r, f) >= 0.08,
              ["zygomaticus_major", "levator_anguli_oris"]),
    "surprise": (lambda r, f: min(lift(r, f, i) for i in BROWS) >= 0.3,
                 ["frontalis_lateral", "frontalis_outer"]),
    "sad": (lambda r, f: max(lift(r, f, i) for i in MOUTH_CORNERS) < -0.05, ["depressor_anguli_oris"]),
    "angry": (lambda r, f: max(lift(r, f, i) for i in MOUTH_CORNERS) < -0.03 and lift(r, f, GLABELLA) < -0.1,
              ["depressor_anguli_oris", "procerus"]),
    "fear": (lambda r, f: min(lift(r, f, i) for i in BROWS[:2]) > 0.1
             and np.linalg.norm(f[107] - f[336]) < np.linalg.norm(r[107] - r[336]) - 0.03,
             ["frontalis", "corrugator_supercilii"]),
    "disgust": (lambda r, f: lift(r, f, UPPER_LIP[0]) - lift(r, f, UPPER_LIP[1]) > 0.1,
                ["levator_labii_superioris"]),
    "disgusted_anger": (lambda r, f: lift(r, f, GLABELLA) < -0.1 and min(lift(r, f, i) for i in UPPER_LIP) > 0.05,
                        ["procerus", "levator_labii_superioris"]),
    "happy_surprise": (lambda r, f: min(lift(r, f, i) for i in MOUTH_CORNERS) > 0.1 and min(lift(r, f, i) for i in BROWS) >= 0.3,
                       ["zygomaticus_major", "levator_anguli_oris", "frontalis_lateral", "frontalis_outer"]),
}


@pytest.fixture(scope="module")
def animations():
    return {name: facesim.simulate(spec(name)) for name in THESIS_EXPRESSIONS}


def test_zero_activation_stays_at_rest():
    animation = facesim.simulate(spec("happy", activations={}))
    assert np.abs(animation.positions - animation.rest).max() < 1e-9
    assert animation.kinetic_energy.max() < 1e-20


def test_api_returns_positions_rest_mesh_and_diagnostics(animations):
    a = animations["happy"]
    assert a.positions.shape == (35, 468, 3)
    assert a.rest.shape == (468, 3) and a.faces.shape == (852, 3)
    assert a.kinetic_energy.shape == a.inverted.shape == a.smallest_area.shape == (35,)
    assert a.inverted.max() == 0 and 0 < a.smallest_area.min() <= 1
    assert set(a.active_muscles) == set(spec("happy").activations)


@pytest.mark.parametrize("name", [n for n in THESIS_EXPRESSIONS if n != "disgust"])
def test_symmetric_expressions_give_mirror_symmetric_displacements(name, animations, mesh):
    mapping = mirror_map(mesh.vertices, mesh.faces)
    d = animations[name].positions - animations[name].rest
    mirrored = d[:, mapping] * np.array([-1.0, 1.0, 1.0])
    assert np.abs(d - mirrored).max() <= 1e-6 * np.abs(d).max()


def test_disgust_is_asymmetric(animations, mesh):
    mapping = mirror_map(mesh.vertices, mesh.faces)
    d = animations["disgust"].positions[-1] - animations["disgust"].rest
    assert np.abs(d - d[mapping] * np.array([-1.0, 1.0, 1.0])).max() > 0.1


def assert_expression_reads(name, s, animation=None):
    """The expression's check passes without an inverted triangle, and fails once the
    muscles it relies on are switched off."""
    a = animation or facesim.simulate(s)
    check, key_muscles = CHECKS[name]
    assert a.inverted.max() == 0
    assert check(a.rest, a.positions[-1])
    kept = {m: v for m, v in s.activations.items() if not any(m.startswith(k) for k in key_muscles)}
    assert len(kept) < len(s.activations)
    without = facesim.simulate(s.with_overrides(activations=kept))
    assert not check(without.rest, without.positions[-1])


@pytest.mark.parametrize("name", THESIS_EXPRESSIONS)
def test_expression_moves_what_it_is_about_without_inverting(name, animations):
    assert_expression_reads(name, spec(name), animations[name])


@pytest.mark.parametrize("name", ["happy", "sad", "surprise"])
def test_settles_when_activations_are_held(name):
    s = spec(name)
    model = model_for(s)
    table = activation_table(s, model.muscles)
    held = np.vstack([table, np.repeat(table[-1:], 200, axis=0)])
    _, energy, inverted, _ = run(model, held, s.dt)
    assert inverted.max() == 0
    assert energy[-1] < 1e-6 * energy.max()


def test_without_edge_repulsion_triangles_collapse_and_with_it_none_do():
    """Thesis fig. 3.16: without edge repulsion the mesh collapsed by step 12."""
    strong = dict(onset=0, mesh=HOPPER_MESH)  # full activation from the first step, the thesis's face and model
    with_er = facesim.simulate(spec("happy", material=material(preset="thesis"), **strong), stop_on_inversion=False)
    without = facesim.simulate(spec("happy", material=material(preset="thesis", edge_repulsion=False), **strong),
                               stop_on_inversion=False)
    assert with_er.inverted.max() == 0
    first = int(np.argmax(without.inverted > 0))
    assert without.inverted.max() > 0
    steps = (first + 1) * without.model.material.substeps
    assert steps <= 60


def depth_below_rest_surface(mesh, points):
    """How far each moved vertex lies below the rest surface (cm, 0 when above), measured
    against the rest triangles of its own two-ring: a fold through the single-layer face
    that the missing skull would have stopped."""
    rest, faces = mesh.vertices, mesh.faces
    vs, vf = mesh.vertex_faces
    ns, ni = mesh.neighbours
    depth = np.zeros(len(points))
    for i, p in enumerate(points):
        ring = np.concatenate([[i], ni[ns[i]:ns[i + 1]]])
        best = np.inf
        for t in np.unique(np.concatenate([vf[vs[j]:vs[j + 1]] for j in ring])):
            a, b, c = rest[faces[t]]
            normal = np.cross(b - a, c - a)
            normal /= np.linalg.norm(normal)
            height = (p - a) @ normal
            q = p - a - height * normal
            e0, e1 = b - a, c - a
            v, w = np.linalg.solve([[e0 @ e0, e0 @ e1], [e0 @ e1, e1 @ e1]], [q @ e0, q @ e1])
            if v >= 0 and w >= 0 and v + w <= 1 and abs(height) < abs(best):
                best = height
        depth[i] = max(0.0, -best) if np.isfinite(best) else 0.0
    return depth


def test_without_the_uv_projection_muscles_pull_the_skin_through_the_surface():
    mesh = load_mesh(HOPPER_MESH)  # the thesis's figure 3.10, on the face of the thesis's scale
    with_uv = facesim.simulate(spec("happy", mesh=HOPPER_MESH, material=material(preset="thesis")))
    without = facesim.simulate(spec("happy", mesh=HOPPER_MESH, material=material(preset="thesis", uv_projection=False)))
    folded = depth_below_rest_surface(mesh, without.positions[-1])
    kept = depth_below_rest_surface(mesh, with_uv.positions[-1])
    assert folded.max() > 0.25 and (folded > 0.05).sum() >= 40
    assert kept.max() < 0.1


def test_divergence_raises_with_the_frame():
    violent = spec("happy", dt=0.5, material=material(preset="thesis", substeps=1))  # the thesis update, one 0.5 s step
    with pytest.raises(SimulationError, match=r"at frame \d+") as info:
        facesim.simulate(violent)
    assert info.value.frame is not None and info.value.frame < 35


def test_an_animation_simulated_in_the_background_is_the_one_simulated_at_once():
    """``facesim render`` simulates on a thread of its own while it draws: the frames,
    energies and checks are the same bits as a simulation run to its end first."""
    s = spec("surprise")
    at_once = facesim.simulate(s)
    background = facesim.simulate(s, background=True).ready()
    for name in ("positions", "kinetic_energy", "inverted", "smallest_area"):
        assert np.array_equal(getattr(background, name), getattr(at_once, name)), name
    assert background.simulation_seconds > 0


def simulation_threads():
    import threading

    return [t for t in threading.enumerate() if t.name == "facesim-simulation"]


def test_a_background_simulation_hands_over_each_frame_as_it_is_done_and_stops_when_cancelled():
    from conftest import wait_for

    long = spec("happy", frames=3000)  # about 2 s of simulation
    animation = facesim.simulate(long, background=True)
    animation.ready(0)  # the first frame, long before the last
    assert animation.progress.done < animation.frames
    assert np.abs(animation.positions[0] - animation.rest).max() < 0.01  # it starts from rest
    animation.cancel()
    wait_for(lambda: not simulation_threads(), timeout=30, what="the simulation to stop")
    assert animation.progress.done < animation.frames and animation.progress.error is None


def test_a_background_simulation_that_diverges_raises_at_the_first_frame_it_did_not_reach():
    violent = spec("happy", dt=0.5, material=material(preset="thesis", substeps=1))
    animation = facesim.simulate(violent, background=True)  # returns: the failure comes with the frames
    with pytest.raises(SimulationError, match=r"at frame \d+") as info:
        animation.ready()
    failed = info.value.frame
    animation.ready(failed - 1)  # the frames before it were simulated, and stay readable
    with pytest.raises(SimulationError):
        animation.ready(failed)


def test_a_small_face_is_simulated_beside_its_drawing_on_serial_kernels_with_any_threading_layer(monkeypatch):
    """A face below PARALLEL_FROM vertices runs the kernels' serial twins (facesim.physics.twins),
    which start no parallel loop: so it is simulated on a thread of its own even where
    Numba's threading layer is its workqueue, which stops the process when two threads
    start parallel loops at once (the renderer's filters run on every core). A larger
    mesh's simulation wants both cores, which the renderer already keeps busy: overlapped,
    a 6,990-vertex face rendered slower, not faster (facesim.animation.simulate.simulate),
    so it is simulated before its frames are drawn."""
    import numba

    from facesim.physics import solver, twins

    monkeypatch.setattr(numba, "threading_layer", lambda: "workqueue")
    animation = facesim.simulate(spec("happy"), background=True)
    assert animation.progress is not None
    assert not twins.parallel(twins.for_mesh(solver._simulate, animation.model.vertex_count))
    assert np.array_equal(animation.ready().positions, facesim.simulate(spec("happy")).positions)
    monkeypatch.setattr(twins, "PARALLEL_FROM", 0)  # the Hopper face as if it were large
    assert facesim.simulate(spec("happy", frames=3), background=True).progress is None


def test_a_streamed_run_holds_a_few_frames_and_gives_the_same_bits(tmp_path):
    """simulate(stream=True) keeps STREAMED_RING frames of positions, each simulated once
    the reader has released the frame that many before it: the simulation never runs
    further ahead of its reader than the ring (asserted on the run's own buffer and
    count, not on memory), and the frames are the bits of a whole-clip run."""
    from facesim.animation.simulate import STREAMED_RING

    long = spec("happy", frames=400)
    whole = facesim.simulate(long)
    streamed = facesim.simulate(long, background=True, stream=True)
    assert streamed.streamed and streamed.positions.shape == (STREAMED_RING, whole.positions.shape[1], 3)
    ahead = []
    for k in range(streamed.frames):
        streamed.ready(k)
        assert np.array_equal(streamed.positions_at(k), whole.positions[k]), k
        ahead.append(streamed.progress.done - k)
        streamed.release(k)
    assert max(ahead) <= STREAMED_RING and ahead[0] < streamed.frames
    assert np.array_equal(streamed.kinetic_energy, whole.kinetic_energy)


def test_a_long_clip_is_encoded_while_its_later_frames_are_simulated(tmp_path):
    """Rendering a streamed run to MP4: the first frames reach the encoder while most of
    the clip is not yet simulated, and the run is never more than the ring (and the
    renderer's frames in flight) ahead of what has been encoded."""
    from facesim.animation.simulate import STREAMED_RING
    from facesim.export.output import write_animation
    from facesim.renderer.settings import RenderSettings

    long = spec("happy", frames=600)
    streamed = facesim.simulate(long, background=True, stream=True)
    done_when_encoded = []
    write_animation(streamed, tmp_path / "long.mp4", RenderSettings(64, 64),
                    progress=lambda count: done_when_encoded.append(streamed.progress.done))
    assert len(done_when_encoded) == 600 and (tmp_path / "long.mp4").is_file()
    assert done_when_encoded[0] < 100  # the first frame was encoded long before the last was simulated
    # the ring, and the renderer's frames past the one encoded: one filtered, one drawn, one prepared
    assert max(done - k for k, done in enumerate(done_when_encoded)) <= STREAMED_RING + 3
