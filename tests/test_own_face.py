"""Any face mesh: the material scaled to the mesh's resolution, muscles carried by position,
and meshes aligned to the default face from named landmarks."""

from dataclasses import replace

import numpy as np
import pytest
import yaml
from conftest import EXPRESSIONS, THESIS_EXPRESSIONS
from test_simulation import assert_expression_reads

import facesim
from facesim.animation.simulate import model_for
from facesim.animation.spec import load_spec
from facesim.config import DEFAULT_MUSCLES, HOPPER_MESH, HOPPER_MUSCLES, LIBRARY
from facesim.face.loading import load_mesh, write_obj
from facesim.face.material import MaterialSpec, over_muscle_file
from facesim.face.muscle_file import MuscleFile, carried_text
from facesim.physics.mesh import subdivide
from facesim.schema import load_model


def subdivision(root, times, muscles=DEFAULT_MUSCLES):
    """The Hopper face Loop-subdivided ``times`` (its first 468 vertices are the originals,
    smoothed) and a muscle file (the default: the head's calibrated one) carried to it by position."""
    base = load_mesh(HOPPER_MESH)
    write_obj(root / "face.obj", subdivide(base, times))
    (root / "face.muscles.yaml").write_text(carried_text(muscles, base))
    return root / "face.obj", root / "face.muscles.yaml"


@pytest.fixture(scope="module")
def subdivided(tmp_path_factory):
    return subdivision(tmp_path_factory.mktemp("sub1"), 1)


@pytest.fixture(scope="module")
def subdivided_twice(tmp_path_factory):
    return subdivision(tmp_path_factory.mktemp("sub2"), 2)


@pytest.fixture(scope="module")
def subdivided_thesis(tmp_path_factory):
    return subdivision(tmp_path_factory.mktemp("sub1_thesis"), 1, HOPPER_MUSCLES)


@pytest.fixture(scope="module")
def astronaut_thesis(astronaut):
    return astronaut[0], HOPPER_MUSCLES


def on(spec, mesh_and_muscles):
    mesh, muscles = mesh_and_muscles
    return spec.with_overrides(mesh=mesh, muscles=muscles)


def test_the_material_scales_with_the_skin_area_per_vertex(subdivided):
    spec = load_spec(EXPRESSIONS / "sad.yaml").with_overrides(mesh=HOPPER_MESH)
    default = model_for(spec)
    assert default.resolution == 1.0 and default.material == replace(over_muscle_file(spec.material, default.muscles), substeps=1)
    fine = model_for(on(spec, subdivided))
    assert fine.vertex_count == 1790 and 0.2 < fine.resolution < 0.3
    s = fine.resolution
    assert fine.material.mass == pytest.approx(s) and fine.material.tissue == pytest.approx(300 * s)
    assert fine.material.substeps == 1 and fine.length_unit == pytest.approx(np.sqrt(s))  # the implicit step's
    thesis = MaterialSpec(preset="thesis")
    assert model_for(on(spec.with_overrides(material=thesis), subdivided)).material.substeps == 8
    assert fine.muscle_force.sum() == pytest.approx(s * default.muscle_force.sum())


@pytest.fixture(scope="module")
def astronaut(tmp_path_factory):
    """scikit-image's astronaut portrait through `facesim mesh from-photo`, with the
    default muscle file as it is (the same MediaPipe topology)."""
    pytest.importorskip("mediapipe", reason="MediaPipe not installed (pip install -e '.[photo]')")
    import imageio.v3 as iio
    from skimage import data

    from facesim.face.photo import mesh_from_photo

    root = tmp_path_factory.mktemp("astronaut")
    iio.imwrite(root / "astronaut.png", data.astronaut())
    mesh_from_photo(root / "astronaut.png", root / "astronaut.obj")
    return root / "astronaut.obj", None  # the default muscle file: the head's, by landmark index


@pytest.fixture(scope="module")
def hopper():
    return HOPPER_MESH, None


def lip_corner_lift(animation) -> float:
    """How far happy lifts the lip corners (landmarks 61, 291, the first vertices of a
    Loop subdivision too) at its apex, as a fraction of the mouth's width at rest."""
    rest, apex = animation.rest, animation.positions[-1]
    return float((apex[[61, 291], 1] - rest[[61, 291], 1]).mean() / np.linalg.norm(rest[291] - rest[61]))


@pytest.mark.parametrize("face", ["hopper", "astronaut", "subdivided", "subdivided_twice"])
def test_every_face_takes_the_calibrated_muscles_by_default(face, request):
    """Issue 46: a face given with --mesh (the Hopper face, a mesh from `mesh from-photo`,
    either Loop-subdivided once or twice with the muscles carried by position) takes the
    head's calibrated muscles, not the thesis's: happy lifts the lip corners at least 8% of
    the mouth's width (the thesis's lifted them 3.8% on the Hopper face, and folded the
    twice-subdivided face at the mouth's inner corners). Measured 2026-12-07: 23.7%, 16.4%, 23.8%, 20.0%."""
    where = request.getfixturevalue(face)
    spec = on(load_spec(EXPRESSIONS / "happy.yaml"), where)
    assert spec.muscles_path == (where[1] or DEFAULT_MUSCLES)
    assert lip_corner_lift(facesim.simulate(spec)) >= 0.08
    thesis = facesim.simulate(load_spec(EXPRESSIONS / "happy.yaml").with_overrides(mesh=HOPPER_MESH, muscles="thesis"))
    assert face != "hopper" or lip_corner_lift(thesis) < 0.05  # the preset the thesis's tables name


@pytest.mark.parametrize("face", ["hopper", "subdivided", pytest.param("subdivided_twice", marks=pytest.mark.heavy(30))])
def test_no_library_expression_inverts_a_triangle_on_the_hopper_face_or_its_subdivisions(face, request):
    """Every spec of the library (blink too, whose lids on a finer mesh have edge vertices
    between the muscle file's points: held still, they folded at the eye's corners)."""
    for path in sorted(LIBRARY.glob("*.yaml")):
        animation = facesim.simulate(on(load_spec(path), request.getfixturevalue(face)))  # raises at an inverted triangle
        assert animation.inverted.max() == 0, path.stem


@pytest.mark.parametrize("name", THESIS_EXPRESSIONS)
@pytest.mark.parametrize("face", ["astronaut_thesis", "subdivided_thesis"])
def test_the_eight_expressions_on_another_face_with_the_same_files(name, face, request):
    """The thesis's muscle and material files, no inverted triangle, and each
    expression's check of the simulation tests (with its ablation, made for the thesis's
    muscle lists) on a second face and on a finer mesh. (The head's calibrated file, which
    these faces take by default, is tested above; on the once-subdivided face its
    corrugators draw fear's brows together 0.2 mm, 0.56 on the Hopper face.)"""
    assert_expression_reads(name, on(load_spec(EXPRESSIONS / f"{name}.yaml"), request.getfixturevalue(face)))


#: The points each expression is about: the lip corners, the glabella.
MOVED = {"happy": (61, 291), "sad": (61, 291), "angry": (9,)}


@pytest.mark.parametrize("name", ["happy", "sad", "angry"])
def test_a_subdivided_face_moves_like_the_one_it_refines(subdivided, name):
    """The points an expression is about move alike on the Hopper face and on its Loop
    subdivision (same muscle file, carried by position). Measured 2026-12-07: 1% apart for
    happy's lip corners, 21% for sad's, 12% for angry's glabella, which the one midline
    procerus pulls over a region the finer mesh resolves differently."""
    spec = load_spec(EXPRESSIONS / f"{name}.yaml")
    coarse = facesim.simulate(spec.with_overrides(mesh=HOPPER_MESH))
    fine = facesim.simulate(on(spec, subdivided))
    for v in MOVED[name]:  # Loop subdivision keeps the original vertices first
        a = coarse.positions[-1, v] - coarse.rest[v]
        b = fine.positions[-1, v] - fine.rest[v]
        assert np.linalg.norm(a - b) < 0.4 * np.linalg.norm(a)


def turned(points, degrees_yaw=25.0, degrees_pitch=10.0, scale=10.0, shift=(3.0, -40.0, 12.0)):
    """A similarity transform of points (a scan in millimetres, turned and moved)."""
    a, b = np.radians([degrees_yaw, degrees_pitch])
    yaw = np.array([[np.cos(a), 0, np.sin(a)], [0, 1, 0], [-np.sin(a), 0, np.cos(a)]])
    pitch = np.array([[1, 0, 0], [0, np.cos(b), -np.sin(b)], [0, np.sin(b), np.cos(b)]])
    return points @ (yaw @ pitch).T * scale + np.array(shift)


def test_align_brings_a_turned_scan_in_millimetres_into_the_face_frame(tmp_path, subdivided):
    from test_cli import facesim as cli

    from facesim.face.align import NAMED_LANDMARKS
    from facesim.physics.mesh import FaceMesh
    fine = load_mesh(subdivided[0])
    scan = tmp_path / "scan.obj"
    write_obj(scan, FaceMesh(turned(fine.vertices), fine.faces))
    # Loop subdivision keeps the original vertices first: the landmarks keep their indices
    (tmp_path / "landmarks.yaml").write_text(yaml.safe_dump({n: i for n, i in NAMED_LANDMARKS.items()}))
    cli("mesh", "align", scan, "--landmarks", tmp_path / "landmarks.yaml", "-o", tmp_path / "aligned.obj", check=0)
    aligned = load_mesh(tmp_path / "aligned.obj")
    assert np.abs(aligned.vertices - fine.vertices).max() < 0.1  # back in cm, upright, facing +z
    carried = load_model(tmp_path / "aligned.muscles.yaml", MuscleFile)
    from facesim.face.muscle_file import resolve_muscles
    on_aligned = resolve_muscles(carried, aligned)
    on_fine = resolve_muscles(load_model(subdivided[1], MuscleFile), fine)
    # every muscle point snaps to the same vertex or, where two lie almost equally near it
    # (the smoothed landmark 62 and a new vertex 0.5 mm from it: the fit's residual
    # decides), to the other, within a millimetre
    for ends in ("attachment", "insertion"):
        a, b = getattr(on_aligned, ends), getattr(on_fine, ends)
        assert np.mean(a == b) >= 0.95
        assert np.linalg.norm(fine.vertices[a] - fine.vertices[b], axis=1).max() < 0.1


def test_landmarks_are_proposed_by_nearest_vertex_on_an_upright_mesh(tmp_path, subdivided):
    from facesim.face.align import NAMED_LANDMARKS, propose_landmarks
    from facesim.physics.mesh import FaceMesh
    fine = load_mesh(subdivided[0])
    scan = FaceMesh(turned(fine.vertices, 0.0, 0.0), fine.faces)  # millimetres, moved, but upright
    proposal = propose_landmarks(scan, load_mesh(HOPPER_MESH))
    found = [proposal[n][0] == i for n, i in NAMED_LANDMARKS.items()]
    assert np.mean(found) >= 0.75


@pytest.mark.parametrize("landmarks, message", [
    ({"nose_tip": 4, "chin": 152}, "name at least 4 landmarks, got 2"),
    ({"nose_tip": 4, "chin": 152, "eye_outer_r": 33, "ear": 5}, "ear: unknown landmark"),
    ({"nose_tip": 4, "chin": 152, "eye_outer_r": 33, "eye_outer_l": 99999}, "eye_outer_l: vertex 99999 does not exist"),
    ({"nose_tip": 4, "chin": 152, "eye_outer_r": 33, "eye_outer_l": "left"}, "eye_outer_l: expected a vertex index or"),
])
def test_bad_landmark_files_are_one_line_errors(tmp_path, landmarks, message):
    from test_cli import facesim as cli

    path = tmp_path / "landmarks.yaml"
    path.write_text(yaml.safe_dump(landmarks))
    result = cli("mesh", "align", HOPPER_MESH, "--landmarks", path, "-o", tmp_path / "out.obj")
    assert result.returncode == 2 and message in result.stderr and "Traceback" not in result.stderr
    assert result.stderr.strip().count("\n") == 0 and not (tmp_path / "out.obj").exists()
