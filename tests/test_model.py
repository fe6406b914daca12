"""The model's cache-friendly vertex order (facesim.physics.model.reordered): a large mesh is
simulated in an order of its own, and everything a user sees stays in the mesh's."""

import numpy as np
import pytest
from conftest import material, spec

import facesim.physics.model as model_module
from facesim.animation.spec import activation_table
from facesim.config import HOPPER_MESH, HOPPER_MUSCLES
from facesim.face.loading import load_face
from facesim.face.material import face_model
from facesim.face.muscle_file import load_muscles
from facesim.physics.layout import ModelArrays
from facesim.physics.run import muscle_forces, run


def test_every_field_of_the_kernels_arrays_is_carried_to_a_new_order_one_way():
    named = (model_module.PER_VERTEX + model_module.VERTEX_VALUED + model_module.PER_SPRING + model_module.PER_TRIANGLE
             + model_module.PER_HINGE + model_module.PER_VERTEX_ROWS + model_module.UNCHANGED)
    assert len(named) == len(set(named))
    assert set(named) == set(ModelArrays._fields)


@pytest.fixture(scope="module")
def hopper():
    mesh = load_face(HOPPER_MESH)
    return mesh, load_muscles(HOPPER_MUSCLES, mesh)


def both_orders(hopper, material_):
    """The Hopper face's model in its own order, and in its cache order (which only a
    larger mesh takes by default)."""
    own = face_model(*hopper, material_)
    reordered = face_model(*hopper, material_, reorder=True)
    assert own.vertex_order is None and reordered.vertex_order is not None
    assert not np.array_equal(reordered.vertex_order, np.arange(own.vertex_count))
    return own, reordered


def test_the_kernels_arrays_in_cache_order_are_the_same_mesh(hopper):
    own, model = both_orders(hopper, spec("happy").material)
    a, order = model.arrays, model.vertex_order
    assert np.array_equal(a.rest_position, own.rest_position[order])
    assert np.array_equal(model.mesh_vertex(a.faces), own.faces[model.triangle_order])  # windings kept
    assert np.array_equal(a.corner_rest_distance, own.arrays.corner_rest_distance[:, model.triangle_order])
    assert np.array_equal(a.spring_end.T, a.spring_indices)
    assert {tuple(sorted(e)) for e in model.mesh_vertex(a.spring_indices)} == {tuple(e) for e in own.spring_indices}
    assert np.allclose(a.spring_rest_length, np.linalg.norm(a.rest_position[a.spring_end[0]] - a.rest_position[a.spring_end[1]],
                                                            axis=1), rtol=0, atol=1e-12)
    for k in range(model.vertex_count):  # each vertex's neighbours and ring, in their sequence
        i = order[k]
        assert np.array_equal(model.mesh_vertex(a.neighbour_index[a.neighbour_start[k]:a.neighbour_start[k + 1]]),
                              own.neighbour_index[own.neighbour_start[i]:own.neighbour_start[i + 1]])
        assert np.array_equal(model.mesh_vertex(a.ring_a[a.ring_start[k]:a.ring_start[k + 1]]),
                              own.ring_a[own.ring_start[i]:own.ring_start[i + 1]])
    assert np.array_equal(model.mesh_vertex(a.muscle_insertion), own.muscle_insertion)
    assert np.array_equal(model.mesh_vertex(a.contact_upper), own.arrays.contact_upper)
    assert np.array_equal(a.lid_column, own.arrays.lid_column[order])
    # springs, triangles and hinges follow the new order, so a loop over them walks memory forwards
    assert np.all(np.diff(a.spring_indices[:, 0]) >= 0)
    assert np.all(np.diff(a.faces.min(axis=1)) >= 0)


@pytest.mark.parametrize("name, preset", [("happy", "thesis"), ("happy", None), ("surprise", None)],
                         ids=["happy, the thesis's update", "happy, implicit with bending", "surprise, jaw and lids"])
def test_a_face_simulated_in_cache_order_moves_as_in_its_own(hopper, name, preset):
    s = spec(name, material=None if preset is None else material(name, preset=preset))
    own, reordered = both_orders(hopper, s.material)
    table = activation_table(s, own.muscles)
    expected, *_, smallest = run(own, table, s.dt)
    got, *_, smallest_reordered = run(reordered, table, s.dt)
    assert np.abs(expected[-1] - own.rest_position).max() > 0.2  # it moved
    assert np.abs(got - expected).max() < 1e-6  # cm: the same motion, summed in another order
    assert np.allclose(smallest_reordered, smallest, rtol=1e-6, atol=0)
    row = table[-1]
    assert np.abs(muscle_forces(reordered, expected[-1], row) - muscle_forces(own, expected[-1], row)).max() < 1e-9


def test_a_face_in_cache_order_simulated_frame_by_frame_in_the_background_gives_the_same_frames(hopper):
    from facesim.physics.run import Progress
    s = spec("happy", frames=12)
    _, reordered = both_orders(hopper, s.material)
    table = activation_table(s, reordered.muscles)
    whole = run(reordered, table, s.dt)[0]
    progress = Progress()
    streamed = run(reordered, table, s.dt, progress=progress)[0]  # one frame a call, into the mesh's order frame by frame
    assert progress.done == len(table) and np.array_equal(streamed, whole)
