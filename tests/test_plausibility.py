"""Random out-of-range and non-finite values in every numeric field of a muscle file and
of a spec (a seeded loop; the face directory's face.yaml is in tests/test_face_from_photo.py):
each case is refused with one line (an InputError, exit 2), fails loudly with its frame
(a SimulationError, exit 1), or runs to a face that visibly moves. Never a quiet run of a
face that does not move, never a traceback. A few cases go through the command line too,
where nothing may be left on disk."""

import random

import numpy as np
import pytest
import yaml
from forked import facesim_process

from facesim.animation.simulate import STILL, simulate
from facesim.animation.spec import load_spec
from facesim.config import HOPPER_MESH, HOPPER_MUSCLES
from facesim.errors import InputError, SimulationError

BAD = [float("nan"), float("inf"), -float("inf"), 1e300, -1e300, 1e150, 1e9, 1e5, -5.0, 0.0, 1e-300, -1e-300, 3.7]
CASES = 40
SPEC = {
    "frames": 8, "dt": 0.01, "onset": 3, "fps": 25,
    "activations": {"zygomaticus_major_l": 1.0, "zygomaticus_major_r": 0.8},
    "aus": {"AU2": 0.6}, "expressions": {"joy": 0.3},
    "timeline": [{"target": "AU4", "keys": [[0, 0.0], [6, 0.7]], "interpolation": "cardinal", "tension": 0.3}],
    "pose": [{"target": "head_yaw", "keys": [[0, 0.0], [6, 10.0]]}],
    "material": {"damping": 40, "stiffness": 1000, "tissue": 300, "mass": 1.0, "drive": 20000, "nonlinearity": 5,
                 "repulsion_nonlinearity": 5, "bending": 100, "iterations": 60, "tolerance": 1e-3},
    "identity": [0.5, -0.3, 1.2],
}


def numeric_leaves(data, path=()):
    """The path of every number in a YAML document (booleans are no numbers)."""
    if isinstance(data, dict):
        for key, value in data.items():
            yield from numeric_leaves(value, path + (key,))
    elif isinstance(data, list):
        for k, value in enumerate(data):
            yield from numeric_leaves(value, path + (k,))
    elif isinstance(data, (int, float)) and not isinstance(data, bool):
        yield path


def with_value(data, path, value):
    changed = yaml.safe_load(yaml.safe_dump(data))
    node = changed
    for key in path[:-1]:
        node = node[key]
    node[path[-1]] = value
    return changed


def outcome(spec_path) -> str:
    """refused, failed (with its frame) or moved; anything else fails the test."""
    try:
        animation = simulate(load_spec(spec_path))
    except InputError as error:
        assert "\n" not in str(error) and str(error), repr(error)
        return "refused"
    except SimulationError as error:
        assert "\n" not in str(error) and error.frame is not None, repr(error)
        return "failed"
    moved = float(np.abs(animation.positions - animation.rest).max())
    assert moved > STILL, f"a quiet run that moved {moved} cm"
    assert np.isfinite(animation.positions).all()
    return "moved"


def cases(document, seed):
    """``CASES`` (path, value) pairs: a part of the document (its top-level field) drawn
    evenly, then a number of it, then a bad value."""
    rng = random.Random(seed)
    parts = {}
    for path in numeric_leaves(document):
        parts.setdefault(path[0], []).append(path)
    groups = sorted(parts)
    return [(rng.choice(parts[rng.choice(groups)]), rng.choice(BAD)) for _ in range(CASES)]


MUSCLES = yaml.safe_load(HOPPER_MUSCLES.read_text())


@pytest.mark.parametrize("path, value", cases(MUSCLES, seed=44))
def test_a_muscle_files_number_is_refused_fails_loudly_or_moves_the_face(tmp_path, path, value):
    muscles = tmp_path / "m.muscles.yaml"
    muscles.write_text(yaml.safe_dump(with_value(MUSCLES, path, value)))
    spec = tmp_path / "spec.yaml"
    spec.write_text(yaml.safe_dump(dict(SPEC, identity=None, mesh=str(HOPPER_MESH), muscles=str(muscles))))
    outcome(spec)


@pytest.mark.parametrize("path, value", cases(SPEC, seed=45))
def test_a_specs_number_is_refused_fails_loudly_or_moves_the_face(tmp_path, path, value):
    spec = tmp_path / "spec.yaml"
    spec.write_text(yaml.safe_dump(with_value(SPEC, path, value)))
    outcome(spec)


def test_the_loop_reaches_every_part_of_the_files():
    """The cases reach the numbers of each part of a spec and of a muscle file."""
    touched = {path[0] for path, _ in cases(SPEC, seed=45)} | {path[0] for path, _ in cases(MUSCLES, seed=44)}
    assert {"material", "timeline", "activations", "pose", "identity", "dt", "muscles", "defaults", "eyelids"} <= touched


@pytest.mark.parametrize("path, value", cases(MUSCLES, seed=46)[:3] + cases(SPEC, seed=47)[:3])
def test_through_the_command_line_one_line_and_nothing_written(tmp_path, path, value):
    muscles = tmp_path / "m.muscles.yaml"
    muscles.write_text(yaml.safe_dump(with_value(MUSCLES, path, value) if path[0] in MUSCLES else MUSCLES))
    document = with_value(SPEC, path, value) if path[0] in SPEC else dict(SPEC)
    document.update(identity=None, mesh=str(HOPPER_MESH), muscles=str(muscles))
    spec = tmp_path / "spec.yaml"
    spec.write_text(yaml.safe_dump(document))
    out = tmp_path / "out.npz"
    result = facesim_process(["render", str(spec), "-o", str(out)], timeout=300)
    assert "Traceback" not in result.stderr
    if result.returncode == 0:
        with np.load(out) as data:
            assert np.abs(data["positions"] - data["positions"][0]).max() > STILL
    else:
        assert result.returncode in (1, 2) and len(result.stderr.strip().splitlines()) == 1, result.stderr
        assert sorted(p.name for p in tmp_path.iterdir()) == ["m.muscles.yaml", "spec.yaml"]
