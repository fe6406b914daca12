"""The default muscle file and the loader's checks."""

import numpy as np
import pytest
import yaml

from facesim.config import DEFAULT_MUSCLES
from facesim.errors import InputError
from facesim.muscles import load_muscles

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
    for k, name in enumerate(muscles.names):
        o, i = muscles.attachment[k], muscles.insertion[k]
        assert 0 <= o < 468 and 0 <= i < 468 and o != i
        if name.endswith("_l"):
            assert x[o] > 0 and x[i] > 0, name
        elif name.endswith("_r"):
            assert x[o] < 0 and x[i] < 0, name
        else:
            assert abs(x[o]) < 1e-6 and abs(x[i]) < 1e-6, name


def test_attachments_and_outer_rim_are_pinned_insertions_are_not(mesh, muscles):
    pinned = set(muscles.pinned.tolist())
    assert set(muscles.attachment.tolist()) <= pinned
    assert set(mesh.boundary_loops[0].tolist()) <= pinned
    assert not set(muscles.insertion.tolist()) & pinned


def write_muscles(tmp_path, change):
    data = yaml.safe_load(DEFAULT_MUSCLES.read_text())
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
        (lambda d: first(d).update(kind="sphincter"), r"muscles -> 0 -> kind: Input should be 'linear'"),
        (lambda d: d["muscles"].append(dict(first(d))), r"duplicate muscle name 'frontalis_medial_r'"),
        (lambda d: first(d).update(name="frontalis_medial_l"), r"duplicate muscle name 'frontalis_medial_l'"),
        (lambda d: d["muscles"][1].update(name="frontalis_medial_x_r"),
         r"muscle frontalis_medial_x_r: named for the right side but its points lie at x = 1\.\d+"),
        (lambda d: first(d).update(name="Frontalis"), r"muscles -> 0 -> name: Value error, must be snake_case"),
        (lambda d: first(d).update(falloff=[1.5, 1.0]), r"falloff: Value error, must be \[r, r_max\]"),
        (lambda d: first(d).update(attachment=[40.0, 0.0, 0.0]), r"muscle frontalis_medial_r: attachment: point \[40.0, 0.0, 0.0\] is \d+\.\d+ cm from the surface"),
    ],
)
def test_bad_muscle_files_give_one_line_naming_file_and_muscle(tmp_path, mesh, change, message):
    path = write_muscles(tmp_path, change)
    with pytest.raises(InputError, match=message) as info:
        load_muscles(path, mesh)
    text = str(info.value)
    assert text.startswith(str(path)) and "\n" not in text


def test_muscles_given_as_3d_points_snap_to_the_same_vertices(tmp_path, mesh, muscles):
    def as_points(data):
        for m in data["muscles"]:
            for key in ("attachment", "insertion"):
                m[key] = [float(c) + 0.05 for c in mesh.vertices[m[key]]]
    snapped = load_muscles(write_muscles(tmp_path, as_points), mesh)
    assert np.array_equal(snapped.attachment, muscles.attachment)
    assert np.array_equal(snapped.insertion, muscles.insertion)
