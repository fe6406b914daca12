"""Any face mesh: the material scaled to the mesh's resolution, muscles carried by position,
and meshes aligned to the default face from named landmarks."""

import numpy as np
import pytest
import yaml

import facesim
from facesim.simulate import model_for
from conftest import EXPRESSIONS
from facesim.config import DEFAULT_MESH, DEFAULT_MUSCLES
from facesim.mesh import load_mesh, subdivide, write_obj
from facesim.muscles import MuscleFile, muscles_as_points
from facesim.schema import load_model
from facesim.spec import load_spec
from test_simulation import CHECKS


@pytest.fixture(scope="module")
def subdivided(tmp_path_factory):
    """The default face Loop-subdivided once (its first 468 vertices are the originals,
    smoothed) and the default muscle file carried to it by position."""
    root = tmp_path_factory.mktemp("sub1")
    base = load_mesh(DEFAULT_MESH)
    write_obj(root / "face.obj", subdivide(base, 1))
    carried = muscles_as_points(load_model(DEFAULT_MUSCLES, MuscleFile), base)
    (root / "face.muscles.yaml").write_text(yaml.safe_dump(carried.model_dump(mode="json")))
    return root / "face.obj", root / "face.muscles.yaml"


def on(spec, mesh_and_muscles):
    mesh, muscles = mesh_and_muscles
    return spec.with_overrides(mesh=mesh, muscles=muscles)


def test_the_material_scales_with_the_skin_area_per_vertex(subdivided):
    spec = load_spec(EXPRESSIONS / "sad.yaml")
    default = model_for(spec)
    assert default.resolution == 1.0 and default.material == spec.material
    fine = model_for(on(spec, subdivided))
    assert fine.vertex_count == 1790 and 0.2 < fine.resolution < 0.3
    s = fine.resolution
    assert fine.material.mass == pytest.approx(s) and fine.material.tissue == pytest.approx(300 * s)
    assert fine.material.substeps == 8 and fine.length_unit == pytest.approx(np.sqrt(s))
    assert fine.muscle_force.sum() == pytest.approx(s * default.muscle_force.sum())


@pytest.mark.parametrize("name", ["sad", "angry"])
def test_a_subdivided_face_moves_like_the_default_one(subdivided, name):
    spec = load_spec(EXPRESSIONS / f"{name}.yaml")
    coarse = facesim.simulate(spec)
    fine = facesim.simulate(on(spec, subdivided))
    assert fine.inverted.max() == 0
    assert CHECKS[name][0](fine.rest, fine.positions[-1])
    for corner in (61, 291):  # Loop subdivision keeps the original vertices first
        a = coarse.positions[-1, corner] - coarse.rest[corner]
        b = fine.positions[-1, corner] - fine.rest[corner]
        assert np.linalg.norm(a - b) < 0.2 * np.linalg.norm(a)
