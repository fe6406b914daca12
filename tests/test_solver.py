"""The physics core's solver: the implicit step, one per frame, holds each expression
where small steps do, and the thesis's preset runs the thesis's model. (A force term
added as one kernel and one line, and a changed kernel compiled again in its callers:
tests/test_compile.py, which compiles a copy of the package.)"""


import numpy as np
import pytest
from conftest import THESIS_EXPRESSIONS, held_apex, material, spec

from facesim.config import PROJECT_DIR


@pytest.mark.parametrize("name", THESIS_EXPRESSIONS)
def test_one_implicit_step_per_frame_holds_each_expression_where_small_steps_do(name):
    """The default step (one per frame) against the same model at eight steps per frame
    with conjugate gradients run to 1e-8: the held apex within 2% of the largest
    displacement. The thesis's per-vertex update cannot be the reference here: the skin's
    bending couples four vertices per hinge, which it cannot carry (facesim.physics.model.Material);
    it is checked against the thesis's equations in tests/test_kernels.py instead."""
    model, reference, folded = held_apex(spec(name, material=material(name, substeps=8, tolerance=1e-8, iterations=2000)))
    implicit_model, implicit, implicit_folded = held_apex(spec(name))
    assert (folded, implicit_folded) == (0, 0)
    assert (model.material.substeps, implicit_model.material.substeps) == (8, 1)
    largest = np.linalg.norm(reference - model.rest_position, axis=1).max()
    assert largest > 0.2  # every expression moves the face by millimetres
    assert np.linalg.norm(implicit - reference, axis=1).max() <= 0.02 * largest


def test_the_thesis_preset_is_the_thesis_model(tmp_path):
    """``material: {preset: thesis}`` in a spec runs the thesis's model for its tables:
    its update at four steps per frame, no bending; fields the spec gives still win.
    Happy in it, on the Hopper face, moves the face and folds nothing."""
    import facesim
    from facesim.animation.simulate import model_for
    from facesim.animation.spec import activation_table
    from facesim.config import HOPPER_MESH
    from facesim.physics.run import run

    path = tmp_path / "thesis_happy.yaml"
    path.write_text((PROJECT_DIR / "expressions" / "happy.yaml").read_text()
                    + f"mesh: {HOPPER_MESH}\nmaterial: {{preset: thesis, damping: 35}}\n")
    thesis = facesim.load_spec(path)
    model = model_for(thesis)
    assert (model.arrays.implicit, model.material.substeps, model.arrays.bending) == (False, 4, 0.0)
    assert model.material.damping == 35
    positions, _, inverted, _ = run(model, activation_table(thesis, model.muscles), thesis.dt, stop_on_inversion=False)
    assert inverted.max() == 0
    assert np.linalg.norm(positions[-1] - model.rest_position, axis=1).max() > 0.3
    assert model_for(spec("happy")).arrays.implicit
