"""The tongue as a rigged part (issue 46: FACS's AU19, ARKit's tongueOut, and the tip
raised for speech's /l/): shown with the jaw open, its tip at least a centimetre past the
lower incisors; at any opening of the jaw, protruded or raised, nothing of it inside a
tooth; and refused on a face with no tongue to draw."""

import numpy as np
import pytest

import facesim
from facesim.animation.calibration import TONGUE_PAST, lower_incisors, tongue_in_teeth, tongue_past_incisors
from facesim.animation.simulate import model_for
from facesim.animation.spec import Spec
from facesim.config import HOPPER_MESH
from facesim.errors import InputError
from facesim.face.figure import figure_for


def tongue_spec(aus=None, arkit=None, **fields):
    return Spec.model_validate(dict(name="tongue", frames=30, aus=aus or {}, arkit=arkit or {}, **fields))


@pytest.fixture(scope="module")
def head():
    model = model_for(tongue_spec())
    return model, figure_for(model)


def drawn(out=0.0, up=0.0) -> np.ndarray:
    """The drawn controls (facesim.animation.simulate.look_table) with the tongue's two set."""
    return np.array([0, 0, 0, 0, 0, 0, out, up], dtype=np.float64)


def test_the_tongue_shown_lies_a_centimetre_past_the_lower_incisors(head):
    model, figure = head
    rest = tongue_past_incisors(figure, model.mesh.head, figure.rest)
    assert -1.5 < rest < 0  # at rest, behind them
    for spec in (tongue_spec(aus={"AU19": 1.0}), tongue_spec(arkit={"tongueOut": 1.0, "jawOpen": 0.5})):
        animation = facesim.simulate(spec)
        x = animation.head_at(animation.frames - 1)
        assert tongue_past_incisors(figure, model.mesh.head, x) >= TONGUE_PAST, spec
        assert tongue_in_teeth(figure, model.mesh.head, x) == 0
    assert len(lower_incisors(figure, model.mesh.head)) > 100


@pytest.mark.parametrize("out, up", [(0.25, 0.0), (0.5, 0.0), (1.0, 0.0), (0.0, 1.0), (0.5, 1.0), (1.0, 1.0)])
def test_nothing_of_the_tongue_passes_through_a_tooth_at_any_opening_of_the_jaw(head, out, up):
    model, figure = head
    inside = {}
    for angle in np.linspace(0.0, 20.0, 11):  # the head's jaw: max_angle 20 degrees
        x = figure.positions(model.rest_position, np.radians(angle), (0.0, 0.0), drawn(out, up))
        inside[f"{angle:.0f} degrees"] = tongue_in_teeth(figure, model.mesh.head, x)
    assert not any(inside.values()), inside


def test_the_tip_raised_rises_a_centimetre_with_the_jaw_closed(head):
    model, figure = head
    tongue = figure.tongue.rows
    tip = tongue[np.argmax(figure.rest[tongue, 2])]
    x = figure.positions(model.rest_position, 0.0, (0.0, 0.0), drawn(up=1.0))
    assert x[tip, 1] - figure.rest[tip, 1] >= 1.0
    assert np.array_equal(figure.positions(model.rest_position, 0.0, (0.0, 0.0), drawn()), figure.rest)


def test_the_tongue_on_a_face_with_none_is_refused():
    """A mask (the Hopper face) has no tongue to draw: its muscle file has no tongue
    controls, and a spec that moves them is refused by name before anything runs."""
    for fields, message in ((dict(aus={"AU19": 1.0}), "AU19 .tongue show. needs the tongue out"),
                            (dict(arkit={"tongueOut": 1.0}), "tongue_out moves a head's tongue, and this face has none")):
        with pytest.raises(InputError, match=message):
            facesim.simulate(tongue_spec(mesh=str(HOPPER_MESH), **fields))
