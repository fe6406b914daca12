"""A plain install works: the wheel carries the head, the Hopper face, their muscle files
and the expression library, and renders from any directory."""

import subprocess
import sys
import zipfile
from pathlib import Path

import imageio.v3 as iio
import numpy as np
import pytest

ROOT = Path(__file__).resolve().parent.parent


def run(*command, cwd=None):
    result = subprocess.run([str(c) for c in command], capture_output=True, text=True, cwd=cwd, timeout=900)
    assert result.returncode == 0, result.stderr[-3000:]
    return result


@pytest.mark.heavy(45)
def test_the_wheel_installs_into_a_fresh_environment_and_renders_from_another_directory(tmp_path):
    run(sys.executable, "-m", "pip", "wheel", "--no-deps", "-q", "-w", tmp_path / "dist", ROOT)
    wheel = next((tmp_path / "dist").glob("facesim-*.whl"))
    names = set(zipfile.ZipFile(wheel).namelist())
    for data in ("meshes/ict/head.npz", "meshes/ict/head.muscles.yaml", "meshes/ict/LICENSE", "meshes/face.obj",
                 "meshes/face.muscles.yaml", "meshes/NOTICE", "expressions/happy.yaml", "expressions/blends/happy_surprise.yaml",
                 "compiled/kernels.tar.xz", "compiled/kernels.json", "compiled/README.md"):
        assert f"facesim/{data}" in names, data

    venv = tmp_path / "venv"
    run(sys.executable, "-m", "venv", venv)
    # with its dependencies, from the registry as a user would; without compiling every
    # installed module's bytecode (pip's own step, half of the install: 24.9 -> 12.3 s),
    # which the renders below compile for what they import
    run(venv / "bin" / "pip", "install", "-q", "--no-compile", wheel)
    elsewhere = tmp_path / "elsewhere"
    elsewhere.mkdir()
    facesim = venv / "bin" / "facesim"
    run(facesim, "render", ROOT / "expressions" / "happy.yaml", "-o", "happy", "--size", "96x96", cwd=elsewhere)
    # a spec of the library by name: the installed copy of expressions/
    run(facesim, "render", "surprise", "-o", "surprise.npz", cwd=elsewhere)
    frames = sorted((elsewhere / "happy").glob("frame_*.png"))
    assert len(frames) == 35
    last = iio.imread(frames[-1]).astype(int)
    assert last.std() > 10  # a head, not an empty frame
    assert np.load(elsewhere / "surprise.npz")["positions"].shape[0] == 35
    # the installed package found its data inside itself, not in this checkout
    where = run(venv / "bin" / "python", "-c", "from facesim.config import HEAD, LIBRARY; print(HEAD); print(LIBRARY)",
                cwd=elsewhere).stdout.split()
    assert all(str(venv) in w for w in where), where
