"""MPEG-4's 68 facial animation parameters (issue 48): the table, the FAP units measured
on a face, each FAP group driven on the head in both directions, and FAP files.

A FAP moves its feature point along its direction by its value in FAP units; facesim
turns the value into its controls' activations (facesim.animation.mpeg4). Measured on
the head as the renderer draws it (``Animation.head_at``)."""

import math

import numpy as np
import pytest

import facesim
from facesim.animation.mpeg4 import ANGLE_UNIT, fap_table, fap_units, point_motion
from facesim.animation.spec import Spec, load_spec
from facesim.errors import InputError

FRAMES = 60
#: A FAP is driven at this share of its gain: its controls at 0.4.
SHARE = 0.4


def driven(fap: dict, frames: int = FRAMES, **spec) -> facesim.Animation:
    return facesim.simulate(Spec.model_validate(dict(name="fap", frames=frames, fap=fap, **spec)))


@pytest.fixture(scope="module")
def units():
    return fap_units(facesim.simulate(Spec(name="rest", frames=1)).model.mesh.head.landmark_positions)


def test_the_table_is_mpeg4s_68_with_their_units_and_directions():
    table = fap_table()
    assert sorted(table) == list(range(1, 69)) and len({f.name for f in table.values()}) == 68
    # anchors from the standard's Table C-1
    for number, name, unit, both, direction in [(3, "open_jaw", "MNS", False, "down"), (6, "stretch_l_cornerlip", "MW", True, "left"),
                                                (19, "close_t_l_eyelid", "IRISD", True, "down"), (23, "yaw_l_eyeball", "AU", True, "left"),
                                                (37, "squeeze_l_eyebrow", "ES", True, "right"), (41, "lift_l_cheek", "ENS", False, "up"),
                                                (48, "head_pitch", "AU", True, "down"), (59, "raise_l_cornerlip_o", "MNS", True, "up"),
                                                (68, "pull_r_ear", "ENS", True, "right")]:
        fap = table[number]
        assert (fap.name, fap.unit, fap.both, fap.direction) == (name, unit, both, direction)
    for fap in table.values():
        assert fap.simulated or fap.none, fap.number  # every FAP is shown, or says why not
        assert all(g > 0 for g, c in zip(fap.gain, (fap.plus, fap.minus)) if c), fap.number


def test_fap_units_are_measured_on_each_face(units):
    cm = {name: value * 1024 for name, value in units.items() if name != "AU"}
    assert 4.0 < cm["MW"] < 6.0 and 5.5 < cm["ES"] < 7.0 and 0.8 < cm["IRISD"] < 1.4 and 1.5 < cm["MNS"] < 3.0
    assert 3.0 < cm["ENS"] < 5.5 and units["AU"] == 1e-5
    other = fap_units(facesim.simulate(Spec(name="rest", frames=1, identity=7)).model.mesh.head.landmark_positions)
    assert other != units and all(0.7 < other[k] / units[k] < 1.4 for k in units)


def low_level(group: int):
    return [f for f in fap_table().values() if f.group == group and f.simulated and not f.pose]


@pytest.mark.parametrize("group", [2, 3, 4, 5, 6, 8, 9])
def test_each_fap_of_a_group_moves_its_point_its_way_by_about_its_value(group, units):
    """Positive values along the FAP's direction, negative ones against it, each by its
    value in FAP units within a factor of two (the muscles are not linear)."""
    failures = []
    for fap in low_level(group):
        for gain, sign in ((fap.gain[0], 1.0), (fap.gain[1], -1.0)):
            if gain == 0:
                continue
            value = sign * SHARE * gain
            base = {3: 470} if fap.base else {}
            animation = driven({**base, fap.number: value})
            moved = point_motion(animation, fap, FRAMES - 1)
            if fap.base:
                moved -= point_motion(driven(base), fap, FRAMES - 1)
            if fap.unit == "AU":  # an eye's turn: its cornea's apex moves r sin(angle) that way
                radius = animation.model.mesh.head.eyeball("left")[1]
                moved = math.asin(np.clip(moved / radius, -1.0, 1.0)) / ANGLE_UNIT
            else:
                moved /= units[fap.unit]
            if not (moved * sign > 0 and 0.5 < moved / value < 2.0):
                failures.append((fap.number, fap.name, round(value), round(moved)))
    assert not failures, failures


def test_the_head_turns_as_the_head_faps_say():
    nose, top = 1, 10
    degrees = 15
    value = math.radians(degrees) / ANGLE_UNIT
    for number, landmark, axis, sign in [(48, nose, 1, -1), (49, nose, 0, 1), (50, top, 0, -1)]:
        animation = driven({number: value}, frames=15)
        head = animation.model.mesh.head
        rest, x = animation.figure.rest, animation.head_at(14)
        rows, weights = head.landmark_vertex[landmark], head.landmark_weight[landmark]
        moved = weights @ (x[rows] - rest[rows])
        assert moved[axis] * sign > 0.5, (number, moved)  # centimetres: the head turned that way


def test_a_viseme_and_an_expression_as_faps():
    """FAP 1 (viseme 1, p b m, then viseme 10, A:) closes then opens the lips; FAP 2
    (expression 1, joy, at 63) lifts the lip corners as happy does."""
    closed, opened = driven({1: [1, 0, 63]}), driven({1: [10, 0, 63]})
    chin = fap_table()[3]
    assert point_motion(opened, chin, FRAMES - 1) > 3 * point_motion(closed, chin, FRAMES - 1) > 0  # A: opens the jaw
    assert closed.activations[-1, closed.muscle_names.index("lip_seal")] > 0.9
    joy = driven({2: [1, 63]})
    corner = fap_table()[59]
    assert point_motion(joy, corner, FRAMES - 1) > 0.2  # cm up
    half = driven({2: [1, 32]})
    assert 0.3 < point_motion(half, corner, FRAMES - 1) / point_motion(joy, corner, FRAMES - 1) < 0.8


def test_faps_the_head_cannot_show_are_said_and_leave_it_still():
    said = []
    animation = facesim.simulate(Spec.model_validate(dict(name="ears", frames=5, fap={"raise_l_ear": 300, 27: 40})),
                                 notice=said.append)
    assert said and "FAPs 27, 65" in said[0] and "docs/mpeg4.md" in said[0]
    assert not animation.activations.any()


def fap_file(path, frames: list[dict[int, list[float]]], fps: float = 25.0) -> None:
    lines = ["# facesim's test", f"2.1 test {fps:g} {len(frames)}"]
    for k, values in enumerate(frames):
        lines.append(" ".join("1" if n in values else "0" for n in range(1, 69)))
        lines.append(" ".join([str(k)] + [f"{v:g}" for n in sorted(values) for v in values[n]]))
    path.write_text("\n".join(lines) + "\n")


def test_a_frame_of_a_fap_file_on_one_line_reads_the_same(tmp_path):
    two = "2.1 t 25 2\n" + ("0 0 1" + " 0" * 65 + "\n0 120\n") + ("0 0 1" + " 0" * 65 + "\n1 240\n")
    one = "2.1 t 25 2\n" + ("0 0 1" + " 0" * 65 + " 0 120\n") + ("0 0 1" + " 0" * 65 + " 1 240\n")
    from facesim.animation.mpeg4 import read_fap_file

    (tmp_path / "two.fap").write_text(two)
    (tmp_path / "one.fap").write_text(one)
    fps, values = read_fap_file(tmp_path / "one.fap")
    assert fps == 25 and values[3].tolist() == [120.0, 240.0] == read_fap_file(tmp_path / "two.fap")[1][3].tolist()


def test_a_fap_file_plays_in_real_time(tmp_path):
    """The jaw opens over the file's frames, and a FAP a frame's mask leaves out holds."""
    frames = [{3: [40.0 * k], 12: [200.0]} if k % 2 == 0 else {3: [40.0 * k]} for k in range(20)]
    frames[5][1] = [1, 0, 63, 0]
    fap_file(tmp_path / "talk.fap", frames, fps=20)
    (tmp_path / "spec.yaml").write_text("fap: talk.fap\n")
    spec = load_spec(tmp_path / "spec.yaml")
    assert (spec.frames, spec.fps, spec.dt) == (20, 20.0, 0.05)
    values = spec.fap_values()
    assert np.allclose(values[3], 40.0 * np.arange(20)) and np.all(values[12] == 200.0)
    assert values[1].shape == (20, 4) and values[1][5:, 0].tolist() == [1.0] * 15 and not values[1][:5].any()
    animation = facesim.simulate(spec)
    chin = [point_motion(animation, fap_table()[3], k) for k in range(0, 20, 4)]
    assert chin == sorted(chin) and chin[-1] > 0.3


@pytest.mark.parametrize("text, message", [
    ("2.1 test 25\n", "line 1: expected the header 'version name fps frames'"),
    ("2.1 test 25 2\n" + "0 0 1" + " 0" * 65 + "\n0 100\n", "the header says 2 frames, and the file ends after 1"),
    ("2.1 test 25 1\n" + ("0 0 1" + " 0" * 65 + "\n0 100\n") * 2, "line 4: more frames than the header's 1"),
    ("2.1 test 25 1\n" + "0 0 1" + " 0" * 64 + "\n0 100\n", "line 2: expected the mask of frame 0: 68 digits"),
    ("2.1 test 25 1\n" + "0 0 1 1" + " 0" * 64 + "\n0 100\n", "line 3: expected frame 0's number and 2 finite values"),
    ("", "an empty FAP file"),
])
def test_a_broken_fap_file_is_one_line_naming_where(tmp_path, text, message):
    (tmp_path / "bad.fap").write_text(text)
    (tmp_path / "spec.yaml").write_text("fap: bad.fap\n")
    with pytest.raises(InputError) as error:
        load_spec(tmp_path / "spec.yaml")
    assert message in str(error.value) and "bad.fap" in str(error.value) and "\n" not in str(error.value)


@pytest.mark.parametrize("fap, message", [
    ({69: 10}, "FAP 69 does not exist"),
    ({"open_mouth": 10}, "'open_mouth' is not an MPEG-4 FAP number"),
    ({3: "wide"}, "FAP 3: expected a value in FAP units"),
    ({3: [[5, 0], [2, 10]]}, "FAP 3: key frames must start at 0 or later and increase"),
    ({1: [1, 2, 99]}, "FAP 1: expected [viseme_select1, viseme_select2, viseme_blend]"),
])
def test_bad_inline_faps_are_one_line(tmp_path, fap, message):
    import yaml

    (tmp_path / "spec.yaml").write_text(yaml.safe_dump({"fap": fap}))
    with pytest.raises(InputError) as error:
        load_spec(tmp_path / "spec.yaml")
    assert message in str(error.value) and "fap" in str(error.value)


def test_docs_list_the_68_with_their_units():
    from pathlib import Path

    docs = (Path(__file__).parents[1] / "docs" / "mpeg4.md").read_text()
    for fap in fap_table().values():
        assert f"| {fap.number} | {fap.name} | {fap.unit} |" in docs, fap.number
