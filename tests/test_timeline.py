"""Key-frame interpolation, FACS action units, MPEG-4 expressions, blending and sequences."""

import numpy as np
import pytest
import yaml
from conftest import EXPRESSIONS

import facesim
from facesim.animation.simulate import model_for
from facesim.animation.spec import activation_table, blend_spec, load_spec
from facesim.animation.timeline import interpolate
from facesim.config import HOPPER_MUSCLES
from facesim.errors import InputError
from facesim.face.muscle_file import MuscleFile, resolve_muscles

PEAK = ([0, 10, 20], [0.0, 1.0, 0.0])
PLATEAU = ([0, 10, 20, 30], [0.0, 1.0, 1.0, 0.0])


@pytest.mark.parametrize("kind, t, expected", [
    ("linear", 5, 0.5), ("linear", 15, 0.5), ("linear", -3, 0.0), ("linear", 25, 0.0),
    ("cosine", 2.5, (1 - np.cos(np.pi / 4)) / 2), ("cosine", 10, 1.0),
    # B-spline (seed eq. 3), outer control points reflected: -1, 0, 1, 0, -1
    ("bspline", 5, (0.125 * -1 + 2.875 * 1) / 6), ("bspline", 10, 4 / 6), ("bspline", 0, 0.0), ("bspline", 20, 0.0),
    # cardinal (seed eq. 4-6), tension 0: tangents 1, 0, -1
    ("cardinal", 5, 0.5 + 0.125), ("cardinal", 10, 1.0), ("cardinal", 20, 0.0),
])
def test_interpolation_against_hand_computed_values(kind, t, expected):
    assert interpolate(*PEAK, [t], kind)[0] == pytest.approx(expected, abs=1e-12)


def test_cardinal_tension_loosens_the_tangents():
    assert interpolate(*PEAK, [5], "cardinal", tension=0.5)[0] == pytest.approx(0.5 + 0.125 * 0.5)
    assert interpolate(*PEAK, [5], "cardinal", tension=1.0)[0] == pytest.approx(0.5)


def test_hold_keeps_equal_keys_flat_where_the_cardinal_spline_drifts():
    t = np.linspace(0, 30, 301)
    cardinal = interpolate(*PLATEAU, t, "cardinal")
    hold = interpolate(*PLATEAU, t, "hold")
    assert interpolate(*PLATEAU, [15], "cardinal")[0] == pytest.approx(1.125)  # the seed's fig. 14
    assert np.all(hold[(t >= 10) & (t <= 20)] == 1.0)
    assert hold.max() == 1.0 and hold.min() == 0.0 and cardinal.max() > 1.1
    assert np.all(np.diff(hold[t <= 10]) >= 0) and np.all(np.diff(hold[t >= 20]) <= 0)  # no overshoot


def write(tmp_path, data, name="spec"):
    path = tmp_path / f"{name}.yaml"
    path.write_text(yaml.safe_dump(data))
    return path


@pytest.fixture(scope="module")
def muscles():
    return model_for(facesim.load_spec(EXPRESSIONS / "happy.yaml")).muscles


def table(tmp_path, muscles, **data):
    return activation_table(load_spec(write(tmp_path, {"frames": 40, **data})), muscles)


def column(muscles, table_, name):
    return table_[:, muscles.index(name)]


def test_envelope_and_seconds_are_key_frames(tmp_path, muscles):
    by_envelope = table(tmp_path, muscles, timeline=[{"target": "risorius_l", "interpolation": "linear",
                                                      "envelope": {"start": 5, "onset": 10, "apex": 10, "offset": 10, "intensity": 0.8}}])
    by_keys = table(tmp_path, muscles, timeline=[{"target": "risorius_l", "interpolation": "linear", "unit": "second",
                                                  "keys": [[0.05, 0], [0.15, 0.8], [0.25, 0.8], [0.35, 0]]}])
    r = column(muscles, by_envelope, "risorius_l")
    assert np.allclose(r, column(muscles, by_keys, "risorius_l"))
    assert r[5] == 0 and r[10] == pytest.approx(0.4) and r[15] == r[25] == pytest.approx(0.8) and r[35:].max() == 0
    assert by_envelope[:, [i for i, n in enumerate(muscles.names) if n != "risorius_l"]].max() == 0


def test_blending_is_linear_in_the_activations(tmp_path, muscles):
    happy, surprise = (activation_table(load_spec(EXPRESSIONS / f"{n}.yaml"), muscles) for n in ("happy", "surprise"))
    blend = activation_table(blend_spec("happy=0.6,surprise=0.4"), muscles)
    assert np.allclose(blend, 0.6 * happy + 0.4 * surprise)
    included = table(tmp_path, muscles, frames=35, include=[{"spec": "happy", "weight": 0.3}])
    assert np.allclose(included, 0.3 * happy)


def test_mpeg4_expressions_by_name_with_intensity(tmp_path, muscles):
    happy = activation_table(load_spec(EXPRESSIONS / "happy.yaml").with_overrides(frames=40), muscles)
    joy = table(tmp_path, muscles, expressions={"joy": 0.5})
    assert np.allclose(joy, 0.5 * happy)
    with pytest.raises(InputError, match=r"expressions: Value error, 'contempt' is not one of the six"):
        table(tmp_path, muscles, expressions={"contempt": 0.5})


def test_a_paired_muscle_named_without_its_side_drives_both_sides(tmp_path, muscles):
    """``activations: {frontalis_galea: 0.7}``: the head has the frontalis's scalp end one a
    side, the thesis's face one midline muscle; the same spec drives either."""
    last = dict(zip(muscles.names, table(tmp_path, muscles, onset=0, activations={"frontalis_galea": 0.7})[-1]))
    assert last["frontalis_galea_l"] == last["frontalis_galea_r"] == pytest.approx(0.7)
    assert sum(v > 0 for v in last.values()) == 2
    with pytest.raises(InputError, match="activations -> frontalis: unknown muscle"):
        table(tmp_path, muscles, activations={"frontalis": 0.7})


def test_action_units_drive_their_muscles_with_facs_letters(tmp_path, muscles):
    t = table(tmp_path, muscles, onset=0, aus={"AU12": "E", "AU1": "C", "AU4": 0.5})
    last = dict(zip(muscles.names, t[-1]))
    assert last["zygomaticus_major_l"] == last["zygomaticus_major_r"] == 1.0
    assert last["frontalis_medial_l"] == last["frontalis_galea_l"] == pytest.approx(0.6)  # both ends of the frontalis
    assert last["corrugator_supercilii_r"] == last["procerus"] == 0.5
    assert sum(v > 0 for v in last.values()) == 2 + 4 + 3


def test_an_action_unit_without_its_muscles_is_an_error(tmp_path, mesh):
    data = yaml.safe_load(HOPPER_MUSCLES.read_text())
    data["muscles"] = [m for m in data["muscles"] if not m["name"].startswith("orbicularis_oculi")]
    del data["jaw"]
    stripped = resolve_muscles(MuscleFile.model_validate(data), mesh)
    with pytest.raises(InputError, match=r"aus -> AU6: AU6 \(cheek raiser\) needs the orbicularis oculi"):
        table(tmp_path, stripped, aus={"AU6": 0.8, "AU12": 1.0})
    with pytest.raises(InputError, match=r"aus -> AU26: AU26 \(jaw drop\) needs the jaw"):
        table(tmp_path, stripped, aus={"AU26": 0.5})
    with pytest.raises(InputError, match=r"aus: Value error, intensity must be a FACS letter A-E"):
        table(tmp_path, muscles, aus={"AU12": "F"})


def test_domination_and_opposition(tmp_path, muscles):
    t = table(tmp_path, muscles, onset=0, aus={"AU12": 1.0, "AU15": 0.75, "AU16": 0.9, "AU17": 0.3})[-1]
    last = dict(zip(muscles.names, t))
    assert last["zygomaticus_major_l"] == pytest.approx(0.25)  # AU15 dominates AU12
    assert last["depressor_anguli_oris_l"] == 0.75
    assert last["depressor_labii_inferioris_l"] == pytest.approx(0.6) and last["mentalis_l"] == 0  # opposition
    both = dict(zip(muscles.names, table(tmp_path, muscles, onset=0, aus={"AU14": 0.5, "AU20": 0.5})[-1]))
    assert both["buccinator_l"] == both["risorius_l"] == 0.5  # two muscles: the dimpler and the stretcher combine


def test_sequences_hold_each_expression_and_ease_between(tmp_path, muscles):
    spec = load_spec(EXPRESSIONS / "sequence.yaml")
    t = activation_table(spec, muscles)
    assert spec.frames == len(t) == 120
    happy = activation_table(load_spec(EXPRESSIONS / "happy.yaml"), muscles)[-1]
    surprise = activation_table(load_spec(EXPRESSIONS / "surprise.yaml"), muscles)[-1]
    assert t[:10].max() == 0
    assert np.allclose(t[25:50], happy) and np.allclose(t[65:90], surprise) and t[105:].max() == 0
    steps = np.abs(np.diff(t, axis=0)).max(axis=1)
    assert steps.max() < 0.2  # smooth transitions, no jumps
    with pytest.raises(InputError, match=r"frames \(50\) differs from the sequence's 120 frames"):
        load_spec(write(tmp_path, {**yaml.safe_load((EXPRESSIONS / "sequence.yaml").read_text()), "frames": 50}))


@pytest.mark.parametrize("track, message", [
    ({"target": "risorius_l", "keys": [[10, 1.0], [5, 0.0]]}, "keys: Value error, out of order"),
    ({"target": "risorius_l", "keys": [[0, 1.0]], "interpolation": "quadratic"}, "interpolation: Input should be 'linear'"),
    ({"target": "risorius_l", "keys": [[0, 1.0]], "interpolation": "cardinal", "tension": 1.5}, "tension: Input should be less than or equal to 1"),
    ({"target": "risorius_l", "keys": [[0, 1.5]]}, "less than or equal to 1"),
    ({"target": "risorius_l"}, "give either keys or an envelope"),
    ({"target": "smile", "keys": [[0, 1.0]]}, "'smile' is neither a muscle, an action unit, nor an expression spec"),
])
def test_bad_timelines_are_one_line_errors(tmp_path, muscles, track, message):
    with pytest.raises(InputError, match=message) as info:
        table(tmp_path, muscles, timeline=[track])
    assert str(info.value).startswith(str(tmp_path / "spec.yaml")) and "\n" not in str(info.value)


def test_happy_surprise_as_a_blend_of_happy_and_surprise():
    """Blending happy and surprise (expressions/blends/) gives the thesis's composite's
    brows, within 0.1 mm, once the composite (made for a jawless face) drops the jaw as
    surprise does (AU26): the frontalis come from surprise unchanged. Left out, the jaw
    alone is 1.4 mm at the outer brows (a single-layer skin carries its pull up the face;
    ICT's jawOpen moves them 0.02 mm). With happy's lip corners drawn up and out over
    surprise's own: up and out, as ICT's smile (AU12) moves them; with the jaw dropped,
    the calibrated zygomaticus major draws them 1.5 mm out and 0.9 mm up beyond surprise."""
    composite_spec = load_spec(EXPRESSIONS / "happy_surprise.yaml")
    jawless = facesim.simulate(composite_spec)
    composite = facesim.simulate(composite_spec.with_overrides(aus={**composite_spec.aus, "AU26": 1.0}))
    blend = facesim.simulate(load_spec(EXPRESSIONS / "blends" / "happy_surprise.yaml"))
    surprise = facesim.simulate(load_spec(EXPRESSIONS / "surprise.yaml"))
    assert blend.inverted.max() == 0
    shape_gap = np.linalg.norm(composite.positions[-1] - blend.positions[-1], axis=1)
    assert shape_gap[[105, 334, 70, 300]].max() < 0.01
    for corner, outward in ((61, -1.0), (291, 1.0)):
        drawn = blend.positions[-1, corner] - surprise.positions[-1, corner]
        assert drawn[1] > 0.05 and outward * drawn[0] > 0.05 and np.hypot(drawn[0], drawn[1]) > 0.15
    gap = [np.linalg.norm(a.positions[-1, 13] - a.positions[-1, 14]) for a in (jawless, blend)]
    assert gap[1] - gap[0] > 0.8  # cm: the jaw dropped


def test_disgusted_anger_as_a_blend_of_anger_and_disgust():
    """Anger with disgust at 0.7 (expressions/blends/) reads as the thesis's composite
    (its check in tests/test_simulation.py passes), but one-sided where the composite is
    not, since disgust is."""
    from test_simulation import CHECKS

    blend = facesim.simulate(load_spec(EXPRESSIONS / "blends" / "disgusted_anger.yaml"))
    assert blend.inverted.max() == 0
    assert CHECKS["disgusted_anger"][0](blend.rest, blend.positions[-1])
    assert abs(blend.positions[-1][269, 1] - blend.positions[-1][39, 1]) > 0.05


def test_the_sequence_simulates_without_inverting():
    animation = facesim.simulate(load_spec(EXPRESSIONS / "sequence.yaml"))
    assert animation.frames == 120 and animation.inverted.max() == 0
    lift = animation.positions[:, 61, 1] - animation.rest[61, 1]
    assert lift[45] > 0.1 and abs(lift[-1]) < 0.05
