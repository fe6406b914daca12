"""Every shape a face rig has (issue 46): ARKit's 52 names and ICT's spellings in a spec's
``arkit:``, ``facesim shapes``, the jaw gliding forward and sideways as a rigid body, and
the lips sealed over an open jaw (ARKit's mouthClose)."""

import numpy as np
import pytest
from forked import facesim_process

import facesim
from facesim.animation.arkit import ARKIT_52, ICT_ALIASES, shape_facs
from facesim.animation.calibration import ICT_EXPRESSIONS
from facesim.animation.spec import Spec, activation_table
from facesim.errors import InputError


def table(model, **fields):
    return activation_table(Spec.model_validate(dict(name="shapes", frames=35, **fields)), model.muscles)


def test_the_vocabulary_is_arkits_52_and_icts_57():
    assert len(ARKIT_52) == len(set(ARKIT_52)) == 52
    assert {"eyeBlinkLeft", "mouthSmileRight", "jawForward", "cheekPuff", "tongueOut", "browInnerUp"} <= set(ARKIT_52)
    assert set(ICT_ALIASES) == set(ICT_EXPRESSIONS)  # every ICT spelling is a name here
    for name in ARKIT_52:  # each ARKit name is simulated or says what it needs
        assert shape_facs(name)
    assert shape_facs("mouthSmileLeft") == shape_facs("mouthSmile_L") == "AU12_L"  # the subject's left
    assert shape_facs("browInnerUp_L") == "AU1_L" and shape_facs("browInnerUp") == "AU1"
    assert shape_facs("jawLeft") == "AU30_L" and shape_facs("jawForward") == "AU29"


def test_arkit_weights_drive_what_their_facs_form_drives_without_cooccurrence(model):
    """mouthSmileLeft 0.7 is AU12_L at 0.7; a smile and a frown given as shapes both act
    (as FACS intensities, AU15 would weaken AU12: a capture's weights are what the face
    did); an ICT spelling is the same control as Apple's."""
    assert np.array_equal(table(model, arkit={"mouthSmileLeft": 0.7}), table(model, aus={"AU12_L": 0.7}))
    assert np.array_equal(table(model, arkit={"mouthSmile_L": 0.7}), table(model, arkit={"mouthSmileLeft": 0.7}))
    both = table(model, arkit={"mouthSmileLeft": 1.0, "mouthFrownLeft": 1.0})
    smile = model.muscles.index("zygomaticus_major_l")
    assert both[-1, smile] == pytest.approx(1.0)
    assert table(model, aus={"AU12_L": 1.0, "AU15_L": 1.0})[-1, smile] == pytest.approx(0.0)
    # mouthClose has no FACS unit: it drives the jaw rig's lip seal
    assert table(model, arkit={"mouthClose": 0.5})[-1, model.muscles.index("lip_seal")] == pytest.approx(0.5)


def test_arkit_timeline_tracks(model):
    track = {"target": "jawLeft", "keys": [[0, 0], [20, 1]]}
    keyed = table(model, timeline=[track])
    column = model.muscles.index("jaw_sideways_l")
    assert keyed[0, column] == 0 and keyed[-1, column] == pytest.approx(1.0)


@pytest.mark.parametrize("arkit, message", [
    ({"mouthSmileLeftt": 0.5}, "'mouthSmileLeftt' is not an ARKit or ICT FaceKit shape name"),
    ({"mouthSmileLeft": 1.5}, "less than or equal to 1"),
])
def test_a_bad_shape_is_one_line_naming_the_field(tmp_path, arkit, message):
    path = tmp_path / "bad.yaml"
    path.write_text(f"frames: 5\narkit: {arkit}\n")
    result = facesim_process(["validate", str(path)])
    assert result.returncode != 0 and "Traceback" not in result.stderr
    line = result.stderr.strip().splitlines()[-1]
    assert str(path) in line and "arkit" in line
    assert __import__("re").search(message, line), line


def test_facesim_shapes_lists_every_name_with_what_drives_it():
    result = facesim_process(["shapes"])
    assert result.returncode == 0, result.stderr
    out = result.stdout
    for name in ARKIT_52:
        assert name in out
    assert "zygomaticus_major_l" in out and "jaw_sideways_l" in out and "lip_seal" in out
    assert "not simulated yet" not in out and "tongue's rig" in out  # tongueOut drives tongue_out
    assert "AU30 (_L/_R)" in out and "AU29" in out
    assert "not on this face" not in out  # every control the default head has (lip_seal, pupil_dilate_l, ...)
    assert "PupilDilate_L" in out and "pupil's radius" in out


def test_a_pupil_dilates_on_its_own_side_and_the_npz_shows_it(tmp_path):
    """ICT's PupilDilate_R, the subject's right pupil alone (the renderer's control,
    ``pupil_dilate_r``): its iris slides outward in the head's NPZ, the other eye and the
    skin stay (tests/test_realism.py compares it with ICT's shape)."""
    from facesim.config import HEAD
    from facesim.face.head import load_head
    path = tmp_path / "pupil.yaml"
    path.write_text("frames: 8\nonset: 2\narkit: {PupilDilate_R: 0.6}\n")
    result = facesim_process(["render", str(path), "-o", str(tmp_path / "p.npz")])
    assert result.returncode == 0, result.stderr
    head = load_head(HEAD)
    with np.load(tmp_path / "p.npz") as data:
        moved = np.linalg.norm(data["positions"][-1] - data["rest"], axis=1)
        assert np.abs(data["skin_positions"][-1] - data["skin_rest"]).max() < 1e-6
    right, left = head.part("eyeball_right"), head.part("eyeball_left")
    assert moved[right].max() > 0.15 and moved[left].max() == 0.0


def held(aus=None, activations=None, frames=40):
    animation = facesim.simulate(Spec.model_validate(dict(name="held", frames=frames, onset=10, aus=aus or {},
                                                          activations=activations or {})))
    assert animation.inverted.max() == 0
    return animation


def teeth(animation, frame):
    """The lower incisors' midpoint (the foremost lower teeth within 5 mm of the midline)
    and the upper teeth's vertices, where the figure puts them at ``frame``."""
    figure = animation.figure
    x = figure.positions(animation.positions[frame], animation.jaw_at(frame))
    tooth = animation.model.mesh.head.part("teeth")
    lower = np.intersect1d(tooth, figure.jaw_rows)
    upper = np.setdiff1d(tooth, figure.jaw_rows)
    front = lower[(np.abs(figure.rest[lower, 0]) < 0.5)]
    front = front[figure.rest[front, 2] > np.percentile(figure.rest[front, 2], 80)]
    return x[front].mean(axis=0), x[upper]


def test_jaw_left_glides_the_lower_teeth_to_the_subjects_left_with_the_upper_still():
    """AU30_L (ARKit's jawLeft): the lower incisors' midpoint at least 0.5 cm toward +x
    (the subject's left), hardly up or down; the upper teeth do not move; the chin's skin
    goes with the jaw; and AU30_R is its mirror image."""
    left = held(aus={"AU30_L": 1.0})
    rest_mid, rest_upper = teeth(left, 0)
    mid, upper = teeth(left, left.frames - 1)
    assert mid[0] - rest_mid[0] >= 0.5 and abs(mid[1] - rest_mid[1]) < 0.1
    assert np.abs(upper - rest_upper).max() < 1e-9
    chin = 152  # MediaPipe's chin
    assert left.positions[-1, chin, 0] - left.rest[chin, 0] > 0.3
    right = held(aus={"AU30_R": 1.0})
    assert teeth(right, right.frames - 1)[0][0] - rest_mid[0] == pytest.approx(-(mid[0] - rest_mid[0]), abs=0.05)


def test_jaw_forward_glides_the_lower_teeth_forward():
    thrust = held(aus={"AU29": 1.0})
    before, after = teeth(thrust, 0)[0], teeth(thrust, thrust.frames - 1)[0]
    assert after[2] - before[2] >= 0.6 and abs(after[0] - before[0]) < 1e-6


def test_the_lips_seal_over_an_open_jaw():
    """jawOpen with mouthClose: the jaw (and the lower teeth) as open as with jawOpen
    alone, the inner lips' middles (MediaPipe 13 over 14) back within 1 mm of each other,
    where jawOpen alone parts them by over 2 cm; the chin's skin goes down with the jaw."""
    open_ = held(aus={"AU27": 1.0})
    sealed = held(aus={"AU27": 1.0}, activations={"lip_seal": 1.0})
    gap = [np.linalg.norm(a.positions[-1, 13] - a.positions[-1, 14]) for a in (open_, sealed)]
    rest_gap = np.linalg.norm(open_.rest[13] - open_.rest[14])
    assert gap[0] > 2.0 and gap[1] < rest_gap + 0.1
    assert teeth(sealed, sealed.frames - 1)[0] == pytest.approx(teeth(open_, open_.frames - 1)[0])
    chin = 152
    assert sealed.positions[-1, chin, 1] - sealed.rest[chin, 1] < -1.0


def test_a_spec_without_a_jaw_refuses_the_jaws_shapes(tmp_path):
    from facesim.config import HOPPER_MESH

    path = tmp_path / "nojaw.muscles.yaml"
    path.write_text("muscles:\n  - {name: zygomaticus_major_l, kind: linear, attachment: 411, insertion: 308}\n")
    s = Spec.model_validate(dict(name="x", frames=5, arkit={"jawLeft": 1.0}, mesh=str(HOPPER_MESH), muscles=str(path)))
    with pytest.raises(InputError, match="arkit -> jawLeft: AU30_L .jaw sideways. needs the jaw sideways"):
        facesim.simulate(s)


def test_a_cheek_puff_pushes_both_cheeks_out_with_the_lips_sealed():
    """AU34 (ARKit's cheekPuff): the air in the closed mouth (facesim.physics.pressure)
    moves the skin of each cheek beside the mouth (2-4 cm out from its centre, within 1.5
    cm of its height) at least 0.5 cm outward along the skin's normal, on average; the
    lips stay sealed (the inner lips' middles within 1 mm of their gap at rest); AU34_L
    puffs the left cheek and leaves the right within a fifth of that."""
    puffed = held(aus={"AU34": 1.0})
    model, x = puffed.model, puffed.rest
    mouth = x[[61, 291, 13, 14]].mean(axis=0)  # MediaPipe's mouth corners and inner lips
    normal = model.arrays.rest_vertex_normal
    beside = (np.abs(x[:, 1] - mouth[1]) < 1.5) & (np.abs(x[:, 0] - mouth[0]) > 2.0) & (np.abs(x[:, 0] - mouth[0]) < 4.0)

    def outward(animation, side):
        on_side = beside & (np.sign(x[:, 0] - mouth[0]) == side)
        return np.einsum("ij,ij->i", animation.positions[-1] - x, normal)[on_side].mean()

    assert outward(puffed, 1) >= 0.5 and outward(puffed, -1) >= 0.5
    gap = np.linalg.norm(puffed.positions[-1, 13] - puffed.positions[-1, 14])
    assert gap < np.linalg.norm(x[13] - x[14]) + 0.1, gap
    left = held(aus={"AU34_L": 1.0})
    assert outward(left, 1) >= 0.5 and abs(outward(left, -1)) < 0.2 * outward(left, 1)


def test_looking_down_turns_that_eye_and_its_lids_follow():
    """AU64_L (ARKit's eyeLookDownLeft): the subject's left eyeball turns down (its iris's
    front moves down at least 3 mm) and the right one does not; the left upper lid's
    middle (MediaPipe 386) comes down with it at least 3 mm, the lower lid (374) a little,
    staying under it; the right lids stay."""
    looked = held(aus={"AU64_L": 1.0})
    figure, head = looked.figure, looked.model.mesh.head
    last = looked.frames - 1
    moved = figure.positions(looked.positions[last], looked.jaw_at(last), tuple(looked.pose[last, 3:5]), looked.pose[last, 5:9])
    rest = figure.positions(looked.positions[0], looked.jaw_at(0))
    left, right = sorted((head.part("eyeball_left"), head.part("eyeball_right")), key=lambda rows: -figure.rest[rows, 0].mean())
    front = lambda rows: rows[figure.rest[rows, 2] > np.percentile(figure.rest[rows, 2], 90)]  # noqa: E731
    assert (moved - rest)[front(left), 1].mean() < -0.3
    assert np.abs(moved - rest)[right].max() < 1e-9
    x, x0 = looked.positions[-1], looked.rest
    assert x[386, 1] - x0[386, 1] < -0.3 and -0.3 < x[374, 1] - x0[374, 1] < 0
    assert x[386, 1] > x[374, 1]
    assert np.abs(x[159] - x0[159]).max() < 0.02 and np.abs(x[145] - x0[145]).max() < 0.02


@pytest.mark.parametrize("activations", [
    {"lip_seal": 1.0}, {"mouth_left": 1.0}, {"mouth_right": 1.0}, {"mouth_left": 1.0, "jaw": 1.0},
    {"mouth_right": 1.0, "jaw": 1.0}, {"lip_seal": 1.0, "jaw": 1.0}, {"mouth_left": 1.0, "mouth_right": 1.0},
    {"mouth_left": 1.0, "jaw_sideways_l": 1.0}, {"mouth_left": 1.0, "jaw_sideways_r": 1.0},
    {"mouth_left": 1.0, "lip_seal": 1.0}, {"mouth_left": 1.0, "cheek_puff_l": 1.0, "cheek_puff_r": 1.0, "lip_seal": 1.0},
    {"lip_roll_upper": 1.0}, {"lip_roll_lower": 1.0}, {"lip_roll_upper": 1.0, "jaw": 1.0},
    {"lip_roll_lower": 1.0, "jaw": 1.0}, {"lip_roll_upper": 1.0, "lip_seal": 1.0, "jaw": 1.0},
    {"lip_roll_lower": 1.0, "mouth_left": 1.0}, {"lip_roll_upper": 1.0, "mouth_right": 1.0},
], ids=lambda a: "+".join(a))
def test_the_shapes_facs_has_no_unit_for_hold_200_frames_without_folding(activations):
    """ARKit's mouthClose, mouthLeft, mouthRight and mouthRoll drive controls, not action
    units, so the fold sweep over the units (tests/test_folds.py; it has AU28, both lips
    rolled) does not reach them alone: each alone, with the jaw open, left with right, the
    lips to a side with the jaw to either side, sealed, puffed and rolled, held 200 frames, inverts no triangle and settles (kinetic energy
    at the end under 1e-6 of its peak)."""
    animation = facesim.simulate(Spec.model_validate(dict(name="held", frames=200, onset=10, activations=activations)))
    assert animation.inverted.max() == 0
    energy = animation.kinetic_energy
    assert energy[-1] <= 1e-6 * energy.max() or energy[-1] < 1e-6


def test_mouth_left_draws_the_lips_to_the_subjects_left():
    """mouthLeft: the lips' middles (MediaPipe 13, 14) slide at least 1 cm toward +x, the
    trailing (right) corner further than the leading one; mouthRight is its mirror."""
    left = held(activations={"mouth_left": 1.0})
    d = left.positions[-1] - left.rest
    assert d[13, 0] > 1.0 and d[14, 0] > 1.0
    assert d[61, 0] > d[291, 0] > 0
    right = held(activations={"mouth_right": 1.0})
    assert right.positions[-1, 13, 0] - right.rest[13, 0] == pytest.approx(-d[13, 0], abs=0.02)


def test_a_rolled_lip_tucks_in_behind_the_other():
    """mouthRollUpper: the upper lip's edge (MediaPipe 13) goes at least 7 mm back and its
    vermilion's top (0) down, the lower lip stays within 2 mm; mouthRollLower: the lower
    lip's edge (14) goes 7 mm back and its vermilion's bottom (17) up, past where the
    upper lip's edge stays (the lips' contact lets a rolled lip pass)."""
    upper = held(activations={"lip_roll_upper": 1.0})
    d = upper.positions[-1] - upper.rest
    assert d[13, 2] < -0.7 and d[0, 1] < -0.2 and np.linalg.norm(d[[14, 17]], axis=1).max() < 0.2
    lower = held(activations={"lip_roll_lower": 1.0})
    x, x0 = lower.positions[-1], lower.rest
    assert x[14, 2] - x0[14, 2] < -0.7 and x[17, 1] - x0[17, 1] > 0.3
    assert x[14, 2] < x[13, 2] - 0.5  # tucked behind the upper lip's edge
    assert np.linalg.norm(x[[0, 13]] - x0[[0, 13]], axis=1).max() < 0.2


def test_lips_part_with_the_jaw_still():
    """AU25 (FACS's lips part): the inner lips' middles (MediaPipe 13, 14) 3-8 mm apart,
    where they touch at rest; the jaw does not turn (its control stays 0, the lower
    teeth do not move) and the mouth's corners move under 1 mm."""
    parted = held(aus={"AU25": 1.0})
    x, x0 = parted.positions[-1], parted.rest
    assert 0.3 < np.linalg.norm(x[13] - x[14]) < 0.8 and np.linalg.norm(x0[13] - x0[14]) < 0.05
    assert not parted.jaw[:, 0].any()
    assert teeth(parted, parted.frames - 1)[0] == pytest.approx(teeth(parted, 0)[0])
    assert np.linalg.norm(x[[61, 291]] - x0[[61, 291]], axis=1).max() < 0.1
