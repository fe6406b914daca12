"""facesim's outputs for the eight thesis expressions stay what they were when this test's
fingerprints were taken (tests/data/golden_outputs.json): the PNG frames byte-identical on
the backend named there, the NPZ's integer and text arrays exactly equal, and its
floating-point arrays equal to 1e-9 of their size.

Floating point is not compared bit for bit because the same code gives other last bits on
another CPU: OpenBLAS picks its kernels by the CPU it runs on, and they sum in another
order (the skin's rest positions moved 8e-15 cm with OPENBLAS_CORETYPE=Prescott; on an
AMD EPYC, every float array of the digests taken on the machine before differed, every
PNG was the same, 2026-12-06). A float array is held to its norm and eight projections
on fixed random directions: a change of any element by more than about 1e-9 of the
array's norm (2e-5 cm spread over the 35 frames of a head's positions) moves them,
where the CPUs' rounding moves them 1e-15.

The digests were written by the package before it was split into layers (issue 43), so
the move is shown to change no output. A change that is meant to move the face or its
pixels regenerates them, and says so in its commit:

    FACESIM_WRITE_GOLDEN=1 pytest tests/test_outputs_unchanged.py
"""

import hashlib
import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from conftest import EXPRESSIONS, THESIS_EXPRESSIONS

GOLDEN = Path(__file__).with_name("data") / "golden_outputs.json"
SIZE = "96x96"
BACKEND = "osmesa"


def _batch(outdir: Path, fmt: str) -> None:
    specs = [str(EXPRESSIONS / f"{name}.yaml") for name in THESIS_EXPRESSIONS]
    subprocess.run([sys.executable, "-m", "facesim", "batch", *specs, "-o", str(outdir), "--format", fmt,
                    "--size", SIZE, "--backend", BACKEND, "--jobs", "2"], check=True, capture_output=True)


#: Within this share of a float array's norm, its fingerprint is unchanged.
TOLERANCE = 1e-9
PROJECTIONS = 8


def _fingerprint(array: np.ndarray):
    """An integer or text array's digest; a float array's dtype and shape, norm and its
    projections on PROJECTIONS fixed random directions (seeded by its size)."""
    array = np.ascontiguousarray(array)
    if array.dtype.kind != "f":
        return hashlib.sha256(str(array.dtype).encode() + str(array.shape).encode() + array.tobytes()).hexdigest()
    values = array.astype(np.float64).ravel()
    directions = np.random.default_rng(values.size).standard_normal((PROJECTIONS, values.size))
    return {"dtype": str(array.dtype), "shape": list(array.shape), "norm": float(np.linalg.norm(values)),
            "projections": (directions @ values).tolist()}


def _same(golden, found) -> bool:
    if isinstance(golden, str) or isinstance(found, str):
        return golden == found
    if (golden["dtype"], golden["shape"]) != (found["dtype"], found["shape"]):
        return False
    scale = TOLERANCE * max(golden["norm"], 1e-300)
    return (abs(golden["norm"] - found["norm"]) <= scale
            and all(abs(a - b) <= scale for a, b in zip(golden["projections"], found["projections"])))


def _digests(outdir: Path) -> dict:
    found = {}
    for name in THESIS_EXPRESSIONS:
        with np.load(outdir / f"{name}.npz") as data:
            for key in sorted(data.files):
                found[f"{name}.npz:{key}"] = _fingerprint(data[key])
        for png in sorted((outdir / name).glob("*.png")):
            found[f"{name}/{png.name}"] = hashlib.sha256(png.read_bytes()).hexdigest()
    return found


@pytest.fixture(scope="module")
def outputs(tmp_path_factory):
    # Kernels compiled in this process and kernels loaded from Numba's cache differ in the
    # last bits (3.6e-15 cm on angry's positions, measured 2026-12-04): one render first
    # fills the cache where it lacks a kernel (the shipped ones stale, or turned off), so
    # the batch reads what every later run reads. (It was a whole first batch: 12 s more.)
    warm = tmp_path_factory.mktemp("warm")
    subprocess.run([sys.executable, "-m", "facesim", "render", str(EXPRESSIONS / "happy.yaml"), "-o", str(warm / "a.png"),
                    "--frame", "34", "--size", SIZE, "--backend", BACKEND], check=True, capture_output=True)
    outdir = tmp_path_factory.mktemp("golden")
    _batch(outdir, "npz")
    _batch(outdir, "png")
    return _digests(outdir)


@pytest.mark.heavy(45)
def test_the_thesis_expressions_render_as_before(outputs):
    if os.environ.get("FACESIM_WRITE_GOLDEN"):
        GOLDEN.write_text(json.dumps({"size": SIZE, "backend": BACKEND, "digests": outputs}, indent=1) + "\n")
    golden = json.loads(GOLDEN.read_text())
    assert (golden["size"], golden["backend"]) == (SIZE, BACKEND)
    assert outputs.keys() == golden["digests"].keys()
    changed = sorted(k for k, v in outputs.items() if not _same(golden["digests"][k], v))
    assert not changed, f"{len(changed)} of {len(outputs)} outputs changed, first {changed[:5]}"


def test_a_float_arrays_fingerprint_holds_rounding_and_catches_a_micrometre():
    """The comparison's own check: the last bits another CPU rounds differently leave a
    head's positions the same; one vertex moved a micrometre in one frame does not."""
    positions = np.random.default_rng(1).uniform(-10, 10, (35, 26719, 3)).astype(np.float32)
    golden = _fingerprint(positions)
    rounded = positions.astype(np.float64) * (1 + 1e-15)
    assert _same(golden, {**_fingerprint(rounded), "dtype": "float32"})
    moved = positions.copy()
    moved[20, 1234, 2] += 1e-4
    assert not _same(golden, _fingerprint(moved))
    assert not _same(golden, _fingerprint(positions[:, :, :2]))
