"""Performance capture (issue 49): a face video read back into ARKit's shapes, the head's
pose and the gaze (facesim.capture), checked by round trips: known curves rendered by
facesim, captured, and compared with the curves that made them."""

import re

import imageio.v3 as iio
import numpy as np
import pytest
from forked import facesim_process

import facesim
from facesim.animation.spec import Spec, load_spec, pose_table
from facesim.capture.performance import capture
from facesim.capture.solver import SOLVED
from facesim.errors import InputError
from facesim.renderer.settings import RenderSettings

pytest.importorskip("mediapipe")

FPS = 25
#: The round trip's curves (expressions/performance.yaml): smooth and sparse, two jaw
#: openings, two blinks, a smile, the inner brows, and the head turned 25 degrees to the
#: subject's left and 20 to the right while it nods.
PERFORMANCE = load_spec("performance")
#: The controls each must be captured with a Pearson correlation of at least 0.9.
MAIN = ("jawOpen", "eyeBlinkLeft", "eyeBlinkRight", "mouthSmileLeft", "mouthSmileRight")


def rendered(tmp_path, name: str, settings=RenderSettings(width=320, height=320), **changes) -> tuple[Spec, object]:
    spec = PERFORMANCE.with_overrides(name=name, **changes)
    path = tmp_path / f"{name}.mp4"
    facesim.render(facesim.simulate(spec), path, settings)
    return spec, path


def agreement(spec, performance) -> dict:
    """Per control that moves: the Pearson correlation of the captured curve with the
    true one, and the lag (frames) at which their cross-correlation peaks."""
    out = {}
    for track in spec.timeline:
        true = track.values(spec.dt, spec.frames)
        got = performance.weights[:, SOLVED.index(track.target)]
        lags = np.correlate(got - got.mean(), true - true.mean(), "full")
        out[track.target] = (float(np.corrcoef(true, got)[0, 1]), int(np.argmax(lags)) - (spec.frames - 1))
    return out


def test_the_default_heads_basis_ships_measured_from_this_code(tmp_path, monkeypatch):
    """A new user's first capture loads the default head's basis from the package, not
    measuring it for 20 s (facesim.capture.solver.SHIPPED_BASIS): it is this code's (an
    edit to the solver needs `python scripts/build_kernels.py --capture-basis`), and it is
    the head's: opening the jaw moves the chin down, a blink closes its own eye's lids."""
    from facesim.capture import solver

    monkeypatch.setenv("FACESIM_CACHE", str(tmp_path))  # nothing cached
    monkeypatch.setattr(solver, "_rendered", lambda *args, **kwargs: pytest.fail(
        "the shipped capture basis is not this code's: run `python scripts/build_kernels.py --capture-basis`"))
    basis = solver.head_basis(Spec(name="capture"))
    assert basis.motion.shape == (len(SOLVED), 470, 3) and basis.turns["grid_residual"].shape[2:] == (468, 2)
    motion = {name: basis.motion[SOLVED.index(name)] for name in ("jawOpen", "eyeBlinkLeft", "eyeBlinkRight")}
    assert motion["jawOpen"][152, 1] < -1.0  # the chin, cm per unit weight
    for blink, (upper, lower), other in (("eyeBlinkLeft", (386, 374), (159, 145)), ("eyeBlinkRight", (159, 145), (386, 374))):
        gap = motion[blink][:, 1]
        assert gap[upper] - gap[lower] < -0.4 and abs(gap[other[0]] - gap[other[1]]) < 0.1
    assert not list(tmp_path.glob("capture-basis-*"))  # nor kept again in the cache


@pytest.fixture(scope="module")
def round_trip(tmp_path_factory):
    root = tmp_path_factory.mktemp("capture")
    spec, video = rendered(root, "performance")
    performance = capture(video, root / "performance.yaml", curves=root / "performance.csv", plot=root / "performance.png")
    return spec, video, performance, root


def check_round_trip(spec, performance):
    """The issue's bar: a Pearson correlation of at least 0.85 averaged over the controls
    that move, 0.9 for the jaw, the blinks and the smiles; the head within 3 degrees."""
    correlations = {name: round(r, 3) for name, (r, _) in agreement(spec, performance).items()}
    assert np.mean(list(correlations.values())) >= 0.85, correlations
    assert all(correlations[name] >= 0.9 for name in MAIN), correlations
    truth = pose_table(spec)[:, :3]
    assert np.abs(performance.head - truth).max() <= 3.0, np.abs(performance.head - truth).max(axis=0)


def check_no_lag(spec, performance):
    """No lag: the jaw's, the blinks' and the smiles' cross-correlations with the true
    curves peak at lag 0."""
    lags = {name: lag for name, (_, lag) in agreement(spec, performance).items()}
    assert all(lags[name] == 0 for name in MAIN), lags


def test_a_performance_rendered_by_facesim_is_captured_back(round_trip):
    spec, _, performance, _ = round_trip
    check_round_trip(spec, performance)


def test_the_captured_curves_peak_with_the_true_ones(round_trip):
    spec, _, performance, _ = round_trip
    check_no_lag(spec, performance)


def test_shapes_the_performance_does_not_move_stay_near_rest(round_trip):
    """The head turns 25 degrees each way and nods while the face makes six shapes: the
    other shapes, read from MediaPipe's misreadings of a turned face, are held down by the
    solve's sparsity prior (facesim.capture.solver.SPARSITY; the largest 0.46, jawForward;
    with the ridge alone eyeWideRight reached 0.92 and three others 0.7-0.8)."""
    spec, _, performance, _ = round_trip
    moved = {track.target for track in spec.timeline}
    others = {name: round(float(performance.weights[:, k].max()), 2)
              for k, name in enumerate(SOLVED) if name not in moved}
    assert max(others.values()) < 0.6, sorted(others.items(), key=lambda item: -item[1])[:5]


def test_the_capture_is_a_spec_that_replays_on_another_face_and_curves_in_live_link_layout(round_trip):
    from facesim.export.rig import LIVE_LINK_COLUMNS

    spec, _, performance, root = round_trip
    written = load_spec(root / "performance.yaml")
    assert (written.frames, written.fps) == (spec.frames, FPS) and abs(written.dt - 1 / FPS) < 1e-9
    replay = facesim.simulate(written.with_overrides(identity=7))
    jaw = replay.activations[:, replay.muscle_names.index("jaw")]
    true_jaw = next(t for t in spec.timeline if t.target == "jawOpen").values(spec.dt, spec.frames)
    assert np.corrcoef(jaw, true_jaw)[0, 1] > 0.9  # the replay opens the jaw when the source did
    assert np.abs(pose_table(written)[:, 0] - performance.head[:, 0]).max() < 0.5  # the head turns, key-framed
    rows = (root / "performance.csv").read_text().splitlines()
    assert tuple(rows[0].split(",")) == LIVE_LINK_COLUMNS and len(rows) == spec.frames + 1
    column = LIVE_LINK_COLUMNS.index("JawOpen")
    assert np.corrcoef([float(r.split(",")[column]) for r in rows[1:]], true_jaw)[0, 1] > 0.9
    assert iio.imread(root / "performance.png").shape[2] in (3, 4)


@pytest.fixture(scope="module")
def held_out(tmp_path_factory):
    """A face the solver was not built on (its shapes are the default head's)."""
    root = tmp_path_factory.mktemp("identity")
    spec, video = rendered(root, "identity7", identity=7)
    return spec, capture(video, root / "identity7.yaml")


def test_a_held_out_identity_is_captured_back(held_out):
    check_round_trip(*held_out)


def test_a_held_out_identitys_curves_peak_with_the_true_ones(held_out):
    check_no_lag(*held_out)


def test_frames_without_a_face_are_bridged_and_said(round_trip, tmp_path):
    spec, video, _, _ = round_trip
    frames = iio.imread(video)
    frames[60:64] = 235  # four blank frames mid-smile
    gappy = tmp_path / "gappy.mp4"
    iio.imwrite(gappy, frames, fps=FPS, codec="libx264", macro_block_size=1)
    said = []
    performance = capture(gappy, tmp_path / "gappy.yaml", notice=said.append)
    assert performance.missing == [60, 61, 62, 63]
    assert any("no face found in 4 frames (60-63)" in s and "bridged" in s for s in said), said
    smile = performance.weights[:, SOLVED.index("mouthSmileLeft")]
    assert smile[60:64].min() > 0.5 * smile[55:70].max()  # held across the gap, not dropped to neutral


def test_the_largest_of_several_faces_is_followed_and_said(round_trip, tmp_path):
    spec, video, _, _ = round_trip
    frames = iio.imread(video)[:40]
    small = frames[:, ::2, ::2]
    pair = np.full((40, 320, 480, 3), 235, np.uint8)
    pair[:, :, :320] = frames
    pair[:, 80:240, 320:] = small
    two = tmp_path / "two.mp4"
    iio.imwrite(two, pair, fps=FPS, codec="libx264", macro_block_size=1)
    said = []
    performance = capture(two, tmp_path / "two.yaml", notice=said.append)
    assert sum("more than one face" in s for s in said) == 1
    true_jaw = next(t for t in spec.timeline if t.target == "jawOpen").values(spec.dt, spec.frames)[:40]
    assert np.corrcoef(performance.weights[:, SOLVED.index("jawOpen")], true_jaw)[0, 1] > 0.9


#: The round trip's clip cut to start half-way into its first jaw opening (frame 20, the
#: jaw at 0.5), its first ten frames (at rest, facing the camera) moved to the end.
NOT_AT_REST = list(range(20, 100)) + list(range(10))


def test_a_video_that_does_not_start_at_rest_is_said_and_read_from_the_neutral_given(round_trip, tmp_path):
    spec, video, performance, _ = round_trip
    assert performance.unsettled is None and performance.neutral == (0, 7)  # the round trip starts at rest
    cut = tmp_path / "cut.mp4"
    iio.imwrite(cut, iio.imread(video)[NOT_AT_REST], fps=FPS, codec="libx264", macro_block_size=1)
    true = {track.target: track.values(spec.dt, spec.frames)[NOT_AT_REST] for track in spec.timeline}

    def correlation(performance, name):
        return np.corrcoef(performance.weights[:, SOLVED.index(name)], true[name])[0, 1]

    said = []
    from_start = capture(cut, tmp_path / "start.yaml", notice=said.append)
    warned = [s for s in said if "not its usual face" in s]
    assert len(warned) == 1 and "the lips' gap" in warned[0] and "--neutral" in warned[0], said
    assert "measured from its face at 0.0-0.3 s" in warned[0], warned
    suggested = float(re.search(r"most usual from ([0-9.]+) s", warned[0]).group(1))
    assert suggested >= 2.8, warned  # its frames from 70 on (the clip's 90-99, then 0-9) are at rest
    assert correlation(from_start, "jawOpen") < 0.8  # measured from a jaw half open: what the notice warns of

    said.clear()
    given = capture(cut, tmp_path / "given.yaml", notice=said.append, neutral_at=3.2)
    assert not [s for s in said if "usual face" in s], said
    assert given.neutral == (80, 87)
    assert "# expressions measured from the face at 3.20-3.52 s" in (tmp_path / "given.yaml").read_text()
    correlations = {name: round(correlation(given, name), 3) for name in true}
    assert min(correlations[name] for name in MAIN) >= 0.9 and np.mean(list(correlations.values())) >= 0.85, correlations
    assert np.abs(given.head - pose_table(spec)[NOT_AT_REST, :3]).max() <= 3.0

    frames = iio.imread(cut)
    frames[70:] = 235  # the face gone from 2.8 s on
    gone = tmp_path / "gone.mp4"
    iio.imwrite(gone, frames, fps=FPS, codec="libx264", macro_block_size=1)
    with pytest.raises(InputError, match=r"gone.mp4: no face found from 3 s on, where --neutral"):
        capture(gone, tmp_path / "gone.yaml", neutral_at=3.0)
    assert not (tmp_path / "gone.yaml").exists()


@pytest.fixture(scope="module")
def photo_clips(tmp_path_factory):
    """The round trip's curves on the astronaut's face directory (scikit-image's portrait
    through `face from-photo`): in its photo look, and drawn --onto her photo, each
    captured back. A textured face is read worse than facesim's clay (docs/capture.md)."""
    from skimage import data

    from facesim.face.own_face import face_from_photo

    root = tmp_path_factory.mktemp("photo_clips")
    photo = root / "astronaut.png"
    iio.imwrite(photo, data.astronaut())
    face_from_photo(photo, root / "astronaut")
    clips = {}
    for name, settings in (("photo look", RenderSettings(width=320, height=320, look="photo")),
                           ("onto", RenderSettings(onto=photo, width=512, height=512))):
        spec, video = rendered(root, name.replace(" ", "_"), settings, face=root / "astronaut")
        clips[name] = spec, capture(video, root / f"{name.replace(' ', '_')}.yaml")
    return clips


READ_WELL = ("jawOpen", "eyeBlinkLeft", "eyeBlinkRight", "mouthSmileLeft")


@pytest.mark.parametrize("clip, held, head", [("photo look", READ_WELL, 6.0), ("onto", READ_WELL, 10.0)])
def test_a_photos_face_animated_is_captured_back_on_the_side_it_reads(photo_clips, clip, held, head):
    """The astronaut's face in its photo look and drawn --onto her photo (92 pixels across
    in the 512-pixel photo): the jaw, the blinks and the left smile come back at 0.8 or
    more (docs/capture.md: 0.90-0.97; the blinks since the sparsity prior) and the head
    within a few degrees; her right smile, her inner brows and the head's angles are the
    full bar's failure, below."""
    spec, performance = photo_clips[clip]
    correlations = {name: round(r, 3) for name, (r, _) in agreement(spec, performance).items()}
    assert all(correlations[name] >= 0.8 for name in held), correlations
    assert np.abs(performance.head - pose_table(spec)[:, :3]).max() <= head


def test_a_textured_face_is_read_with_its_own_turns(photo_clips, round_trip):
    """A turned face is misread differently on every face: the capture measures it on a
    face fitted to the video's neutral frame too, and keeps what the frames fit better
    (docs/capture.md): the subject's own for the astronaut's textured face, the default
    head's for facesim's clay, and the written spec says which."""
    assert all(photo_clips[clip][1].turns_read_on.startswith("the subject's face") for clip in photo_clips)
    _, _, performance, root = round_trip
    assert performance.turns_read_on == "facesim's default head"
    assert "misreading as measured on facesim's default head" in (root / "performance.yaml").read_text()


@pytest.mark.xfail(strict=True, reason="a textured face's right smile comes back at 0.79-0.86, its inner brows at "
                   "0.55-0.57 and the head 4.8-8.7 degrees off (docs/capture.md)")
@pytest.mark.parametrize("clip", ["photo look", "onto"])
def test_a_photos_face_animated_is_captured_back(photo_clips, clip):
    check_round_trip(*photo_clips[clip])


def facesim_command(*args, cwd):
    return facesim_process(list(args), cwd=cwd)


def test_bad_videos_are_one_line_and_nothing_written(tmp_path):
    blank = tmp_path / "blank.mp4"
    iio.imwrite(blank, np.full((10, 64, 64, 3), 200, np.uint8), fps=FPS, codec="libx264", macro_block_size=1)
    (tmp_path / "notes.mp4").write_text("not a video")
    (tmp_path / "frames").mkdir()
    cases = [
        (["blank.mp4", "-o", "a.yaml"], "blank.mp4: no face found in any of its 10 frames"),
        (["notes.mp4", "-o", "a.yaml"], "notes.mp4: not a video ffmpeg can read"),
        (["missing.mp4", "-o", "a.yaml"], "missing.mp4: no such video or directory of frames"),
        (["frames", "-o", "a.yaml"], "frames: a directory with no frames in it"),
        (["blank.mp4", "-o", "a.txt"], "-o: a.txt: expected a .yaml or .yml file"),
        (["blank.mp4", "-o", "a.yaml", "--curves", "a.yaml"], "--curves: a.yaml: expected a .csv file"),
        (["blank.mp4", "-o", "a.yaml", "--fps", "0"], "--fps: expected frames per second between 0 and 240"),
        (["blank.mp4", "-o", "a.yaml", "--neutral", "2"], "--neutral: expected a time within blank.mp4 (0-0.4 s), got 2"),
    ]
    before = sorted(p.name for p in tmp_path.iterdir())
    for args, message in cases:
        result = facesim_command("capture", *args, cwd=tmp_path)
        assert result.returncode == 2 and message in result.stderr and "Traceback" not in result.stderr, (args, result.stderr)
        assert len(result.stderr.strip().splitlines()) == 1, result.stderr
    assert sorted(p.name for p in tmp_path.iterdir()) == before
