"""Each FACS action unit, and each of ICT FaceKit's 57 shapes alone, against ICT's
light-stage shape for it (issues 16 and 46).

Every unit of ICT's FACS table that anatomy lets a face drive, and every ICT shape as the
control it stands for (a side alone: mouthSmile_L is AU12_L; the jaw's glides), is
simulated alone at full intensity on the default head and held, and its displacement at
the simulated vertices is carried over the head's face area as the head shows it
(facesim.animation.calibration.on_face) and compared there with ICT's own shape, vertex
for vertex, as REALISM.md does (``tests/data/ict_shapes.npz``, provenance in its README):
direction (cosine at least 0.8) and amplitude (norm ratio 0.75-1.33), no inverted
triangle. ``CALIBRATED`` lists the rows ``scripts/calibrate.py`` has brought within those
bounds; the others are expected to fail until they are (strict: a row that starts
passing fails here until it is listed), so the table below tracks REALISM.md. The left
and right of a pair are mirror images of each other within 1 mm.
"""

from pathlib import Path

import numpy as np
import pytest

import facesim
from facesim.animation.calibration import (
    AMPLITUDE,
    COSINE,
    FACE_AREA,
    ICT_EXPRESSIONS,
    ICT_ROWS,
    ICT_SHAPES,
    PROTOTYPES,
    against_prototype,
    apex_frame,
    compare,
    hold,
    hold_row,
    ict_fields,
    on_face,
    row_control,
)
from facesim.animation.simulate import model_for
from facesim.animation.spec import Spec, load_spec
from facesim.animation.timeline import ACTION_UNITS
from facesim.config import HEAD
from facesim.face.figure import figure_for
from facesim.face.head import load_head
from facesim.face.material import face_model

DATA = Path(__file__).parent / "data" / "ict_shapes.npz"
#: Rows within the bounds on the default head (REALISM.md).
CALIBRATED = {"AU1", "AU2", "AU4", "AU5", "AU6", "AU7", "AU9", "AU10", "AU11", "AU12", "AU14", "AU15", "AU16", "AU17", "AU18", "AU20", "AU22", "AU24", "AU26", "AU27", "AU45",
              "browDown_L", "browDown_R", "browOuterUp_L", "browOuterUp_R", "cheekRaiser_L", "cheekRaiser_R",
              "cheekSquint_L", "cheekSquint_R", "eyeBlink_L", "eyeBlink_R", "eyeSquint_L", "eyeSquint_R", "eyeWide_L",
              "eyeWide_R", "jawForward", "jawLeft", "jawOpen", "jawRight", "mouthDimple_L", "mouthDimple_R",
              "mouthFrown_L", "mouthFrown_R", "mouthFunnel", "mouthLowerDown_L", "mouthLowerDown_R", "mouthPress_L",
              "mouthPress_R", "mouthPucker", "mouthShrugLower", "mouthShrugUpper",
              "mouthStretch_L", "mouthStretch_R", "mouthUpperUp_L", "mouthUpperUp_R", "noseSneer_L", "noseSneer_R",
              "eyeLookUp_L", "eyeLookUp_R", "eyeLookDown_L", "eyeLookDown_R", "eyeLookIn_L", "eyeLookIn_R", "eyeLookOut_L",
              "eyeLookOut_R", "mouthLeft", "mouthRight", "mouthSmile_L",
              "mouthSmile_R", "mouthRollUpper", "mouthRollLower", "cheekPuff_L", "cheekPuff_R", "browInnerUp_L", "browInnerUp_R", "mouthClose"}
#: Gaze shapes are held to the lids' direction alone (issue 46): their amplitude over the
#: face area is the head's follow spreading a lid landmark's motion (at the landmarks,
#: looking up or down moves the lids 1.05-1.10 of ICT's), and ICT's eyeballs do not turn.
GAZE_ROWS = {r for r in ICT_EXPRESSIONS if r.startswith("eyeLook")}
#: ICT's shapes with nothing on the face area to compare: the pupils' dilation moves the eyeballs' irises alone.
OFF_FACE = {"PupilDilate_L", "PupilDilate_R"}


@pytest.fixture(scope="module")
def ict():
    return ict_fields(np.load(DATA))


@pytest.fixture(scope="module")
def head_model():
    return model_for(Spec.model_validate(dict(name="neutral", frames=1)))


def test_calibration_data_is_icts_shapes_on_the_default_heads_face(ict):
    data = np.load(DATA)
    assert list(data["expression_names"]) == list(ICT_EXPRESSIONS)
    assert np.array_equal(data["landmark_vertex"], load_head(HEAD).landmarks)
    # ICT's smile moves the lip corners about 1.5 cm, one side of it as far: the data is ICT's, in cm
    assert 1.3 < np.linalg.norm(ict["AU12"], axis=1).max() < 1.8
    assert 1.3 < np.linalg.norm(ict["mouthSmile_L"], axis=1).max() < 1.8
    assert np.array_equal(ict["AU12"], ict["mouthSmile_L"] + ict["mouthSmile_R"])


@pytest.fixture(scope="module")
def head_figure(head_model):
    return figure_for(head_model)


@pytest.mark.parametrize("row", [r for r in ICT_ROWS if r not in OFF_FACE])
def test_each_unit_and_shape_matches_icts_scanned_shape(row, ict, head_model, head_figure, request):
    if row not in CALIBRATED:
        request.applymarker(pytest.mark.xfail(strict=True, reason=f"{row} is outside the bounds still (REALISM.md)"))
    unit = row_control(row)
    assert unit.split("_")[0] in ACTION_UNITS or unit in head_model.muscles.names, f"{row} is not driven"
    held = hold_row(head_model, row, figure=head_figure)
    c = compare(on_face(head_figure, held.displacement), ict[row])
    assert c.cosine >= COSINE, f"{row} ({unit}): cosine {c.cosine:.2f} with ICT's shape"
    if row not in GAZE_ROWS:
        assert AMPLITUDE[0] <= c.amplitude <= AMPLITUDE[1], f"{row} ({unit}): amplitude {c.amplitude:.2f} of ICT's"
    assert held.inverted == 0, f"{row} ({unit}): {held.inverted} inverted triangles"


@pytest.mark.parametrize("side", ["L", "R"])
def test_a_pupil_dilates_as_icts_pupildilate(side, head_model, head_figure):
    """ICT's PupilDilate moves an eye's iris alone (nothing on the face area): the
    renderer's pupil control (``pupil_dilate_l``/``_r``) at 1, against ICT's shape over
    the irises' vertices it moves, within the bounds of every other row, the other eye still."""
    from facesim.animation.arkit import shape_facs
    data = np.load(DATA)
    rows, theirs = data["pupil_rows"], data["pupil_deltas"][0 if side == "L" else 1].astype(np.float64)
    control = shape_facs(f"PupilDilate_{side}")
    assert control in head_model.muscles.names
    still = head_figure.positions(head_model.rest_position)
    look = np.zeros(6)
    look[4 if side == "L" else 5] = 1.0
    ours = head_figure.positions(head_model.rest_position, look=look)[rows] - still[rows]
    c = compare(ours, theirs)
    assert c.cosine >= COSINE and AMPLITUDE[0] <= c.amplitude <= AMPLITUDE[1], f"cosine {c.cosine:.2f}, amplitude {c.amplitude:.2f}"
    other = np.linalg.norm(theirs, axis=1) < 1e-6  # ICT's other eye
    assert np.abs(ours[other]).max() == 0.0


PAIRS = [(r, r[:-2] + "_R") for r in ICT_EXPRESSIONS if r.endswith("_L") and r not in OFF_FACE] + [
    ("jawLeft", "jawRight"), ("mouthLeft", "mouthRight")]


@pytest.mark.parametrize("pair", PAIRS, ids="+".join)
def test_the_left_and_right_of_a_pair_are_mirror_images(pair, head_model, head_figure):
    """The left shape alone and the right one alone, reflected through the midline onto the
    left (the head's mirror map, x negated), within 1 mm of each other at every simulated
    vertex."""
    from facesim.physics.mesh import mirror_map

    try:
        left, right = (row_control(shape) for shape in pair)
    except ValueError as exc:
        pytest.xfail(str(exc))
    mirror = mirror_map(head_model.rest_position, head_model.faces)
    moved = {side: hold(head_model, unit, figure=head_figure).displacement for side, unit in (("L", left), ("R", right))}
    reflected = moved["R"][mirror] * np.array([-1.0, 1.0, 1.0])
    assert np.linalg.norm(moved["L"], axis=1).max() > 0.2  # it moves the face
    assert np.linalg.norm(moved["L"] - reflected, axis=1).max() < 0.1


def head_file_and_model_with(head_model, change):
    """The default head's muscle file (a dict) and a model of the head built with
    ``change`` (a function editing that dict in place) applied to a copy of it, with the
    head_model's material before resolution scales it."""
    import copy

    import yaml

    from facesim.config import HEAD_MUSCLES
    from facesim.face.muscle_file import MuscleFile, resolve_muscles
    raw = yaml.safe_load(HEAD_MUSCLES.read_text())
    changed = copy.deepcopy(raw)
    change(changed)
    material = Spec.model_validate(dict(name="neutral", frames=1)).material
    return raw, face_model(head_model.mesh, resolve_muscles(MuscleFile.model_validate(changed), head_model.mesh), material)


@pytest.mark.parametrize("au, muscle", [("AU18", "incisivus_labii"), ("AU14", "buccinator")])
def test_a_muscles_push_moves_the_skin_off_its_surface_as_far_as_icts(au, muscle, ict, head_model):
    """ICT's pucker (AU18) moves the lips about 1 cm forward, its dimpler (AU14) the lip
    corners half a centimetre back into the cheek. A muscle pulls in the plane of the
    muscles' projection (eq. 3.21), which the back-projection onto the curved face carries
    little off its surface; the muscle's protrusion (muscle_forces._muscle_forces) pushes along
    the skin's rest normal, outward for the incisivi's pout, inward for the buccinator
    pressing the cheek to the teeth. Measured at the 10 simulated vertices ICT moves most
    off the face (depth): the pucker 0.79 of ICT's depth against 0.36 without its push
    (cosine 0.90 against 0.83), the dimpler 0.92 against -0.28, forward instead of back
    (cosine 0.83 against 0.27)."""
    def unpushed(raw):
        for m in raw["muscles"]:
            if m["name"] in (muscle, f"{muscle}_l", f"{muscle}_r"):
                m["protrusion"] = 0.0

    _, flat = head_file_and_model_with(head_model, unpushed)
    theirs = ict[au][load_head(HEAD).landmarks, 2]
    deepest = np.argsort(np.abs(theirs))[-10:]
    figure = figure_for(head_model)
    depth, cosine = {}, {}
    for name, model in (("pushed", head_model), ("flat", flat)):
        held = hold(model, au, figure=figure)
        depth[name] = held.displacement[deepest, 2].mean() / theirs[deepest].mean()
        cosine[name] = compare(on_face(figure, held.displacement), ict[au]).cosine
    assert 0.75 < depth["pushed"] < 1.25 and depth["flat"] < 0.5
    assert cosine["pushed"] >= COSINE and cosine["pushed"] > cosine["flat"] + 0.05


def test_a_lower_lip_pushed_up_slides_forward_over_the_upper_one(head_model):
    """ICT's chin raiser (AU17) moves the inner lower lip 6.9 mm up and 5.5 mm forward
    and leaves the upper lip still: the lower lip slides up the upper one's front rather
    than lifting it. The lips' contact keeps each pair apart across a plane turned
    ``contact_tilt`` degrees (facesim.physics.rig): under AU17 the pair's relative motion lies in
    that plane, and the upper lip rises less than half as far as across a horizontal one,
    which the lower lip can only lift."""
    raw, flat = head_file_and_model_with(head_model, lambda raw: raw["jaw"].update(contact_tilt=0.0))
    assert raw["jaw"]["contact_tilt"] > 0
    tilt = np.radians(raw["jaw"]["contact_tilt"])
    upper, lower = 13, 14  # the inner lips' middle, a contact pair
    figure = figure_for(head_model)
    tilted, level = (hold(model, "AU17", figure=figure).displacement for model in (head_model, flat))
    relative = tilted[lower] - tilted[upper]
    slide = np.array([0.0, np.sin(tilt), np.cos(tilt)])  # up the plane, forward
    assert relative @ slide > 0.95 * np.linalg.norm(relative) and relative[1] > 0.5  # cm
    assert tilted[lower, 1] > 0.6 and tilted[lower, 2] > 0.3
    assert tilted[upper, 1] < 0.5 * level[upper, 1]


#: Ekman's six, each read at its apex as its FACS prototype (REALISM.md): ICT's shapes of
#: the prototype's units, their intensities fitted, at cosine at least this with the face,
#: with at least half of those units showing at SHOWS or more.
BASIC_SIX, PROTOTYPE_COSINE, SHOWS = ("happy", "sad", "angry", "fear", "disgust", "surprise"), 0.7, 0.2


@pytest.mark.parametrize("name", BASIC_SIX)
def test_each_basic_expression_at_its_apex_reads_as_its_facs_prototype(name, ict):
    """Issue 46.6: angry and fear were rebuilt on FACS's prototypes; each of the six is
    measured against its prototype composed from ICT's scanned shapes."""
    animation = facesim.simulate(load_spec(name))
    k = apex_frame(animation)
    moved = animation.figure.positions(animation.positions[k], animation.jaw_at(k))
    measured = against_prototype((moved - animation.figure.rest)[:FACE_AREA], ict, PROTOTYPES[name])
    weights = measured.weights
    assert measured.fitted.cosine >= PROTOTYPE_COSINE, f"{name}: cosine {measured.fitted.cosine:.2f} ({weights})"
    shown = [u for u in PROTOTYPES[name] if u in ICT_SHAPES]
    assert 2 * sum(weights[u] >= SHOWS for u in shown) >= len(shown), weights
