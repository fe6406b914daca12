"""Every input and every fault, as a hostile tester meets them: bad meshes, bad numbers,
full disks, --force on what facesim did not write, signals, dead parents, hung
schedulers, photos of every mode. Each case asserts the exit code, one line on stderr, no
traceback, and what is left on disk: nothing new, nothing the user had lost."""

import os
import signal
import socket
import subprocess
import sys
import textwrap
import time
from contextlib import contextmanager
from pathlib import Path

import numpy as np
import pytest
import yaml
from conftest import cpu_seconds, wait_for
from test_cli import SMALL, facesim, one_line_error, write_spec

from facesim.config import HOPPER_MESH, HOPPER_MUSCLES
from facesim.face.loading import load_mesh, obj_text
from facesim.files import Terminated
from facesim.physics.mesh import FaceMesh


def tree(root: Path) -> dict:
    """Every file under root with its bytes: what a run must leave as it was."""
    return {p.relative_to(root): (p.read_bytes() if p.is_file() else None) for p in sorted(root.rglob("*"))}


def hopper_spec(tmp_path, mesh, name="spec", muscles=HOPPER_MUSCLES, **fields):
    return write_spec(tmp_path, name, mesh=str(mesh), muscles=str(muscles), **fields)


def broken_face(tmp_path, name, change):
    """The Hopper face with one defect, as an OBJ."""
    face = load_mesh(HOPPER_MESH)
    vertices, faces = change(face.vertices.copy(), face.faces.copy())
    path = tmp_path / f"{name}.obj"
    path.write_text(obj_text(FaceMesh(vertices, faces)) if np.isfinite(vertices).all() else
                    "".join(f"v {x} {y} {z}\n" for x, y, z in vertices) + "".join(f"f {a + 1} {b + 1} {c + 1}\n" for a, b, c in faces))
    return path


def collapse_an_edge(v, f):
    v[f[0, 0]] = v[f[0, 1]]  # one vertex moved onto another: zero-area triangles
    return v, f


def add_a_loose_vertex(v, f):
    return np.vstack([v, v.mean(axis=0)]), f


def make_a_coordinate_nan(v, f):
    v[7, 1] = np.nan
    return v, f


def flip_every_triangle(v, f):
    return v, f[:, ::-1]


def in_kilometres(v, f):
    return v * 1e-5, f


MESH_DEFECTS = [
    (collapse_an_edge, "no area"),
    (add_a_loose_vertex, "belong to no triangle"),
    (make_a_coordinate_nan, "non-finite"),
    (flip_every_triangle, "face away from +z"),
    (in_kilometres, "wrong units"),
]


@pytest.mark.parametrize("change, message", MESH_DEFECTS, ids=[c.__name__ for c, _ in MESH_DEFECTS])
def test_a_broken_mesh_is_one_line_in_every_command(tmp_path, change, message):
    """Zero-area triangles and loose vertices once reached the kernels (ZeroDivisionError),
    NaN once proposed vertex 0 for every landmark, a flipped face rendered dark with exit
    0, a face in kilometres asked for 400,000 sub-steps per frame: each is now refused by
    the mesh check that `mesh info` reports, before anything runs or is written."""
    mesh = broken_face(tmp_path, "broken", change)
    spec = hopper_spec(tmp_path, mesh, activations={"zygomaticus_major_l": 1.0, "jaw": 0.8})
    before = tree(tmp_path)
    info = facesim("mesh", "info", mesh)
    assert info.returncode in (1, 2) and "Traceback" not in info.stderr and message in info.stdout + info.stderr
    assert "ok: usable" not in info.stdout
    one_line_error(facesim("render", spec, "-o", tmp_path / "out" / "a.mp4", *SMALL), 2, str(mesh), message)
    one_line_error(facesim("validate", spec), 2, str(mesh), message)
    one_line_error(facesim("sheet", spec, "-o", tmp_path / "s.png", "--size", "64x64"), 2, str(mesh), message)
    one_line_error(facesim("muscles", "--mesh", mesh, "--muscles", HOPPER_MUSCLES), 2, str(mesh), message)
    if change is make_a_coordinate_nan:  # landmarks and align take meshes in any units and pose, never NaN
        one_line_error(facesim("mesh", "landmarks", mesh, "-o", tmp_path / "l.yaml"), 2, str(mesh), message)
    assert tree(tmp_path) == before


def test_an_stl_triangle_soup_is_welded_into_a_face(tmp_path):
    """STL stores every triangle with its own corners; read as it is, a face falls apart
    into 852 pieces. facesim welds the corners (STL has no vertex order to keep)."""
    import trimesh

    face = load_mesh(HOPPER_MESH)
    stl = tmp_path / "face.stl"
    trimesh.Trimesh(face.vertices, face.faces, process=False).export(stl)
    result = facesim("mesh", "info", stl, check=0)
    assert "468 vertices, 852 triangles, 1 piece(s)" in result.stdout and "ok: usable" in result.stdout


@pytest.mark.parametrize("force, code, message", [(".inf", 2, "finite number"), ("1e20", 2, "no face's muscle"),
                                                  ("1e150", 2, "no face's muscle"), ("9e4", 1, "at frame")])
def test_runaway_muscle_forces(tmp_path, force, code, message):
    """A force of .inf is no number; one beyond what any face's muscle pulls (physics.model.
    MUSCLE_STRETCH_LIMIT) is refused before the simulation, where 1e150 once ran to a face
    that moved 0.0 cm, exit 0; one within it whose simulation diverges is reported with its
    frame (fastmath once hid the non-finite values: ZeroDivisionError)."""
    text = HOPPER_MUSCLES.read_text().replace("  force: 200", f"  force: {force}", 1)
    assert f"force: {force}" in text
    muscles = tmp_path / "strong.muscles.yaml"
    muscles.write_text(text)
    spec = hopper_spec(tmp_path, HOPPER_MESH, muscles=muscles)
    one_line_error(facesim("render", spec, "-o", tmp_path / "a.mp4", *SMALL), code, message)
    assert not list(tmp_path.glob("*.mp4")) and not list(tmp_path.glob(".a*"))


def test_attachment_true_is_not_vertex_1(tmp_path):
    text = yaml.safe_load(HOPPER_MUSCLES.read_text())
    text["muscles"][0]["attachment"] = True
    muscles = tmp_path / "m.yaml"
    muscles.write_text(yaml.safe_dump(text))
    one_line_error(facesim("muscles", "--mesh", HOPPER_MESH, "--muscles", muscles), 2, str(muscles), "attachment")


def test_batch_reports_every_spec_when_one_has_a_broken_mesh(tmp_path):
    """One bad spec once killed the whole batch with no table, and with --jobs 1 the specs
    after it never ran."""
    broken = hopper_spec(tmp_path, broken_face(tmp_path, "broken", collapse_an_edge), "a_broken")
    good = hopper_spec(tmp_path, HOPPER_MESH, "b_good", frames=4, onset=2)
    out = tmp_path / "out"
    result = facesim("batch", broken, good, "-o", out, "--jobs", "1", "--format", "npz", *SMALL)
    assert result.returncode == 1 and "Traceback" not in result.stderr
    assert "a_broken" in result.stdout and "FAILED" in result.stdout and "b_good" in result.stdout
    assert (out / "b_good.npz").is_file() and not (out / "a_broken.npz").exists()
    assert [line for line in result.stderr.splitlines() if line.startswith("facesim: error:")] == [
        f"facesim: error: {broken}: {tmp_path / 'broken.obj'}: " + result.stderr.split("broken.obj: ", 1)[1].splitlines()[0]]


# --- --force and what is already on disk -------------------------------------------------


def test_force_never_replaces_what_facesim_did_not_write(tmp_path):
    """--force once deleted a directory named like the output with everything in it, and
    unrelated files in a frames directory."""
    spec = write_spec(tmp_path, frames=2, onset=1)
    keep = tmp_path / "keep.mp4"
    keep.mkdir()
    (keep / "thesis.tex").write_text("years of work")
    frames = tmp_path / "frames"
    frames.mkdir()
    (frames / "frame_0000.png").write_bytes(b"not facesim's")
    (frames / "notes.txt").write_text("mine")
    mine = tmp_path / "mine.gif"
    mine.write_text("a text file called .gif")
    photo_dir = tmp_path / "photo_out"
    photo_dir.mkdir()
    (photo_dir / "x").write_text("x")
    before = tree(tmp_path)
    one_line_error(facesim("render", spec, "-o", keep, "--force"), 2, str(keep))
    one_line_error(facesim("render", spec, "-o", frames, "--force"), 2, str(frames))
    one_line_error(facesim("render", spec, "-o", mine, "--force"), 2, str(mine))
    one_line_error(facesim("render", spec, "-o", ".", "--force", cwd=tmp_path), 2)
    one_line_error(facesim("mesh", "from-photo", tmp_path / "p.png", "-o", photo_dir, "--force"), 2, str(photo_dir))
    one_line_error(facesim("sheet", spec, "-o", keep, "--force"), 2)
    assert tree(tmp_path) == before


def test_force_replaces_facesims_own_output(tmp_path):
    spec = write_spec(tmp_path, frames=2, onset=1)
    out = tmp_path / "a.npz"
    facesim("render", spec, "-o", out, check=0)
    first = out.read_bytes()
    one_line_error(facesim("render", spec, "-o", out), 2, "exists")
    assert out.read_bytes() == first
    facesim("render", spec, "-o", out, "--force", check=0)
    frames = tmp_path / "frames"
    facesim("render", spec, "-o", frames, *SMALL, check=0)
    facesim("render", spec, "-o", frames, "--force", *SMALL, check=0)
    assert sorted(p.name for p in frames.iterdir()) == ["facesim-manifest.json", "frame_0000.png", "frame_0001.png"]


def test_two_renders_to_one_output_cannot_both_win(tmp_path):
    """Both once succeeded, the second silently replacing the first."""
    spec = write_spec(tmp_path, frames=8)
    out = tmp_path / "a.mp4"
    command = [sys.executable, "-m", "facesim", "render", str(spec), "-o", str(out), *SMALL]
    runs = [subprocess.Popen(command, stderr=subprocess.PIPE, text=True) for _ in range(2)]
    results = [(p.wait(timeout=300), p.stderr.read()) for p in runs]
    codes = sorted(code for code, _ in results)
    assert codes == [0, 2], results
    loser = next(err for code, err in results if code == 2)
    assert loser.count("\n") == 1 and "Traceback" not in loser
    assert "already exists" in loser or "appeared while facesim was writing it" in loser
    assert sorted(p.name for p in tmp_path.iterdir()) == ["a.mp4", "spec.yaml"]


# --- writes that fail ----------------------------------------------------------------------


@contextmanager
def small_disk(path: Path, size: str):
    """A tmpfs of ``size`` mounted at path (needs root; the test is skipped otherwise)."""
    path.mkdir()
    mounted = subprocess.run(["mount", "-t", "tmpfs", "-o", f"size={size}", "tmpfs", str(path)], capture_output=True)
    if mounted.returncode != 0:
        pytest.skip(f"cannot mount a small tmpfs here to fill: {mounted.stderr.decode().strip()[:200]}")
    try:
        yield path
    finally:
        subprocess.run(["umount", "-l", str(path)], check=False)


@pytest.mark.parametrize("name", ["a.mp4", "a.gif", "a.npz", "frames"])
def test_a_full_disk_is_one_line_and_leaves_nothing(tmp_path, name):
    """On a full disk an MP4 was once renamed into place corrupt (4 KB, 'wrote', exit 0) and
    the other formats ended in an OSError traceback. What the user had there stays."""
    spec = write_spec(tmp_path, frames=40)  # ~7 KB of MP4: more than the 4 KB left beside precious.txt
    with small_disk(tmp_path / "disk", "8k") as disk:
        (disk / "precious.txt").write_text("kept")
        result = facesim("render", spec, "-o", disk / name, "--size", "256x256")
        one_line_error(result, 1, name)
        assert "space" in result.stderr.lower() or "verify" in result.stderr.lower()
        assert sorted(p.name for p in disk.iterdir()) == ["precious.txt"]


def test_a_failed_render_leaves_no_directory_it_made(tmp_path):
    spec = write_spec(tmp_path, dt=0.5, material={"preset": "thesis", "substeps": 1})  # diverges
    one_line_error(facesim("render", spec, "-o", tmp_path / "new" / "deeper" / "a.mp4", *SMALL), 1, "at frame")
    assert not (tmp_path / "new").exists()


def test_sigterm_during_the_write_leaves_nothing(tmp_path):
    """SIGTERM (kill, timeout, job schedulers) once left `.a.partial-PID.mp4` behind."""
    spec = write_spec(tmp_path, frames=400, onset=4)
    out = tmp_path / "a.mp4"
    process = subprocess.Popen([sys.executable, "-m", "facesim", "render", str(spec), "-o", str(out), *SMALL],
                               stderr=subprocess.PIPE, text=True)
    partial = wait_for(lambda: [p for p in tmp_path.iterdir() if p.name.startswith(".a")], what="the partial MP4")
    process.send_signal(signal.SIGTERM)
    _, stderr = process.communicate(timeout=60)
    assert process.returncode == 128 + signal.SIGTERM, stderr
    assert "stopped by" in stderr and "Traceback" not in stderr
    assert not any(p.exists() for p in partial) and list(tmp_path.iterdir()) == [spec]


@pytest.fixture
def own_signal_handlers():
    """facesim's SIGTERM, SIGHUP and SIGINT handlers in this process (SIGINT's default
    handler set first, as in a terminal: a test worker may run with it ignored), the test
    runner's restored after."""
    from facesim.files import handling_termination, terminating_signal

    runner = signal.signal(signal.SIGINT, signal.default_int_handler)
    try:
        with handling_termination():
            yield
        assert terminating_signal() is None  # nothing recorded is left for the next test
    finally:
        signal.signal(signal.SIGINT, runner)


def swallowing_library(then=None, signum=signal.SIGTERM):
    """Library code that catches everything (a bare ``except``) while a signal arrives."""
    try:
        os.kill(os.getpid(), signum)
        time.sleep(1.0)
    except BaseException:
        if then is not None:
            raise then from None


@pytest.mark.parametrize("signum, raised", [(signal.SIGTERM, Terminated), (signal.SIGINT, KeyboardInterrupt)])
def test_a_signal_that_library_code_swallowed_still_leaves_nothing(tmp_path, own_signal_handlers, signum, raised):
    """CI once saw a render go on to write all 400 frames, exit 0, after its SIGTERM, and
    another all 3,000 after its Ctrl-C."""
    from facesim.files import atomic_path

    with pytest.raises(raised):
        with atomic_path(tmp_path / "a.mp4") as tmp:
            tmp.write_bytes(b"....ftyp")
            swallowing_library(signum=signum)
    assert list(tmp_path.iterdir()) == []


def test_a_swallowed_ctrl_c_is_reported_as_an_interruption(own_signal_handlers, capsys):
    import typer

    from facesim.cli import handled

    @handled
    def command():
        swallowing_library(then=ValueError("argument 2: KeyboardInterrupt"), signum=signal.SIGINT)

    with pytest.raises(typer.Exit) as stopped:
        command()
    assert stopped.value.exit_code == 130
    assert capsys.readouterr().err == "facesim: error: interrupted; nothing was written\n"


def test_an_error_a_signal_turned_into_is_reported_as_the_signal(own_signal_handlers, capsys):
    """ctypes turns the signal's exception into an ArgumentError when it lands in an OpenGL
    call's argument conversion: that was a traceback, and is the signal's one line."""
    import typer

    from facesim.cli import handled

    @handled
    def command():
        swallowing_library(then=ValueError("argument 2: Terminated: SIGTERM"))

    with pytest.raises(typer.Exit) as stopped:
        command()
    assert stopped.value.exit_code == 128 + signal.SIGTERM
    assert capsys.readouterr().err == "facesim: error: stopped by SIGTERM; nothing was written\n"


def test_sigterm_stops_a_long_simulation_within_seconds(tmp_path):
    """The kernel returns to Python every ~0.2 s (it once held Ctrl-C for 36 s)."""
    spec = write_spec(tmp_path, frames=100000, material={"substeps": 20}, activations={"zygomaticus_major_l": 0.5})
    import threading

    process = subprocess.Popen([sys.executable, "-m", "facesim", "render", str(spec), "-o", str(tmp_path / "a.mp4")],
                               stderr=subprocess.PIPE, text=True)
    lines = []
    reader = threading.Thread(target=lambda: lines.extend(process.stderr), daemon=True)
    reader.start()
    # the simulation has started once the estimate, timed on its first frames, is said,
    # and the process has since used another second of CPU
    wait_for(lambda: any("minutes of simulation" in line for line in lines), what="the long-run notice")
    started = cpu_seconds(process.pid)
    wait_for(lambda: cpu_seconds(process.pid) > started + 1, what="the simulation to run")
    sent = time.monotonic()
    process.send_signal(signal.SIGTERM)
    process.wait(timeout=60)
    reader.join(timeout=10)
    stderr = "".join(lines)
    assert process.returncode == 128 + signal.SIGTERM and "Traceback" not in stderr, stderr
    assert time.monotonic() - sent < 5.0
    assert list(tmp_path.iterdir()) == [spec]
    assert "(Ctrl-C stops it)" in stderr


def rss_mb(pid: int) -> float:
    return int(Path(f"/proc/{pid}/statm").read_text().split()[1]) * os.sysconf("SC_PAGE_SIZE") / 2**20


def test_a_huge_dataset_starts_at_once_and_stays_flat(tmp_path):
    """`--n 10000000` once spent 130 s before the first sample, then grew ~60 MB/s."""
    out = tmp_path / "ds"
    process = subprocess.Popen([sys.executable, "-m", "facesim", "dataset", "-o", str(out), "--n", "10000000",
                                "--jobs", "1", "--size", "32x32"], stderr=subprocess.DEVNULL)
    try:
        labels = lambda: len(list((out / "labels").glob("*.json"))) if (out / "labels").is_dir() else 0  # noqa: E731
        wait_for(lambda: labels() >= 3, timeout=90, what="the first samples")
        early = rss_mb(process.pid)
        wait_for(lambda: labels() >= 25, timeout=120, what="25 samples")
        assert rss_mb(process.pid) - early < 40, (early, rss_mb(process.pid))
    finally:
        process.kill()
        process.wait()


# --- dataset ---------------------------------------------------------------------------------


@pytest.mark.parametrize("option, message", [
    (["--size", "0x0"], "--size"),
    (["--seed", "-1"], "--seed"),
    (["--backend", "vulkan"], "--backend"),
    (["--n", "-3"], "--n"),
    (["--executor", "spark"], "--executor"),
])
def test_dataset_checks_its_settings_before_writing(tmp_path, option, message):
    """`--size 0x0` once wrote dataset.json first, so the corrected rerun was refused."""
    args = ["--n", "2", *option] if option[0] != "--n" else option
    one_line_error(facesim("dataset", "-o", tmp_path / "ds", *args), 2, message)
    assert list(tmp_path.iterdir()) == []


def descendants(pid: int) -> set[int]:
    children = {}
    for stat in Path("/proc").glob("[0-9]*/stat"):
        try:
            fields = stat.read_text().rsplit(")", 1)[1].split()
        except OSError:
            continue
        children.setdefault(int(fields[1]), []).append(int(stat.parent.name))
    found, todo = set(), [pid]
    while todo:
        for child in children.get(todo.pop(), []):
            found.add(child)
            todo.append(child)
    return found


def alive(pid: int) -> bool:
    try:
        state = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[0]
    except OSError:
        return False
    return state != "Z"


def test_killing_the_dataset_leaves_no_worker(tmp_path):
    """Killing only the main process (SIGKILL: it can do nothing) once orphaned its
    workers, about 380 MB each, for ever."""
    process = subprocess.Popen([sys.executable, "-m", "facesim", "dataset", "-o", str(tmp_path / "ds"), "--n", "400",
                                "--jobs", "2", "--size", "64x64"], stderr=subprocess.DEVNULL)
    workers = wait_for(lambda: (lambda d: d if len(d) >= 2 else None)(descendants(process.pid)), what="the workers")
    process.kill()
    process.wait()
    wait_for(lambda: not any(alive(p) for p in workers), timeout=15, what="the workers to die")


def test_a_scheduler_that_never_answers_times_out(tmp_path):
    """A Dask scheduler that accepts and never answers once hung `dataset` for ever."""
    pytest.importorskip("distributed", reason="Dask not installed (pip install -e '.[dask]')")
    with socket.socket() as server:
        server.bind(("127.0.0.1", 0))
        server.listen(8)  # the kernel accepts connections; nobody ever reads or answers
        port = server.getsockname()[1]
        start = time.monotonic()
        result = facesim("dataset", "-o", tmp_path / "ds", "--n", "2", "--executor", "dask",
                         "--scheduler", f"tcp://127.0.0.1:{port}", "--scheduler-timeout", "2")
    one_line_error(result, 1, f"127.0.0.1:{port}", "no answer within 2 s")
    assert time.monotonic() - start < 60
    assert not (tmp_path / "ds").exists()
    malformed = facesim("dataset", "-o", tmp_path / "ds", "--n", "2", "--executor", "dask", "--scheduler", "nonsense:::")
    one_line_error(malformed, 2, "nonsense:::", "tcp://HOST:PORT")
    assert not (tmp_path / "ds").exists()


def _kernel_threads(_):
    import numba

    return numba.get_num_threads()


def test_worker_processes_share_the_cores_between_them():
    """Each of facesim's worker processes (batch, dataset, frames in parallel) runs a
    large mesh's parallel kernels on its share of the cores, not on all of them: on two
    cores, `batch --jobs 2` on a 6,990-vertex face took 24-26 s with every worker on
    both, 9-10 s with one each."""
    import numba

    from facesim.workers import available_cores, worker_pool

    for jobs in (1, 2):
        with worker_pool(jobs) as pool:
            threads = set(pool.map(_kernel_threads, range(2 * jobs)))
        assert threads == {min(numba.config.NUMBA_NUM_THREADS, max(1, available_cores() // jobs))}, (jobs, threads)


def test_jobs_are_capped_to_the_machine(tmp_path):
    out = tmp_path / "ds"
    result = facesim("dataset", "-o", out, "--n", "1", "--jobs", "1000", "--size", "64x64", check=0)
    assert f"--jobs 1000: this machine has {os.cpu_count()} cores" in result.stderr


# --- mesh align and photos ---------------------------------------------------------------------


def test_a_failed_align_leaves_nothing(tmp_path):
    """`mesh align` once left its OBJ and muscle file behind when the muscles did not fit
    the aligned mesh, blocking the rerun with 'already exists'."""
    import trimesh

    box = trimesh.creation.box(extents=(14, 18, 10))
    path = tmp_path / "box.ply"
    box.export(path)
    corners = {name: int(k % 8) for k, name in enumerate(("eye_outer_r", "eye_outer_l", "nose_tip", "chin",
                                                           "mouth_corner_r", "mouth_corner_l"))}
    landmarks = tmp_path / "landmarks.yaml"
    landmarks.write_text(yaml.safe_dump(corners))
    before = tree(tmp_path)
    result = facesim("mesh", "align", path, "--landmarks", landmarks, "-o", tmp_path / "aligned.obj")
    assert result.returncode == 2 and "Traceback" not in result.stderr, result.stderr
    assert len(result.stderr.strip().splitlines()) == 1
    assert tree(tmp_path) == before


@pytest.fixture(scope="module")
def astronaut(tmp_path_factory):
    pytest.importorskip("mediapipe", reason="MediaPipe not installed (pip install -e '.[photo]')")
    from PIL import Image
    from skimage import data

    return Image.fromarray(data.astronaut()), tmp_path_factory.mktemp("photos")


def save_la(image, root):
    image.convert("LA").save(root / "la.png")
    return root / "la.png"


def save_palette(image, root):
    image.convert("P").save(root / "p.png")
    return root / "p.png"


def save_cmyk(image, root):
    image.convert("CMYK").save(root / "cmyk.jpg")
    return root / "cmyk.jpg"


def save_16_bit(image, root):
    from PIL import Image

    Image.fromarray(np.asarray(image.convert("L")).astype(np.uint16) * 257).save(root / "grey16.png")
    return root / "grey16.png"


def save_animated(image, root):
    from PIL import Image

    image.save(root / "anim.gif", save_all=True, append_images=[Image.new("RGB", image.size)], duration=100)
    return root / "anim.gif"


@pytest.mark.parametrize("save", [save_la, save_palette, save_cmyk, save_16_bit, save_animated],
                         ids=["LA", "P", "CMYK", "16-bit", "animated"])
def test_photos_of_every_mode_find_the_face_quietly(astronaut, save, tmp_path):
    """A grey-with-alpha PNG once crashed MediaPipe; CMYK, 16-bit and animated GIFs found no
    face; every run printed TensorFlow Lite's log lines."""
    photo = save(*astronaut)
    result = facesim("mesh", "from-photo", photo, "-o", tmp_path / "face.obj", check=0)
    assert result.stderr.strip().splitlines() == [f"wrote {tmp_path / 'face.obj'}: 468 vertices, 852 triangles"]


@pytest.mark.parametrize("content, message", [(b"hello", "not a readable image"), (None, "truncated")])
def test_unreadable_photos_are_one_line(astronaut, tmp_path, content, message):
    photo = tmp_path / "photo.png"
    if content is None:
        astronaut[0].save(photo)
        content = photo.read_bytes()[:20000]
    photo.write_bytes(content)
    one_line_error(facesim("mesh", "from-photo", photo, "-o", tmp_path / "face.obj"), 2, str(photo), message)
    assert list(tmp_path.iterdir()) == [photo]


# --- issue 44: no silent wrong result ----------------------------------------------------


def test_force_keeps_a_users_file_named_like_a_frame(tmp_path):
    """`echo notes > d/frame_0000.png; facesim render happy -o d --force` deleted the notes
    and exited 0: a frames directory was judged by its file names."""
    d = tmp_path / "d"
    d.mkdir()
    (d / "frame_0000.png").write_text("notes")
    before = tree(tmp_path)
    one_line_error(facesim("render", "happy", "-o", d, "--force", *SMALL), 2, str(d), "facesim-manifest.json")
    assert tree(tmp_path) == before


def test_force_keeps_a_face_directory_facesim_did_not_write(tmp_path):
    """A directory of the user's own head.obj, head.mtl, head.png, face.yaml and
    muscles.yaml: `face from-photo a.png -o DIR --force` replaced all of them."""
    mine = tmp_path / "mine"
    mine.mkdir()
    for name in ("head.obj", "head.mtl", "head.png", "head_onto.png", "face.yaml", "muscles.yaml"):
        (mine / name).write_text(f"my own {name}")
    before = tree(tmp_path)
    one_line_error(facesim("face", "from-photo", tmp_path / "a.png", "-o", mine, "--force"), 2, str(mine))
    assert tree(tmp_path) == before


def test_force_keeps_a_facesim_directory_edited_since(tmp_path):
    """A frames directory facesim wrote, with one frame since replaced by the user's own
    picture: its manifest no longer holds, and --force leaves it."""
    frames = tmp_path / "frames"
    facesim("render", "happy", "-o", frames, "--size", "32x32", check=0)
    (frames / "frame_0003.png").write_bytes((frames / "frame_0000.png").read_bytes())  # the user's retouch
    before = tree(tmp_path)
    one_line_error(facesim("render", "happy", "-o", frames, "--force", "--size", "32x32"), 2, str(frames))
    assert tree(tmp_path) == before


def hopper_muscles_with(tmp_path, change) -> Path:
    data = yaml.safe_load(HOPPER_MUSCLES.read_text())
    change(data)
    path = tmp_path / "changed.muscles.yaml"
    path.write_text(yaml.safe_dump(data))
    return path


@pytest.mark.parametrize("where", ["muscle", "defaults"])
def test_an_overflowing_muscle_force_is_refused_by_render_and_validate(tmp_path, where):
    """A force of 1e150 (in a muscle or in `defaults: force:`) under the implicit solver:
    the face moved 0.0 cm in every frame, the video was written, and validate said ok."""
    def overflow(data):
        if where == "muscle":
            data["muscles"][0]["force"] = 1e150
        else:
            data.setdefault("defaults", {})["force"] = 1e150
            for m in data["muscles"]:
                m.pop("force", None)
    muscles = hopper_muscles_with(tmp_path, overflow)
    spec = hopper_spec(tmp_path, HOPPER_MESH, muscles=muscles, material={"solver": "implicit", "bending": 0.0})
    one_line_error(facesim("render", spec, "-o", tmp_path / "a.mp4", *SMALL), 2, str(muscles), "no face's muscle")
    one_line_error(facesim("validate", spec), 2, str(muscles), "no face's muscle")
    assert not list(tmp_path.glob("*.mp4"))


def test_a_muscle_that_reaches_no_vertex_is_refused(tmp_path):
    """A muscle whose zone and falloff leave it no vertex did nothing when activated."""
    def narrow(data):
        data["muscles"][0]["falloff"] = [1e-6, 1e-6]
        data["muscles"][0]["zone"] = 1e-6
    muscles = hopper_muscles_with(tmp_path, narrow)
    name = yaml.safe_load(muscles.read_text())["muscles"][0]["name"]
    spec = hopper_spec(tmp_path, HOPPER_MESH, muscles=muscles)
    one_line_error(facesim("validate", spec), 2, str(muscles), name, "no vertex")


def test_a_run_whose_activated_muscles_move_nothing_fails(tmp_path):
    """Whatever the cause, a face that stays at rest while muscles contract is a failed
    run (exit 1), not a video of a still face."""
    from facesim.animation.simulate import STILL, check_moved, model_for
    from facesim.animation.spec import activation_table, load_spec
    from facesim.errors import SimulationError

    spec = load_spec(write_spec(tmp_path))
    model = model_for(spec)
    table = activation_table(spec, model.muscles)
    with pytest.raises(SimulationError, match="did not move"):
        check_moved(model, table, 0.0, spec.source)
    with pytest.raises(SimulationError, match="did not move"):
        check_moved(model, table, float("nan"), spec.source)
    check_moved(model, table, 10 * STILL, spec.source)  # a face that moves passes
    check_moved(model, np.zeros_like(table), 0.0, spec.source)  # and one asked to stay still stays


@pytest.mark.parametrize("identity, message", [
    ([5.0] * 100, "beyond 4.5 standard deviations"),
    ([10.0] * 100, "beyond 4.5 standard deviations"),
    ([1e6] + [0.0] * 99, "beyond 4.5 standard deviations"),
    ([1.4] * 100, "length is 14"),
    ([0.0, ".nan"], "weight 1 is nan"),
])
def test_implausible_identity_weights_are_one_line(tmp_path, identity, message):
    """Weights of 5 on all 100 modes tore the head with no warning; 10 to 1e6 ended in a
    traceback from the mirror map, or blamed the shipped head.npz; a NaN said 'Input
    should be a valid integer'. A weight length of 14 is still a head (1.4 on every mode
    is 14.0): it runs."""
    spec = tmp_path / "spec.yaml"
    spec.write_text("frames: 4\nactivations: {zygomaticus_major_l: 1}\nidentity: [" + ", ".join(map(str, identity)) + "]\n")
    result = facesim("validate", spec)
    if message.startswith("length is 14"):
        assert result.returncode == 0, result.stderr
    else:
        one_line_error(result, 2, str(spec), "identity", message)


def test_face_with_identity_or_mesh_is_refused_on_the_command_line(tmp_path):
    """`render --face DIR --identity 3` and `--face DIR --mesh ...` ignored --identity and
    --mesh; a spec giving both was already refused."""
    for extra in (["--identity", "3"], ["--mesh", str(HOPPER_MESH)]):
        result = facesim("render", "happy", "--face", tmp_path, *extra, "-o", tmp_path / "a.mp4")
        one_line_error(result, 2, "--face", extra[0])
    assert not list(tmp_path.iterdir())


def test_onto_with_size_is_refused(tmp_path):
    """--onto draws at the photo's size and ignored --size without a word."""
    one_line_error(facesim("render", "happy", "--face", tmp_path, "--onto", tmp_path / "p.png", "--size", "64x64",
                           "-o", tmp_path / "a.mp4"), 2, "--size", "--onto")


def test_outputs_by_intent(tmp_path):
    """`-o out.frames/` (a directory whose name has a dot) was "unknown output type";
    `-o x.png` too, where one PNG of the apex frame is meant; `--frame N` picks another."""
    from PIL import Image

    facesim("render", "happy", "-o", f"{tmp_path / 'out.frames'}/", "--size", "32x32", check=0)
    assert len(list((tmp_path / "out.frames").glob("frame_*.png"))) == 35
    existing = tmp_path / "existing.d"
    existing.mkdir()
    facesim("render", "happy", "-o", existing, "--size", "32x32", check=0)
    assert len(list(existing.glob("frame_*.png"))) == 35
    facesim("render", "happy", "-o", tmp_path / "apex.png", "--size", "64x64", check=0)
    facesim("render", "happy", "-o", tmp_path / "first.png", "--frame", "0", "--size", "64x64", check=0)
    apex, first = (np.asarray(Image.open(tmp_path / n)) for n in ("apex.png", "first.png"))
    frames = sorted((tmp_path / "out.frames").glob("frame_*.png"))
    assert apex.shape == (64, 64, 3) and np.abs(apex.astype(int) - first.astype(int)).max() > 30  # the smile shows
    one_line_error(facesim("render", "happy", "-o", tmp_path / "b.png", "--frame", "35"), 2, "--frame", "0 to 34")
    one_line_error(facesim("render", "happy", "-o", tmp_path / "b.mp4", "--frame", "3"), 2, "--frame", ".png")
    assert len(frames) == 35 and not (tmp_path / "b.png").exists()


FORK_WHILE_THREADED = """
import os, threading
from facesim.animation.simulate import model_for
from facesim.animation.spec import activation_table, load_spec
from facesim.config import LIBRARY
from facesim.physics.run import run
spec = load_spec(LIBRARY / "happy.yaml")
model = model_for(spec)
table = activation_table(spec, model.muscles)
run(model, table[:1], spec.dt, threads=2)  # the threading layer's pool started on this thread, as a render's
running = threading.Thread(target=lambda: [run(model, table, spec.dt, threads=2) for _ in range(20)])
running.start()
while running.is_alive():  # forked as ffmpeg is: with the fork handlers (Python's own spawning may skip them)
    child = os.fork()
    if child == 0:
        os._exit(0)
    os.waitpid(child, 0)
"""


@pytest.fixture()
def tbb_env():
    """This environment with TBB's library found and no threading layer chosen, so that
    Numba picks by its priority; skipped where TBB is not installed."""
    import importlib.util

    if importlib.util.find_spec("tbb") is None and not (Path(sys.prefix) / "lib" / "libtbb.so.12").exists():
        pytest.skip("TBB is not installed (the test extra installs it)")
    env = dict(os.environ, LD_LIBRARY_PATH=str(Path(sys.prefix) / "lib"))
    env.pop("NUMBA_THREADING_LAYER", None)
    return env


def test_stdout_carries_nothing_facesim_did_not_mean(tmp_path, tbb_env):
    """With TBB installed, Numba's pool wrote "Unable to join threads to shut down before
    fork()" on stdout when a process forked (ffmpeg for every MP4) while a parallel
    kernel ran on another thread. facesim prefers OpenMP (facesim.config._prefer_openmp):
    a render's stdout is empty, and so is that of a process forking while facesim's
    parallel kernels run beside it; asked to prefer TBB again, the noise is back, so this
    test can tell."""
    env = tbb_env
    quiet = facesim("render", "happy", "-o", tmp_path / "a.mp4", "--size", "32x32", env=env, check=0)
    assert quiet.stdout == ""

    def forking(**changes):
        return subprocess.run([sys.executable, "-c", FORK_WHILE_THREADED], capture_output=True, text=True,
                              env=dict(env, **changes), timeout=300)

    quiet = forking()
    assert quiet.stdout == "" and "fork" not in quiet.stderr
    assert "Unable to join threads" in forking(NUMBA_THREADING_LAYER_PRIORITY="tbb omp workqueue").stdout


def test_a_pools_worker_starts_openmps_threads_too(tbb_env):
    """A worker of `batch --jobs` or `dataset` sets its thread count (facesim.workers.
    share_the_cores) before it imports any kernel, which starts Numba's threads: they
    are OpenMP's, as a kernel's would be (facesim.config.prepare_numba; when Numba was
    first set up by a kernel module alone, such a worker started TBB's, whose pool writes
    on stdout at each fork), and preferring TBB again shows the test can tell."""
    env = tbb_env
    code = "from facesim.workers import share_the_cores; share_the_cores(2); import numba; print(numba.threading_layer())"

    def layer(**changes):
        result = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, env=dict(env, **changes),
                                timeout=120)
        assert result.returncode == 0, result.stderr[-2000:]
        return result.stdout.split()[-1]

    assert layer() == "omp"
    assert layer(NUMBA_THREADING_LAYER_PRIORITY="tbb omp workqueue") == "tbb"


def test_openmps_threads_sleep_soon_after_a_loop_unless_the_user_chose_otherwise():
    """libgomp's threads spin 300,000 times for work after each parallel loop unless told
    otherwise, and a render's loops (the head's skin weights, the edge filter) left them
    taking a core from llvmpipe and the simulation: facesim sets a short spin
    (facesim.config.OPENMP_SPIN) before OpenMP starts, in the process and its workers,
    and keeps what a user set for OpenMP's waiting."""
    code = ("from facesim.workers import share_the_cores; share_the_cores(2); import os, numba; "
            "print(numba.threading_layer(), os.environ.get('GOMP_SPINCOUNT'), os.environ.get('OMP_WAIT_POLICY'))")

    def started(**changes):
        env = {k: v for k, v in os.environ.items() if k not in ("GOMP_SPINCOUNT", "OMP_WAIT_POLICY")}
        result = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, env=dict(env, **changes),
                                timeout=120)
        assert result.returncode == 0, result.stderr[-2000:]
        return result.stdout.split()[-3:]

    from facesim.config import OPENMP_SPIN

    assert started() == ["omp", str(OPENMP_SPIN), "None"]
    assert started(GOMP_SPINCOUNT="infinity") == ["omp", "infinity", "None"]
    assert started(OMP_WAIT_POLICY="active") == ["omp", "None", "active"]


def test_a_long_clip_is_announced_from_its_measured_speed(monkeypatch):
    """`frames: 100000` on the head: the estimate assumed a rate the head does not reach
    (23 s predicted, 156 s taken). Now a long clip's first frames are timed on the face at
    hand (simulate.expected_seconds; its accuracy, 0.9-1.0 of the time taken for 600 and
    3,000 frames of happy in a quiet process, is a measurement, not asserted here), and
    simulate says it before starting."""
    from conftest import spec

    import facesim.animation.simulate as simulating
    from facesim.animation.simulate import simulate

    long = spec("happy").with_overrides(frames=600)
    monkeypatch.setattr(simulating, "LONG_CLIP", 100)
    monkeypatch.setattr(simulating, "LONG_RUN", 0.0)
    measured = []
    monkeypatch.setattr(simulating, "expected_seconds", lambda *args: measured.append(args) or 90.0)
    said = []
    simulate(long, notice=said.append)
    assert len(measured) == 1 and len(measured[0][1]) == 600  # timed on this clip's own table
    assert said == [f"{long.source}: 600 frames of 468 vertices: about 2 minutes of simulation, as its first frames "
                    "ran here (Ctrl-C stops it)"]
    monkeypatch.setattr(simulating, "LONG_CLIP", 601)
    said.clear()
    simulate(long, notice=said.append)
    assert said == []  # a shorter clip is not timed


def test_a_clip_kept_whole_says_how_much_memory_it_takes(tmp_path):
    """`frames: 100000` to an NPZ grew to gigabytes without a word; a video streams (its
    memory: tests/test_simulation.py, BENCHMARKS.md). What must hold the whole clip says
    so before it starts."""
    spec = write_spec(tmp_path, frames=100000)
    process = subprocess.Popen([sys.executable, "-m", "facesim", "render", str(spec), "-o", str(tmp_path / "a.npz")],
                               stderr=subprocess.PIPE, text=True)
    import threading

    lines = []
    threading.Thread(target=lambda: lines.extend(process.stderr), daemon=True).start()
    wait_for(lambda: any("GB of positions" in line for line in lines), what="the memory notice")
    process.send_signal(signal.SIGTERM)
    process.wait(timeout=60)
    assert any("100,000 frames of 468 vertices hold 1.0 GB of positions in memory" in line for line in lines), lines
    assert sorted(p.name for p in tmp_path.iterdir()) == ["spec.yaml"]


def test_a_slow_warm_run_does_not_blame_compiling(tmp_path):
    """The last line of a 100,000-frame render said "the first run compiles the Numba
    kernels" whenever the simulation took over 3 s; it says so now only when this
    process compiled them."""
    face = ("--mesh", HOPPER_MESH)  # its skin is the head's: the same kernels, nothing to draw
    facesim("render", write_spec(tmp_path, "short", frames=2, onset=1), *face, "-o", tmp_path / "warm.npz", check=0)
    spec = write_spec(tmp_path, frames=8000)  # several seconds of simulation, every kernel warm
    result = facesim("render", spec, *face, "-o", tmp_path / "again.npz", check=0)
    last = result.stderr.strip().splitlines()[-1]
    seconds = float(last.split("simulation ")[1].split(" ms")[0]) / 1000
    assert seconds > 3 and "compil" not in last, last


def test_unusual_identity_weights_are_said_once(tmp_path):
    """Weights past 3.5 standard deviations on some mode (within the 4.5 that is refused)
    make an unusual head: the run says so before it starts, once; a seed says nothing."""
    from facesim.animation.simulate import simulate
    from facesim.animation.spec import load_spec

    for identity, expected in (([0.5, 3.8, -1.0], 1), ([0.5, 1.0], 0), (7, 0)):
        spec = write_spec(tmp_path, frames=3, onset=1, identity=identity)
        said = []
        simulate(load_spec(spec), notice=said.append)
        assert len(said) == expected, (identity, said)
        if expected:
            assert "weight 1 is 3.8" in said[0] and "unusual head" in said[0] and str(spec) in said[0]


def test_a_signal_where_python_cannot_raise_is_not_printed_and_still_stops_the_work():
    """SIGTERM inside a finaliser (or an at-fork handler: CI's render was starting its
    encoder) cannot raise there; Python printed "Exception ignored" with a traceback. It
    is kept quiet, recorded, and raised again where the work checks for it. (In a process
    of its own: pytest replaces Python's hook for these with its own.)"""
    code = textwrap.dedent("""
        import os, signal
        from facesim.files import Terminated, check_terminated, handling_termination

        class Finalised:
            def __del__(self):
                os.kill(os.getpid(), signal.SIGTERM)

        try:
            with handling_termination():
                finalised = Finalised()
                del finalised
                print("still working")
                check_terminated()
        except Terminated:
            print("stopped")
    """)
    result = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=60)
    assert result.stdout.split() == ["still", "working", "stopped"]
    assert "Exception ignored" not in result.stderr and "Traceback" not in result.stderr, result.stderr


def test_a_signal_while_the_encoder_starts_leaves_no_file_behind(tmp_path, own_signal_handlers, monkeypatch):
    """CI: a SIGTERM that arrived as the MP4's encoder (ffmpeg) was being started left it
    running with no one to close it; it wrote its file after facesim had removed the
    temporary, and a ``.a.partial-….mp4`` was left beside the spec."""
    import gc

    import imageio_ffmpeg

    from facesim.export.output import write_frames

    start = imageio_ffmpeg.write_frames

    def signalled_as_it_starts(*args, **kwargs):
        writer = start(*args, **kwargs)

        class Starting:
            def send(self, value):
                sent = writer.send(value)
                if value is None:  # ffmpeg has just been started
                    os.kill(os.getpid(), signal.SIGTERM)
                return sent

            def close(self):
                writer.close()

        return Starting()

    monkeypatch.setattr(imageio_ffmpeg, "write_frames", signalled_as_it_starts)
    frames = np.zeros((3, 16, 16, 3), np.uint8)
    with pytest.raises(Terminated):
        write_frames(frames, tmp_path / "a.mp4", "mp4", 10.0)
    gc.collect()  # an encoder left open is closed here, and writes its file
    assert list(tmp_path.iterdir()) == []
