"""The command line, as a user meets it: every command and option, every bad input, and
the batch of the eight thesis expressions. Commands run in fresh processes, as users run
them (a process keeps the first OpenGL platform it loads), forked from one that has
imported facesim and nothing of OpenGL (tests/forked.py)."""

import signal
import subprocess
import sys

import imageio.v3 as iio
import numpy as np
import pytest
import yaml
from conftest import EXPRESSIONS, THESIS_EXPRESSIONS, cpu_seconds, wait_for
from forked import facesim_process

import facesim as facesim_api

SMALL = ["--size", "160x160"]


def facesim(*args, cwd=None, check=None, env=None):
    """`python -m facesim *args` in a process of its own (forked: tests/forked.py)."""
    result = facesim_process(list(map(str, args)), cwd=cwd, env=env, timeout=600)
    if check is not None:
        assert result.returncode == check, result.stderr
    return result


def one_line_error(result, code, *fragments):
    assert result.returncode == code, (result.returncode, result.stderr)
    lines = result.stderr.strip().splitlines()
    assert len(lines) == 1, result.stderr
    assert "Traceback" not in result.stderr
    assert lines[0].startswith("facesim: error: ")
    for fragment in fragments:
        assert fragment in lines[0], lines[0]


def mp4_frames(path):
    """Decode an MP4 with ffmpeg (imageio-ffmpeg) into (frames, height, width, 3)."""
    import imageio_ffmpeg

    reader = imageio_ffmpeg.read_frames(str(path))
    meta = next(reader)
    width, height = meta["size"]
    return np.stack([np.frombuffer(f, dtype=np.uint8).reshape(height, width, 3) for f in reader])


def write_spec(tmp_path, name="spec", **fields):
    data = {"frames": 12, "dt": 0.01, "onset": 4, "activations": {
        f"{muscle}_{side}": 1.0 for muscle in ("zygomaticus_major", "levator_anguli_oris", "frontalis_lateral") for side in "lr"}}
    data.update(fields)
    path = tmp_path / f"{name}.yaml"
    path.write_text(yaml.safe_dump(data))
    return path


def assert_animated(frames):
    assert all(f.std() > 5 for f in frames), "a blank frame"
    change = np.abs(frames[-1].astype(int) - frames[0].astype(int)).max(axis=-1)
    assert (change > 6).sum() >= 10, "the face does not move"


def test_render_default_output_is_out_name_mp4(tmp_path):
    spec = write_spec(tmp_path, "smile")
    result = facesim("render", spec, *SMALL, cwd=tmp_path, check=0)
    frames = mp4_frames(tmp_path / "out" / "smile.mp4")
    assert frames.shape == (12, 160, 160, 3)
    assert_animated(frames)
    # not a terminal: no progress bar, one closing line
    assert result.stderr.strip().count("\n") == 0 and "wrote" in result.stderr


def test_render_with_each_backend_gives_the_same_picture(tmp_path):
    spec = write_spec(tmp_path)
    last = {}
    for backend in ("osmesa", "egl"):
        facesim("render", spec, "-o", tmp_path / backend, "--backend", backend, *SMALL, check=0)
        files = sorted((tmp_path / backend).glob("frame_*.png"))
        assert [f.name for f in files[:2]] == ["frame_0000.png", "frame_0001.png"] and len(files) == 12
        frames = np.stack([iio.imread(f) for f in files])
        assert_animated(frames)
        last[backend] = frames[-1].astype(int)
    assert np.abs(last["osmesa"] - last["egl"]).mean() < 2


def test_gif_npz_fps_size_and_cameras(tmp_path):
    spec = write_spec(tmp_path)
    facesim("render", spec, "-o", tmp_path / "a.gif", "--size", "80x64", "--fps", "10", check=0)
    gif = iio.imread(tmp_path / "a.gif", index=None)
    assert gif.shape[:3] == (12, 64, 80)
    assert iio.immeta(tmp_path / "a.gif", index=0)["duration"] == 100
    facesim("render", spec, "-o", tmp_path / "a.npz", check=0)
    data = np.load(tmp_path / "a.npz")
    assert data["positions"].shape == (12, 26719, 3) and data["faces"].shape == (52220, 3)  # the head, whole
    assert data["skin_positions"].shape == (12, 468, 3) and data["skin_faces"].shape == (852, 3)
    assert list(data["muscles"]).count("zygomaticus_major_l") == 1
    views = {}
    for camera in ("front", "three-quarter", "profile"):
        facesim("render", spec, "-o", tmp_path / camera, "--camera", camera, *SMALL, check=0)
        views[camera] = iio.imread(tmp_path / camera / "frame_0000.png").astype(int)
    assert np.abs(views["front"] - views["profile"]).mean() > 5
    assert np.abs(views["front"] - views["three-quarter"]).mean() > 3
    # the front view is symmetric, the profile is not
    assert np.abs(views["front"] - views["front"][:, ::-1]).mean() < np.abs(views["profile"] - views["profile"][:, ::-1]).mean()


def test_a_still_face_writes_a_gif_of_every_frame(tmp_path):
    """Pillow stores a run of identical frames as one longer frame: a face at rest is a
    GIF of one frame that lasts the whole animation, and it is not refused as short."""
    spec = tmp_path / "still.yaml"
    spec.write_text("name: still\nframes: 9\nactivations: {}\n")
    facesim("render", spec, "-o", tmp_path / "still.gif", "--size", "48x48", "--fps", "30", check=0)
    durations = [iio.immeta(tmp_path / "still.gif", index=k)["duration"]
                 for k in range(len(iio.imread(tmp_path / "still.gif", index=None)))]
    assert abs(sum(durations) - 9 * 1000 / 30) <= 10 * len(durations)  # GIF keeps centiseconds


def test_wireframe_show_muscles_and_parallel_frames(tmp_path):
    spec = write_spec(tmp_path)
    plain = tmp_path / "plain"
    facesim("render", spec, "-o", plain, *SMALL, check=0)
    facesim("render", spec, "-o", tmp_path / "wire", "--wireframe", *SMALL, check=0)
    facesim("render", spec, "-o", tmp_path / "arrows", "--show-muscles", *SMALL, check=0)
    facesim("render", spec, "-o", tmp_path / "jobs", "--jobs", "2", *SMALL, check=0)
    facesim("render", spec, "-o", tmp_path / "aliased", "--no-antialias", *SMALL, check=0)
    last = {name: iio.imread(tmp_path / name / "frame_0011.png").astype(int)
            for name in ("plain", "wire", "arrows", "jobs", "aliased")}
    assert 0 < np.abs(last["aliased"] - last["plain"]).mean() < 2
    assert np.abs(last["wire"] - last["plain"]).mean() > 2
    red = (last["arrows"][..., 0] > 150) & (last["arrows"][..., 1] < 80)
    assert red.sum() > 5 and ((last["plain"][..., 0] > 150) & (last["plain"][..., 1] < 80)).sum() == 0
    assert np.array_equal(last["jobs"], last["plain"])  # same frames from two processes


def test_the_heads_npz_holds_every_vertex_of_the_head_as_rendered(tmp_path):
    """Issue 46: `-o x.npz` on the head writes all of ICT's 26,719 vertices per frame in
    ICT's order (its triangles index them), with the jaw, the eyes and the head's pose
    applied, and the simulated skin apart; a face mask keeps its own vertices."""
    from facesim.config import HEAD, HOPPER_MESH
    from facesim.face.head import load_head
    head = load_head(HEAD)
    pose = [{"target": "head_yaw", "keys": [[0, 0], [11, 30]]}, {"target": "gaze_yaw", "keys": [[0, 0], [11, 20]]}]
    spec = write_spec(tmp_path, aus={"AU26": 1.0}, pose=pose)
    facesim("render", spec, "-o", tmp_path / "head.npz", check=0)
    data = np.load(tmp_path / "head.npz")
    x, skin = data["positions"], data["skin_positions"]
    assert x.shape == (12, 26719, 3) and x.dtype == np.float32 and np.isfinite(x).all()
    assert np.array_equal(data["faces"], head.triangles) and np.allclose(data["rest"], head.vertices)
    neck = head.part("head_neck")
    assert np.abs(x[0, neck] - head.vertices[neck]).max() < 1e-4  # frame 0: unturned; the skull and neck still
    # the last frame turned back by the head's yaw about the neck is the unturned head:
    # the skin's landmarks on it moved as the simulated skin did (within 1 mm) ...
    from facesim.face.figure import HEAD_NECK
    from facesim.geometry import rotation
    unturned = (x[-1] - HEAD_NECK) @ rotation(30.0) + HEAD_NECK
    moved = unturned[data["skin_on_head"]] - data["rest"][data["skin_on_head"]]
    lids = np.isin(np.arange(468), [159, 145, 386, 374, 158, 153, 385, 380])  # the lids travel the head's own gap
    assert np.abs(moved - (skin[-1] - data["skin_rest"]))[~lids].max() < 0.1
    # ... the lower teeth dropped with the jaw, the upper ones did not move ...
    teeth = head.part("teeth")
    drop = unturned[teeth, 1] - data["rest"][teeth, 1]
    assert drop.min() < -0.5 and np.abs(drop).max() - np.abs(drop.min()) < 1e-6 and (np.abs(drop) < 1e-3).sum() > 100
    # ... and the eyes turned 20 degrees further than the head: the cornea's apex moved
    # toward the subject's left (+x), as gaze_yaw turns it, by about sin 20° of the eye's radius
    for side in ("left", "right"):
        ball = head.part(f"eyeball_{side}")
        apex = ball[np.argmax(data["rest"][ball, 2])]
        assert 0.3 < unturned[apex, 0] - data["rest"][apex, 0] < 0.6
    mask = write_spec(tmp_path, "mask", mesh=str(HOPPER_MESH))
    facesim("render", mask, "-o", tmp_path / "mask.npz", check=0)
    with np.load(tmp_path / "mask.npz") as data:
        assert data["positions"].shape == (12, 468, 3) and "skin_positions" not in data.files


def test_render_a_blend_without_a_spec_file(tmp_path):
    facesim("render", "--blend", "happy=0.6,surprise=0.4", "-o", tmp_path / "b.npz", check=0)
    data = np.load(tmp_path / "b.npz")
    muscles = list(data["muscles"])
    last = data["activations"][-1]
    assert last[muscles.index("zygomaticus_major_l")] == pytest.approx(0.6)
    assert last[muscles.index("frontalis_outer_r")] == pytest.approx(0.4)
    one_line_error(facesim("render", "--blend", "happy=2", "-o", tmp_path / "c.npz"), 2, "--blend")
    one_line_error(facesim("render", "--blend", "grin=0.5", "-o", tmp_path / "c.npz"), 2, "'grin'")
    one_line_error(facesim("render", "-o", tmp_path / "c.npz"), 2, "give a SPEC file, --blend, or both")


def test_existing_output_needs_force(tmp_path):
    spec = write_spec(tmp_path)
    out = tmp_path / "x.npz"
    facesim("render", spec, "-o", out, check=0)
    one_line_error(facesim("render", spec, "-o", out), 2, "already exists", "--force")
    facesim("render", spec, "-o", out, "--force", check=0)


def test_batch_of_the_eight_expressions(tmp_path):
    specs = [EXPRESSIONS / f"{name}.yaml" for name in THESIS_EXPRESSIONS]
    result = facesim("batch", *specs, "-o", tmp_path, "--size", "128x128", "--jobs", "2", check=0)
    for name in THESIS_EXPRESSIONS:
        frames = mp4_frames(tmp_path / f"{name}.mp4")
        assert frames.shape == (35, 128, 128, 3), name
        assert_animated(frames)
        assert name in result.stdout
    for column in ("spec", "muscles", "frames", "simulation", "render", "fps"):
        assert column in result.stdout


def test_batch_finishes_the_good_specs_when_one_fails(tmp_path):
    good = write_spec(tmp_path, "good")
    bad = write_spec(tmp_path, "bad", activations={"no_such_muscle": 0.5})
    out = tmp_path / "out"
    result = facesim("batch", good, bad, "-o", out, "--format", "npz", "--jobs", "2")
    assert result.returncode == 1
    assert (out / "good.npz").exists() and not (out / "bad.npz").exists()
    assert "no_such_muscle: unknown muscle" in result.stderr and "Traceback" not in result.stderr


def test_validate_info_muscles_and_sheet(tmp_path):
    result = facesim("validate", *sorted(EXPRESSIONS.glob("*.yaml")), check=0)
    assert result.stdout.count("ok: ") == len(list(EXPRESSIONS.glob("*.yaml")))
    info = facesim("info", check=0).stdout
    assert "468 vertices, 852 triangles" in info and "41 muscles (37 linear, 4 sphincter)" in info
    assert ("controls: jaw, jaw_thrust, jaw_sideways_l, jaw_sideways_r, lip_seal, cheek_puff_l, cheek_puff_r, mouth_left, "
            "mouth_right, lip_roll_upper, lip_roll_lower, tongue_out, tongue_up, eyelid_r, "
            "levator_palpebrae_r, gaze_up_r, gaze_down_r, gaze_left_r, gaze_right_r, pupil_dilate_r, eyelid_l, "
            "levator_palpebrae_l, gaze_up_l, gaze_down_l, gaze_left_l, gaze_right_l, pupil_dilate_l") in info
    assert "backend egl: ok" in info and "backend osmesa: ok" in info
    listing = facesim("muscles", "--plot", tmp_path / "m.png", check=0).stdout
    assert "zygomaticus_major_l" in listing and "procerus" in listing
    assert iio.imread(tmp_path / "m.png").shape[0] > 500
    facesim("sheet", EXPRESSIONS, "-o", tmp_path / "sheet.png", "--size", "96x96", check=0)  # a directory
    sheet = iio.imread(tmp_path / "sheet.png")
    assert sheet.shape[0] >= 3 * 96 and sheet.shape[1] >= 3 * 96


@pytest.mark.parametrize(
    "fields, fragments",
    [
        ({"activations": {"zygomaticus_major_l": 1.7}}, ["activations -> zygomaticus_major_l", "less than or equal to 1"]),
        ({"activations": {"smile_muscle": 0.5}}, ["activations -> smile_muscle: unknown muscle"]),
        ({"dt": 0}, ["dt: Input should be greater than 0"]),
        ({"dt": -0.01}, ["dt: Input should be greater than 0"]),
        ({"frames": 0}, ["frames: Input should be greater than or equal to 1"]),
        ({"frames": 10**7}, ["frames: Input should be less than or equal to 100000"]),
        ({"colour": "red"}, ["colour: unknown field"]),
        ({"material": {"stiffness": -1}}, ["material -> stiffness"]),
    ],
)
def test_bad_specs_give_one_line_and_exit_2(tmp_path, fields, fragments):
    spec = write_spec(tmp_path, **fields)
    out = tmp_path / "never.mp4"
    one_line_error(facesim("render", spec, "-o", out), 2, str(spec), *fragments)
    assert not out.exists() and not list(tmp_path.glob(".never*"))


def test_missing_and_malformed_files(tmp_path):
    one_line_error(facesim("render", tmp_path / "nope.yaml"), 2, "nope.yaml: file not found")
    broken = tmp_path / "broken.yaml"
    broken.write_text("frames: [1, 2\nactivations: {")
    one_line_error(facesim("render", broken), 2, "broken.yaml: malformed YAML at line")
    one_line_error(facesim("validate", broken), 2, "broken.yaml")


def test_bad_options_and_unwritable_output(tmp_path):
    spec = write_spec(tmp_path)
    one_line_error(facesim("render", spec, "--size", "big"), 2, "--size")
    one_line_error(facesim("render", spec, "--camera", "top", "-o", tmp_path / "a.npz"), 2, "--camera")
    one_line_error(facesim("render", spec, "-o", tmp_path / "a.avi"), 2, "unknown output type")
    one_line_error(facesim("render", spec, "--jobs", "0"), 2, "--jobs")
    blocked = tmp_path / "file"
    blocked.write_text("")
    one_line_error(facesim("render", spec, "-o", blocked / "a.mp4"), 2, "a.mp4")
    one_line_error(facesim("render", spec, "-o", "/proc/a.mp4"), 2, "/proc/a.mp4: output directory is not writable")


def test_no_gl_backend_names_the_package_to_install(tmp_path):
    spec = write_spec(tmp_path)
    code = ("import facesim.renderer.backend as r; r.backend_available = lambda name: False; "
            f"from facesim.cli import app; app(['render', {str(spec)!r}, '-o', {str(tmp_path / 'a.mp4')!r}])")
    result = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True)
    one_line_error(result, 1, "no working GL backend", "apt-get install libosmesa6")
    assert not (tmp_path / "a.mp4").exists()


def test_divergence_is_reported_with_its_frame_and_nothing_written(tmp_path):
    spec = write_spec(tmp_path, dt=0.5, material={"preset": "thesis", "substeps": 1})
    one_line_error(facesim("render", spec, "-o", tmp_path / "a.mp4"), 1, "at frame")
    assert not list(tmp_path.glob("*.mp4")) and not list(tmp_path.glob(".a*"))


def test_ctrl_c_leaves_nothing_behind(tmp_path):
    spec = write_spec(tmp_path, frames=3000, activations={"zygomaticus_major_l": 0.5})
    out = tmp_path / "long.mp4"
    facesim_api.simulate(facesim_api.load_spec(spec).with_overrides(frames=2))  # Numba's cache warm: the child renders by 8 s
    # as from a terminal: a shell without job control (CI running us in the background)
    # hands its children SIGINT ignored, and Python then never raises KeyboardInterrupt
    process = subprocess.Popen([sys.executable, "-m", "facesim", "render", str(spec), "-o", str(out), *SMALL],
                               stderr=subprocess.PIPE, text=True,
                               preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL))
    wait_for(lambda: cpu_seconds(process.pid) > 6, what="the render to start")
    process.send_signal(signal.SIGINT)
    _, stderr = process.communicate(timeout=120)
    assert process.returncode == 130, stderr
    assert "interrupted" in stderr and "Traceback" not in stderr
    assert list(tmp_path.iterdir()) == [spec]
