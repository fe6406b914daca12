"""The default face mesh, meshes/face.obj, and the builder that makes it from a photo."""

import importlib.util

import numpy as np
import pytest
from forked import facesim_process

from facesim.config import HOPPER_MESH, HOPPER_MUSCLES
from facesim.errors import InputError
from facesim.face.loading import load_mesh
from facesim.face.muscle_file import load_muscles
from facesim.physics.mesh import mirror_map


@pytest.fixture(scope="module")
def mesh():
    """These tests are about the committed Hopper face (the default head simulates it)."""
    return load_mesh(HOPPER_MESH)

HAS_MEDIAPIPE = importlib.util.find_spec("mediapipe") is not None
needs_mediapipe = pytest.mark.skipif(not HAS_MEDIAPIPE, reason="MediaPipe not installed (pip install -e '.[photo]')")


def test_size_matches_mediapipe_face_mesh(mesh):
    assert mesh.vertex_count == 468
    assert len(mesh.faces) == 852


def test_one_open_surface_with_rim_mouth_and_eye_openings(mesh):
    assert mesh.connected_components() == 1
    assert mesh.edge_face_count.max() == 2  # manifold
    loops = mesh.boundary_loops
    assert [len(loop) for loop in loops] == [36, 20, 16, 16]
    rim, mouth, eye_a, eye_b = (set(loop.tolist()) for loop in loops)
    assert {13, 14, 78, 308} <= mouth
    assert {159, 145} <= eye_a | eye_b and {386, 374} <= eye_a | eye_b
    assert {10, 152} <= rim


def test_mirror_symmetric(mesh):
    mapping = mirror_map(mesh.vertices, mesh.faces)  # also checks triangles map to triangles
    mirrored = mesh.vertices[mapping] * np.array([-1.0, 1.0, 1.0])
    assert np.abs(mirrored - mesh.vertices).max() <= 1e-6
    assert (mapping == np.arange(468)).sum() == 28  # midline landmarks
    assert mapping[61] == 291 and mapping[33] == 263


def test_triangles_face_the_viewer(mesh):
    assert (mesh.face_normals[:, 2] > 0).mean() >= 0.95


def test_adult_proportions_in_centimetres(mesh):
    v = mesh.vertices
    assert 4.0 <= np.linalg.norm(v[61] - v[291]) <= 6.0  # mouth width ch-ch
    assert np.linalg.norm(v[33] - v[263]) == pytest.approx(8.9, abs=1e-5)  # the scale reference ex-ex
    # MediaPipe's top landmark (10) sits at mid-forehead, below the hairline, so the mesh
    # is shorter than a hairline-to-chin face height (about 18 cm)
    assert 13.0 <= v[10, 1] - v[152, 1] <= 20.0
    assert 10.0 <= np.linalg.norm(v[168] - v[152]) <= 13.5  # nasion-gnathion, Farkas adult range
    assert v[4, 2] == v[:, 2].max()  # nose tip foremost
    assert v[10, 1] == v[:, 1].max() and v[152, 1] == v[:, 1].min()


def test_right_landmarks_lie_on_the_subjects_right(mesh):
    """MediaPipe's RIGHT_EYE and mouth-corner 61 are the subject's right, at -x."""
    v = mesh.vertices
    assert v[33, 0] < 0 and v[61, 0] < 0 and v[263, 0] > 0 and v[291, 0] > 0


def test_loading_a_missing_or_unreadable_mesh_is_one_line(tmp_path):
    with pytest.raises(InputError, match="mesh file not found"):
        load_mesh(tmp_path / "none.obj")
    bad = tmp_path / "bad.obj"
    bad.write_text("this is not a mesh\n")
    with pytest.raises(InputError, match="bad.obj"):
        load_mesh(bad)


@needs_mediapipe
def test_make_mesh_rebuilds_the_committed_face(tmp_path):
    import matplotlib.cbook

    from facesim.face.photo import mesh_from_photo

    photo = matplotlib.cbook.get_sample_data("grace_hopper.jpg", asfileobj=False)
    rebuilt = mesh_from_photo(photo, tmp_path / "face.obj")
    committed = load_mesh(HOPPER_MESH)
    assert np.array_equal(rebuilt.faces, committed.faces)
    assert np.abs(rebuilt.vertices - committed.vertices).max() <= 1e-4


@needs_mediapipe
def test_a_photo_without_a_face_is_a_clear_error(tmp_path):
    import imageio.v3 as iio

    from facesim.face.photo import mesh_from_photo

    blank = tmp_path / "blank.png"
    iio.imwrite(blank, np.full((256, 256, 3), 200, dtype=np.uint8))
    with pytest.raises(InputError, match=r"blank.png: no face found"):
        mesh_from_photo(blank, tmp_path / "out.obj")
    assert not (tmp_path / "out.obj").exists()


@needs_mediapipe
def test_a_second_photo_gives_a_valid_mesh_that_carries_the_default_muscles(tmp_path):
    import imageio.v3 as iio
    from skimage import data

    from facesim.face.photo import mesh_from_photo

    photo = tmp_path / "astronaut.png"
    iio.imwrite(photo, data.astronaut())
    mesh = mesh_from_photo(photo, tmp_path / "astronaut.obj")
    loaded = load_mesh(tmp_path / "astronaut.obj")
    assert loaded.vertex_count == 468 and len(loaded.faces) == 852
    assert [len(loop) for loop in loaded.boundary_loops] == [36, 20, 16, 16]
    assert (loaded.face_normals[:, 2] > 0).mean() >= 0.95
    assert np.abs(loaded.vertices - mesh.vertices).max() < 1e-5
    muscles = load_muscles(HOPPER_MUSCLES, loaded)
    from facesim.physics.muscles import GAZE, JAW_CONTROLS, PUPIL

    lids = [(f"eyelid_{s}", f"levator_palpebrae_{s}", *(f"{g}_{s}" for g in GAZE), f"{PUPIL}_{s}") for s in "rl"]
    assert muscles.count == 40 and muscles.controls == (*JAW_CONTROLS, *lids[0], *lids[1])


@needs_mediapipe
def test_cli_from_photo_on_a_blank_image_is_one_line(tmp_path):
    import imageio.v3 as iio

    blank = tmp_path / "blank.png"
    iio.imwrite(blank, np.zeros((128, 128, 3), dtype=np.uint8))
    result = facesim_process(["mesh", "from-photo", str(blank), "-o", str(tmp_path / "m.obj")])
    assert result.returncode == 2
    assert result.stderr.strip().endswith("blank.png: no face found in the image")
    assert "Traceback" not in result.stderr and not (tmp_path / "m.obj").exists()


def run_mesh_info(path):
    return facesim_process(["mesh", "info", str(path)])


def test_mesh_info_on_the_default_face():
    result = run_mesh_info(HOPPER_MESH)
    assert result.returncode == 0
    assert "468 vertices, 852 triangles" in result.stdout and "[36, 20, 16, 16]" in result.stdout
    assert "fits by landmark index" in result.stdout and "ok: usable" in result.stdout


def test_mesh_info_names_what_is_wrong(tmp_path, mesh):
    from facesim.face.loading import write_obj
    from facesim.physics.mesh import FaceMesh
    cases = {
        "mm.obj": (FaceMesh(mesh.vertices * 10, mesh.faces), "wrong units?"),
        "flipped.obj": (FaceMesh(mesh.vertices, np.vstack([mesh.faces[:10, ::-1], mesh.faces[10:]])), "flipped"),
        "back.obj": (FaceMesh(mesh.vertices * np.array([-1.0, 1.0, -1.0]), mesh.faces), "face away from +z"),  # turned round
    }
    for name, (broken, message) in cases.items():
        write_obj(tmp_path / name, broken)
        result = run_mesh_info(tmp_path / name)
        assert result.returncode == 1 and message in result.stdout, name
    tetra = tmp_path / "closed.obj"
    tetra.write_text("v 0 0 0\nv 10 0 0\nv 0 10 0\nv 0 0 10\nf 1 3 2\nf 1 2 4\nf 2 3 4\nf 1 4 3\n")
    result = run_mesh_info(tetra)
    assert result.returncode == 1 and "a closed head" in result.stdout and "facesim mesh align" in result.stdout
