"""The default muscle file and the loader's checks."""

import numpy as np
import pytest
import yaml
from conftest import EXPRESSIONS

from facesim.config import DEFAULT_MUSCLES, HOPPER_MESH, HOPPER_MUSCLES
from facesim.errors import InputError
from facesim.face.loading import load_mesh
from facesim.face.muscle_file import load_muscles
from facesim.physics.muscles import LINEAR

THESIS_MUSCLES = [
    "frontalis_medial", "frontalis_lateral", "frontalis_outer", "corrugator_supercilii",
    "levator_labii_superioris", "levator_labii_superioris_alaeque_nasi", "zygomaticus_major",
    "levator_anguli_oris", "risorius", "depressor_anguli_oris", "depressor_labii_inferioris",
    "mentalis", "zygomaticus_minor",
]


def test_every_thesis_muscle_on_both_sides_and_procerus(muscles):
    names = set(muscles.names)
    for m in THESIS_MUSCLES:
        assert {f"{m}_l", f"{m}_r"} <= names
    assert "procerus" in names


def test_indices_valid_and_on_the_side_the_name_says(mesh, muscles):
    x = mesh.vertices[:, 0]
    for k, name in enumerate(muscles.names[:muscles.count]):
        if muscles.kind[k] == LINEAR:
            points = [muscles.attachment[k], muscles.insertion[k]]
            assert points[0] != points[1], name
            sides = x[points]
        else:  # a sphincter: the side of its centre
            points = list(muscles.centre_index[muscles.centre_start[k]:muscles.centre_start[k + 1]]) + list(muscles.ring[k])
            sides = [x[muscles.centre_index[muscles.centre_start[k]:muscles.centre_start[k + 1]]].mean()]
        assert all(0 <= p < 468 for p in points), name
        if name.endswith("_l"):
            assert min(sides) > 0, name
        elif name.endswith("_r"):
            assert max(sides) < 0, name
        else:
            assert max(abs(s) for s in sides) < 1e-6, name
    assert muscles.controls == ("jaw", "jaw_thrust", "jaw_sideways_l", "jaw_sideways_r", "lip_seal", "cheek_puff_l", "cheek_puff_r",
                                "mouth_left", "mouth_right", "lip_roll_upper", "lip_roll_lower", "tongue_out", "tongue_up",
                                "eyelid_r", "levator_palpebrae_r", "gaze_up_r", "gaze_down_r", "gaze_left_r", "gaze_right_r",
                                "pupil_dilate_r", "eyelid_l", "levator_palpebrae_l", "gaze_up_l", "gaze_down_l", "gaze_left_l",
                                "gaze_right_l", "pupil_dilate_l")


def test_the_rim_is_tied_attachments_as_the_file_says_insertions_never(mesh, muscles):
    """The default head's file ties its rim to the skull (the skin beyond the cut) and
    leaves its attachments free (its hypodermis holds the skin); the thesis's face pins
    both (test below and the next)."""
    pinned = set(muscles.pinned.tolist())
    attachments = set(muscles.attachment[muscles.kind == LINEAR].tolist())
    assert set(muscles.tied.tolist()) == set(mesh.boundary_loops[0].tolist()) and muscles.tie > 0
    assert not set(muscles.tied.tolist()) & pinned
    assert (attachments <= pinned) == yaml.safe_load(DEFAULT_MUSCLES.read_text()).get("pinned", {}).get("attachments", True)
    assert not set(muscles.insertion.tolist()) & pinned


def test_the_thesis_faces_rim_is_pinned():
    mesh = load_mesh(HOPPER_MESH)
    hopper = load_muscles(HOPPER_MUSCLES, mesh)
    assert set(mesh.boundary_loops[0].tolist()) <= set(hopper.pinned.tolist()) and len(hopper.tied) == 0


def write_muscles(tmp_path, change, source=HOPPER_MUSCLES):
    data = yaml.safe_load(source.read_text())
    change(data)
    path = tmp_path / "bad.muscles.yaml"
    path.write_text(yaml.safe_dump(data))
    return path


def first(data):
    return data["muscles"][0]


@pytest.mark.parametrize(
    "change, message",
    [
        (lambda d: first(d).update(insertion=999), r"muscle frontalis_medial_r: insertion: vertex 999 does not exist"),
        (lambda d: first(d).update(insertion=first(d)["attachment"]), r"muscle frontalis_medial_r: zero length"),
        (lambda d: first(d).update(kind="spiral"), r"muscles -> 0: Input tag 'spiral' found using 'kind' does not match"),
        (lambda d: first(d).update(kind="sphincter"), r"muscles -> 0 -> sphincter -> centre: Field required"),
        (lambda d: d["muscles"].append(dict(first(d))), r"duplicate name 'frontalis_medial_r'"),
        (lambda d: first(d).update(name="frontalis_medial_l"), r"duplicate name 'frontalis_medial_l'"),
        (lambda d: first(d).update(name="jaw"), r"duplicate name 'jaw'"),
        (lambda d: d["muscles"][1].update(name="frontalis_medial_x_r"),
         r"muscle frontalis_medial_x_r: named for the right side but its points lie at x = 1\.\d+"),
        (lambda d: first(d).update(name="Frontalis"), r"muscles -> 0 -> linear -> name: Value error, must be snake_case"),
        (lambda d: first(d).update(falloff=[1.5, 1.0]), r"falloff: Value error, must be \[r, r_max\]"),
        (lambda d: first(d).update(attachment=[40.0, 0.0, 0.0]), r"muscle frontalis_medial_r: attachment: point \[40.0, 0.0, 0.0\] is \d+\.\d+ cm from the surface"),
        (lambda d: d["pinned"].update(boundary="tied"), r"pinned: Value error, tie: expected a positive stiffness with boundary: tied"),
        (lambda d: d["pinned"].update(tie=500), r"pinned: Value error, tie: expected a positive stiffness .* got tie 500 with boundary outer"),
        (lambda d: d["pinned"].update(boundary="tied", tie=-1), r"pinned -> tie: Input should be greater than or equal to 0"),
        (lambda d: first(d).update(protrusion=25), r"muscles -> 0 -> linear -> protrusion: Input should be less than or equal to 20"),
        (lambda d: next(m for m in d["muscles"] if m["name"] == "incisivus_labii").update(protrusion=-25),
         r"sphincter -> protrusion: Input should be greater than or equal to -20"),
    ],
)
def test_bad_muscle_files_give_one_line_naming_file_and_muscle(tmp_path, mesh, change, message):
    path = write_muscles(tmp_path, change)
    with pytest.raises(InputError, match=message) as info:
        load_muscles(path, mesh)
    text = str(info.value)
    assert text.startswith(str(path)) and "\n" not in text


def test_an_insertion_on_the_pinned_rim_is_refused(tmp_path, mesh):
    """A muscle inserted where the skin is pinned would pull nothing there: one line, not
    a muscle that silently does nothing at its centre."""
    rim = mesh.boundary_loops[0]
    right = rim[mesh.vertices[rim, 0] < -1.0][0]
    path = write_muscles(tmp_path, lambda d: first(d).update(insertion=int(right)))
    with pytest.raises(InputError, match=rf"muscle frontalis_medial_r: insertion: vertex {right} is pinned"):
        load_muscles(path, mesh)


def test_muscles_given_as_3d_points_snap_to_the_same_vertices(tmp_path, mesh, muscles):
    def point(index):
        return [float(c) + 0.005 for c in mesh.vertices[index]]  # the lips are 0.03 cm apart

    def as_points(data):
        for m in data["muscles"]:
            for key in ("attachment", "insertion"):
                if key in m:
                    m[key] = point(m[key])
            for key in ("centre", "ring"):
                if key in m:
                    m[key] = [point(i) for i in m[key]]
        for part in [data["jaw"]] + data["eyelids"]:
            for key in ("lower", "upper"):
                part[key] = [point(i) for i in part[key]]
    snapped = load_muscles(write_muscles(tmp_path, as_points, DEFAULT_MUSCLES), mesh)
    for key in ("attachment", "insertion", "centre_index", "pinned"):
        assert np.array_equal(getattr(snapped, key), getattr(muscles, key)), key
    assert all(np.array_equal(a, b) for a, b in zip(snapped.ring, muscles.ring))
    assert np.array_equal(snapped.jaw.lower, muscles.jaw.lower) and np.array_equal(snapped.eyelids[1].upper, muscles.eyelids[1].upper)


def test_a_head_held_by_its_hypodermis_leaves_its_attachments_free(tmp_path, mesh):
    pinned = load_muscles(write_muscles(tmp_path, lambda d: d["pinned"].update(attachments=False)), mesh).pinned
    assert set(pinned.tolist()) == set(mesh.boundary_loops[0].tolist())


def test_a_muscle_file_brings_the_material_its_forces_were_set_on_and_a_spec_wins(tmp_path):
    """The Hopper face's file was tuned on the thesis's skin (no bending, regions at the
    moving skin): a spec without a material gets that skin, a spec's own fields win, and a
    bad field in the file is one line naming the file."""
    import facesim
    from facesim.animation.simulate import model_for
    from facesim.config import HOPPER_MESH
    from facesim.face.material import MaterialSpec
    spec = facesim.load_spec(EXPRESSIONS / "happy.yaml").with_overrides(mesh=HOPPER_MESH, muscles="thesis")
    model = model_for(spec)
    assert (model.material.bending, model.material.regions) == (0.0, "moving")
    mine = model_for(spec.with_overrides(material=MaterialSpec(bending=20.0)))
    assert (mine.material.bending, mine.material.regions) == (20.0, "moving")
    head = model_for(facesim.load_spec(EXPRESSIONS / "happy.yaml"))
    assert (head.material.bending, head.material.regions) == (MaterialSpec().bending, "attached")
    path = write_muscles(tmp_path, lambda d: d.update(material={"bending": -1}))
    with pytest.raises(InputError, match=r"bad.muscles.yaml: material -> bending: Input should be greater than or equal to 0"):
        load_muscles(path, load_mesh(HOPPER_MESH))
