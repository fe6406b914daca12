"""Datasets: the same samples on any executor, resumable after a crash, clear errors."""

import hashlib
import os
import signal
import subprocess
import sys

import pytest

pytest.importorskip("dask.distributed")

import numpy as np  # noqa: E402
from conftest import wait_for  # noqa: E402
from forked import facesim_process  # noqa: E402

from facesim.dataset import POSE_JITTER, DatasetSettings, build_dataset, read_manifest, sample  # noqa: E402
from facesim.errors import InputError  # noqa: E402

SETTINGS = DatasetSettings(seed=7, width=64, height=64, jitter=True)


def rows(directory):
    return read_manifest(next(directory.glob("manifest.*")))


def check_complete(directory, n):
    manifest = rows(directory)
    assert [int(r["index"]) for r in manifest] == list(range(n))  # no duplicate, none missing
    for r in manifest:
        if r["status"] == "ok":
            assert hashlib.sha256((directory / r["image"]).read_bytes()).hexdigest() == r["sha256"]
    assert not list(directory.rglob(".*partial*"))
    return manifest


def test_the_draw_depends_on_seed_and_index_only():
    aus = ["AU1", "AU2", "AU12", "AU14", "AU15", "AU20"]
    assert sample(7, 3, aus) == sample(7, 3, aus)
    assert sample(7, 3, aus) != sample(8, 3, aus)
    draws = [sample(7, i, aus) for i in range(200)]
    assert 60 < sum(d["expression"] is not None for d in draws) < 140
    for name, limit in POSE_JITTER.items():  # head and gaze turned within their limits, both ways
        angles = np.array([d[name] for d in draws])
        assert np.abs(angles).max() <= limit and angles.min() < -limit / 2 and angles.max() > limit / 2


def test_every_renderer_of_a_head_draws_the_same_pixels():
    """A sample is the same bytes in any process. pyrender ordered a head's parts by their
    memory addresses, and the blended eyelashes showed it: this draw (seed 7, sample 9)
    came out one of two ways, a pixel apart, from renderer to renderer."""
    from facesim.animation.simulate import model_for, simulate
    from facesim.animation.spec import Spec
    from facesim.dataset import FRAMES, ONSET, available_action_units
    from facesim.renderer.scene import FaceRenderer
    from facesim.renderer.settings import RenderSettings

    draw = sample(7, 9, available_action_units(model_for(Spec(frames=FRAMES, onset=ONSET)).muscles.names))
    animation = simulate(Spec(frames=FRAMES, onset=ONSET, identity=draw["identity"], aus=draw["aus"]))
    renderers, images = [], set()
    for _ in range(8):  # kept alive, so that each one's meshes lie at new addresses
        renderer = FaceRenderer(animation.rest, animation.faces, RenderSettings(64, 64), "auto", animation.figure)
        renderer.view(draw["yaw"], draw["pitch"], draw["light"])
        renderers.append(renderer)
        images.add(renderer.frame(animation, FRAMES - 1, pose=tuple(draw[n] for n in POSE_JITTER)).tobytes())
    for renderer in renderers:
        renderer.close()
    assert len(images) == 1


def test_dask_local_cluster_gives_the_same_manifest_as_the_local_executor(tmp_path):
    """The same images by either executor; and Dask's LocalCluster, which sets the
    variables its workers start with (OMP_NUM_THREADS=1, MALLOC_TRIM_THRESHOLD_,
    PYTHONHASHSEED, ...) in the process that makes it, leaves the caller's environment as
    it was: every process the caller starts later would have run on one OpenMP thread."""
    local = build_dataset(tmp_path / "local", 6, SETTINGS, executor="local", jobs=1)
    before = dict(os.environ)
    dask = build_dataset(tmp_path / "dask", 6, SETTINGS, executor="dask", jobs=2)
    assert dict(os.environ) == before
    a, b = check_complete(local.parent, 6), check_complete(dask.parent, 6)
    assert [(r["id"], r["sha256"]) for r in a] == [(r["id"], r["sha256"]) for r in b]
    assert len({r["sha256"] for r in a}) == 6  # six different images
    assert {"expression", "aus", "activations", "yaw", "light", "head_yaw", "gaze_pitch", "sha256"} <= set(a[0])


def test_an_interrupted_run_completes_with_nothing_duplicated_or_missing(tmp_path):
    directory = tmp_path / "ds"
    command = [sys.executable, "-m", "facesim", "dataset", "--n", "10", "--seed", "7", "--size", "64x64", "--jitter",
               "-o", str(directory), "--jobs", "2"]
    process = subprocess.Popen(command, stderr=subprocess.DEVNULL, start_new_session=True)
    wait_for(lambda: len(list(directory.glob("labels/*.json"))) >= 3, what="three samples")
    import os

    os.killpg(process.pid, signal.SIGKILL)  # the whole run dies, workers included
    process.wait()
    finished = len(list(directory.glob("labels/*.json")))
    assert 3 <= finished < 10
    subprocess.run(command, check=True, capture_output=True)
    resumed = check_complete(directory, 10)
    fresh = build_dataset(tmp_path / "fresh", 10, SETTINGS, jobs=2)
    assert [r["sha256"] for r in resumed] == [r["sha256"] for r in rows(fresh.parent)]


def test_a_second_run_skips_finished_samples(tmp_path):
    build_dataset(tmp_path, 3, SETTINGS, jobs=1)
    stamps = {p: p.stat().st_mtime_ns for p in tmp_path.glob("images/*.png")}
    build_dataset(tmp_path, 4, SETTINGS, jobs=1)
    assert all(p.stat().st_mtime_ns == t for p, t in stamps.items())
    check_complete(tmp_path, 4)
    with pytest.raises(InputError, match="made with other settings"):
        build_dataset(tmp_path, 4, DatasetSettings(seed=8, width=64, height=64, jitter=True), jobs=1)


def test_clips_hold_every_frame_and_end_on_the_image(tmp_path):
    import imageio.v3 as iio
    import numpy as np
    from test_cli import mp4_frames

    build_dataset(tmp_path, 2, DatasetSettings(seed=7, width=64, height=64, clip=True), jobs=1)
    for r in check_complete(tmp_path, 2):
        frames = mp4_frames(tmp_path / r["clip"])
        assert frames.shape == (20, 64, 64, 3)
        assert np.abs(frames[-1].astype(int) - iio.imread(tmp_path / r["image"]).astype(int)).mean() < 3


@pytest.mark.parametrize("args, code, message", [
    (["--n", "0"], 2, "--n: the number of samples must be at least 1, got 0"),
    (["--n", "-3"], 2, "--n: the number of samples must be at least 1"),
    (["--n", "2", "--executor", "dask", "--scheduler", "tcp://127.0.0.1:9", "--scheduler-timeout", "1"], 1,
     "cannot reach the Dask scheduler"),
    (["--n", "2", "--executor", "dask", "--scheduler", "tcp://127.0.0.1:9", "--scheduler-timeout", "0"], 2,
     "--scheduler-timeout: expected a number of seconds above 0, got 0"),
    (["--n", "2", "--executor", "spark"], 2, "--executor: expected local or dask"),
])
def test_bad_arguments_are_one_line(tmp_path, args, code, message):
    """Bad arguments exit 2; a scheduler that cannot be reached is a failed run (exit 1)."""
    result = facesim_process(["dataset", "-o", str(tmp_path / "ds"), *args], timeout=120)
    assert result.returncode == code
    assert result.stderr.strip().splitlines() == [f"facesim: error: {result.stderr.strip().split('error: ', 1)[1]}"]
    assert message in result.stderr and not (tmp_path / "ds").exists()
