"""`facesim face from-photo`: ICT's head and a camera fitted to a photo's landmarks, the
photo baked into the head's texture, the face directory (facesim.face.fit, facesim.face.bake,
facesim.face.own_face)."""

import importlib.util

import imageio.v3 as iio
import numpy as np
import pytest
import yaml
from conftest import EXPRESSIONS, ROOT, spec
from forked import facesim_process

from facesim.animation.simulate import model_for, simulate
from facesim.config import HEAD
from facesim.errors import InputError
from facesim.face.align import similarity
from facesim.face.figure import figure_for
from facesim.face.head import load_head

pytestmark = pytest.mark.skipif(importlib.util.find_spec("mediapipe") is None,
                                reason="MediaPipe not installed (pip install -e '.[photo]')")


def hopper_photo():
    import matplotlib.cbook

    return matplotlib.cbook.get_sample_data("grace_hopper.jpg", asfileobj=False)


@pytest.fixture(scope="module")
def photos(tmp_path_factory):
    from skimage import data

    astronaut = tmp_path_factory.mktemp("photos") / "astronaut.png"
    iio.imwrite(astronaut, data.astronaut())
    return {"astronaut": astronaut, "hopper": hopper_photo()}


def fitted(path):
    from facesim.face.fit import fit_head
    from facesim.face.photo import detect_landmarks, read_image

    image = read_image(path)
    return fit_head(load_head(HEAD), HEAD, detect_landmarks(image, str(path), refine=True), image.shape[1], image.shape[0], str(path))


@pytest.mark.parametrize("name", ["astronaut", "hopper"])
def test_fitted_landmarks_fall_on_the_photos(photos, name):
    """The fitted head's landmarks, through the fitted camera, within 2% of the face's width
    (median) of where MediaPipe finds them; the faces look at the camera."""
    fit = fitted(photos[name])
    assert np.median(fit.residual) < 0.02
    assert np.percentile(fit.residual, 90) < 0.04
    assert abs(fit.camera.yaw) < 10


def render_head(identity, yaw=0.0, size=512):
    model = model_for(spec("happy").with_overrides(identity=identity))
    from facesim.renderer.scene import FaceRenderer
    from facesim.renderer.settings import RenderSettings
    with FaceRenderer(model.rest_position, model.faces, RenderSettings(size, size, framing="head"),
                      figure=figure_for(model)) as renderer:
        return renderer.render(model.rest_position, pose=[yaw, 0, 0, 0, 0])


def aligned_rms(a, b):
    s, r, t = similarity(a, b)
    return float(np.sqrt(((s * a @ r.T + t - b) ** 2).sum(axis=1).mean()))


def test_fit_recovers_a_known_head(tmp_path):
    """Identity seed 7 rendered in the clay look as a photo: the fitted neutral head is
    within the issue's 0.2 cm RMS of the seed-7 head over the whole head (after a
    similarity), and nearer it than ICT's generic head is. Measured: 0.195 cm against the
    generic head's 0.264. It was 0.208 while the clay head had no eyebrows: MediaPipe then
    guessed the brows' ten points on bare skin (facesim.face.figure.BROW_OUTLINES); over seeds
    0-20 the mean went 0.377 -> 0.374 cm with the brows painted. The same fit to the exact
    landmarks reaches 0.158: what is left is MediaPipe's error on each face."""
    photo = tmp_path / "seed7.png"
    iio.imwrite(photo, render_head(7))
    fit = fitted(photo)
    truth = load_head(HEAD, 7).vertices
    generic = aligned_rms(load_head(HEAD).vertices, truth)
    ours = aligned_rms(load_head(HEAD, list(fit.identity)).vertices, truth)
    assert ours < 0.2
    assert ours < generic - 0.05


def test_face_directory(tmp_path, photos):
    """The directory holds the fitted head (OBJ + MTL + PNG, trimesh loads it textured, ICT's
    vertex order kept), its muscle file, the identity and the camera; the texture carries
    the photo's colours where the camera sees the face."""
    import trimesh

    from facesim.face.fit import Camera
    from facesim.face.own_face import FACE_FILES, face_from_photo, read_obj_vertices
    from facesim.face.photo import read_image

    out = tmp_path / "hopper"
    record = face_from_photo(photos["hopper"], out)
    assert {p.name for p in out.iterdir()} == FACE_FILES | {"facesim-manifest.json"}
    saved = yaml.safe_load((out / "face.yaml").read_text())
    assert saved["identity"] == record["identity"] and len(saved["identity"]) == 100
    camera = Camera.from_dict(saved["camera"], "face.yaml")
    head = load_head(HEAD, saved["identity"])
    assert np.abs(read_obj_vertices(out / "head.obj") - head.vertices).max() < 1e-5

    scene = trimesh.load(out / "head.obj", process=False)
    skin = scene.geometry["M_Face"]
    assert isinstance(skin.visual, trimesh.visual.TextureVisuals) and skin.visual.material.image is not None

    # the nose tip's texel is the photo's pixel at the nose tip
    from facesim.face.bake import atlas_uv

    photo = read_image(photos["hopper"])
    texture = iio.imread(out / "head.png")
    rows, _, uv = atlas_uv(head)
    nose = head.landmarks[4]
    t = np.flatnonzero((head.triangles[rows] == nose).any(axis=1))[0]
    corner = list(head.triangles[rows[t]]).index(nose)
    u, v = uv[t, corner]
    texel = texture[int((1 - v) * texture.shape[0]), int(u * texture.shape[1])].astype(float)
    x, y = camera.project(head.vertices[[nose]])[0]
    pixel = photo[int(y), int(x)].astype(float)
    assert np.abs(texel - pixel).max() < 25


def test_fitted_faces_smile_and_are_surprised_without_folds(photos):
    """happy and surprise simulate on the fitted heads with no inverted triangle
    (simulate raises on one)."""
    for name in ("astronaut", "hopper"):
        identity = [float(w) for w in fitted(photos[name]).identity]
        for expression in ("happy", "surprise"):
            animation = simulate(spec(expression).with_overrides(identity=identity))
            assert animation.inverted.max() == 0


def test_a_face_turned_too_far_is_refused(tmp_path):
    photo = tmp_path / "turned.png"
    iio.imwrite(photo, render_head(None, yaw=45))
    with pytest.raises(InputError, match=r"turned \d+ degrees from the camera, too far to fit \(at most 35\)"):
        fitted(photo)


def test_bad_photos_get_one_line_and_nothing_written(tmp_path, photos):
    from PIL import Image

    from facesim.face.own_face import face_from_photo

    blank = tmp_path / "blank.png"
    iio.imwrite(blank, np.full((300, 300, 3), 200, dtype=np.uint8))
    small = tmp_path / "small.png"
    Image.open(photos["astronaut"]).resize((300, 300)).save(small)
    truncated = tmp_path / "truncated.jpg"
    data = open(hopper_photo(), "rb").read()
    truncated.write_bytes(data[: len(data) // 3])
    cases = {blank: "no face found", small: r"pixels across, too small to fit \(at least 100 needed\)",
             truncated: "not a readable image", tmp_path / "missing.jpg": "photo not found"}
    for photo, message in cases.items():
        out = tmp_path / f"out_{photo.stem}"
        with pytest.raises(InputError, match=message):
            face_from_photo(photo, out)
        assert not out.exists()
    assert sorted(p.name for p in tmp_path.iterdir()) == sorted(["blank.png", "small.png", "truncated.jpg"])


def test_several_faces_use_the_largest_and_say_so(tmp_path, photos):
    from PIL import Image

    from facesim.face.photo import detect_landmarks, read_image

    big = Image.open(photos["hopper"]).convert("RGB")
    group = Image.new("RGB", (big.width * 2, big.height), (128, 128, 128))
    group.paste(big, (0, 0))
    group.paste(big.resize((big.width * 2 // 3, big.height * 2 // 3)), (big.width + 20, 60))
    said = []
    landmarks = detect_landmarks(np.asarray(group), "group.png", said.append)
    assert len(said) == 1 and "2 faces found; using the largest" in said[0]
    alone = detect_landmarks(read_image(photos["hopper"]), "hopper")
    assert np.median(np.linalg.norm(landmarks[:, :2] - alone[:, :2], axis=1)) < 3  # the big one, where it was pasted


def test_command_line(tmp_path, photos):
    from typer.testing import CliRunner

    from facesim.cli import app

    out = tmp_path / "face"
    runner = CliRunner()
    result = runner.invoke(app, ["face", "from-photo", str(photos["astronaut"]), "-o", str(out)])
    assert result.exit_code == 0, result.output
    assert "landmarks within" in result.output
    # her photo smiles with her teeth showing: said, and the face written all the same
    said = [line for line in result.output.splitlines() if "the face is not at rest" in line]
    assert len(said) == 1 and "astronaut.png" in said[0] and "lips 8 mm apart" in said[0], result.output
    again = runner.invoke(app, ["face", "from-photo", str(photos["astronaut"]), "-o", str(out)])
    assert again.exit_code == 2 and "already exists" in again.output
    stranger = tmp_path / "mine"
    stranger.mkdir()
    (stranger / "notes.txt").write_text("mine")
    refused = runner.invoke(app, ["face", "from-photo", str(photos["astronaut"]), "-o", str(stranger), "--force"])
    assert refused.exit_code == 2 and (stranger / "notes.txt").read_text() == "mine"


def test_a_photos_expression_is_measured_against_the_fitted_head_at_rest(tmp_path, photos):
    """What face from-photo bakes into the skin is the photo as it is: a face that is not at
    rest keeps its expression at rest and moves it (the astronaut's smile, teeth and all,
    on closed lips), so it is said. facesim's own head is the known case: at rest it is at
    rest, its surprise parts the lips, its happy apex (lips closed) raises the corners;
    Grace Hopper's portrait is at rest, the astronaut's is not."""
    from facesim.face.fit import PHOTO_AT_REST

    lips, corners = PHOTO_AT_REST
    from facesim.renderer.scene import FaceRenderer
    from facesim.renderer.settings import RenderSettings

    for name, frames in (("happy", (0, 34)), ("surprise", (34,))):
        animation = simulate(spec(name))
        with FaceRenderer.of(animation, RenderSettings(width=512, height=512)) as renderer:
            for frame in frames:
                iio.imwrite(tmp_path / f"{name}{frame}.png", renderer.frame(animation, frame))
    measured = {name: fitted(path).mouth_against_rest() for name, path in (
        ("rest", tmp_path / "happy0.png"), ("smile", tmp_path / "happy34.png"), ("surprise", tmp_path / "surprise34.png"),
        ("hopper", photos["hopper"]), ("astronaut", photos["astronaut"]))}
    assert measured["rest"][0] < lips and measured["rest"][1] < corners, measured
    assert measured["hopper"][0] < lips and measured["hopper"][1] < corners, measured
    assert measured["smile"][0] < lips < measured["surprise"][0] and measured["smile"][1] > corners, measured
    assert measured["astronaut"][0] > 2 * lips and measured["astronaut"][1] > corners, measured


@pytest.fixture(scope="module")
def faces(tmp_path_factory, photos):
    """Both photos' face directories, made once for the module."""
    from facesim.face.own_face import face_from_photo

    root = tmp_path_factory.mktemp("faces")
    for name in ("astronaut", "hopper"):
        face_from_photo(photos[name], root / name)
    return {name: root / name for name in ("astronaut", "hopper")}


def onto_frames(face, photo, expression_or_spec, frames=()):
    """The chosen frames of an expression rendered through the face's fitted camera into its
    photo (the pipeline of `facesim render SPEC --face DIR --onto PHOTO`)."""
    from facesim.face.photo import read_image
    from facesim.renderer.scene import FaceRenderer
    from facesim.renderer.settings import RenderSettings
    height, width = read_image(photo).shape[:2]
    animation = simulate(expression_or_spec.with_overrides(face=face))
    settings = RenderSettings(width, height, look="photo", onto=photo)
    with FaceRenderer.of(animation, settings) as renderer:
        return [renderer.frame(animation, k) for k in frames]


def face_box(photo):
    from facesim.face.photo import detect_landmarks, read_image

    landmarks = detect_landmarks(read_image(photo), str(photo))[:, :2]
    (x0, y0), (x1, y1) = np.floor(landmarks.min(axis=0)).astype(int), np.ceil(landmarks.max(axis=0)).astype(int)
    return slice(y0, y1), slice(x0, x1)


@pytest.mark.parametrize("name", ["astronaut", "hopper"])
def test_the_neutral_head_through_the_photos_camera_is_the_photo(faces, photos, name):
    """Frame 0 (neutral) composited onto the photo matches the photo in the face's bounding
    box with a PSNR of at least 30 dB (measured: 34.2 dB on the astronaut, 34.1 on Hopper),
    and the expression's apex does not (the face moved), while away from the face the
    photo stays as it was."""
    from facesim.face.photo import read_image

    photo = read_image(photos[name]).astype(float)
    neutral, apex = onto_frames(faces[name], photos[name], spec("happy"), frames=(0, 34))
    box = face_box(photos[name])

    def psnr(image):
        return 10 * np.log10(255.0**2 / ((image.astype(float)[box] - photo[box]) ** 2).mean())

    assert neutral.shape == photo.shape
    assert psnr(neutral) >= 30.0
    assert psnr(apex) < 26.0
    outside = np.ones(photo.shape[:2], dtype=bool)
    outside[slice(box[0].start - 40, box[0].stop + 80), slice(box[1].start - 60, box[1].stop + 60)] = False
    change = np.abs(apex.astype(float) - photo).max(axis=2)[outside]  # hair, clothes and background as they were:
    assert (change <= 2).mean() > 0.85 and change.mean() < 2  # (measured: 91% and 0.6 on Hopper, whose cap is re-rendered)


def test_a_blink_closes_the_photos_eyes_and_an_open_mouth_shows_teeth(faces, photos, tmp_path):
    """On Hopper's photo (a closed mouth). AU45 closes both eyes: the lids' skin comes over
    the pupils (MediaPipe's landmarks on the photo: the pupil's patch twice as light,
    measured 2.0x on both eyes, and the dark pixels in each eye's box halved, measured
    0.53x and 0.44x; MediaPipe itself does not see closed eyes closed behind glasses).
    The jaw dropped (AU26 + AU27) opens a mouth MediaPipe sees open, with the head's teeth
    (light, unsaturated pixels) where the photo had closed lips: the lower incisors' edge,
    measured 17 pixels (27 with the jaw's hinge in the head's coordinates, 2 mm from the
    contour points' axis used now)."""
    from facesim.animation.spec import Spec
    from facesim.face.photo import detect_landmarks, read_image

    photo = read_image(photos["hopper"])
    blink = Spec(name="blink", frames=20, onset=10, aus={"AU45": 1.0})
    mouth = Spec(name="mouth", frames=20, onset=10, aus={"AU26": 1.0, "AU27": 1.0})
    (closed,) = onto_frames(faces["hopper"], photos["hopper"], blink, frames=(19,))
    (opened,) = onto_frames(faces["hopper"], photos["hopper"], mouth, frames=(19,))
    p = detect_landmarks(photo, "photo")[:, :2]
    for (upper, lower), ring in (((159, 145), [33, 133, 159, 145, 160, 144, 158, 153]),
                                 ((386, 374), [362, 263, 386, 374, 385, 380, 387, 373])):
        x, y = ((p[upper] + p[lower]) / 2).astype(int)
        pupil = [image[y - 2:y + 3, x - 2:x + 3].astype(float).mean() for image in (photo, closed)]
        assert pupil[1] > 1.5 * pupil[0]
        (x0, y0), (x1, y1) = np.floor(p[ring].min(axis=0)).astype(int), np.ceil(p[ring].max(axis=0)).astype(int)
        dark = [(image[y0:y1 + 1, x0:x1 + 1].astype(float).mean(axis=2) < 70).sum() for image in (photo, closed)]
        assert dark[1] < 0.65 * dark[0]

    q = detect_landmarks(opened, "render")[:, :2]
    assert np.linalg.norm(q[13] - q[14]) > np.linalg.norm(p[13] - p[14]) + 10
    x0, x1 = sorted(q[[78, 308], 0].astype(int))  # the mouth's corners, and its outer lips above and below
    y0, y1 = int(q[0, 1]), int(q[17, 1])

    def teeth(image):
        inside = image[y0:y1, x0:x1].astype(int)
        return ((inside.min(axis=2) > 150) & (np.ptp(inside, axis=2) < 60)).sum()

    assert teeth(opened) > 12 and teeth(photo) < teeth(opened) / 4


def test_the_photo_look_draws_the_baked_photo(faces, photos):
    """--look photo on the default camera: the nose tip's pixel takes the photo's colour
    there (the texture, unlit), --look clay facesim's skin; a face directory brings its
    identity (the fitted head's own shape)."""
    from facesim.renderer.scene import FaceRenderer
    from facesim.renderer.settings import RenderSettings
    animation = simulate(spec("happy").with_overrides(face=faces["hopper"]))
    record = yaml.safe_load((faces["hopper"] / "face.yaml").read_text())
    assert np.allclose(animation.model.mesh.head.vertices, load_head(HEAD, record["identity"]).vertices)
    looks = {}
    for look in ("photo", "clay"):
        with FaceRenderer.of(animation, RenderSettings(256, 256, look=look)) as renderer:
            x, y = renderer.project(animation.model.mesh.head.vertices[[animation.model.mesh.head.landmarks[4]]])[0]
            looks[look] = renderer.render(animation.rest)[int(y) - 2:int(y) + 3, int(x) - 2:int(x) + 3].reshape(-1, 3).mean(axis=0)
    from facesim.face.fit import Camera
    from facesim.face.photo import read_image

    camera = Camera.from_dict(record["camera"], "face.yaml")
    head = animation.model.mesh.head
    px, py = camera.project(head.vertices[[head.landmarks[4]]])[0]
    pixel = read_image(photos["hopper"])[int(py) - 2:int(py) + 3, int(px) - 2:int(px) + 3].reshape(-1, 3).mean(axis=0)
    assert np.abs(looks["photo"] - pixel).max() < 20
    assert np.abs(looks["clay"] - pixel).max() > 20


def test_face_options_and_their_errors(faces, photos, tmp_path):
    """`render --face DIR --onto PHOTO` writes frames of the photo's size; `face:` in a spec
    (relative to it); one line and nothing written for: --onto or --look photo without a
    face, --onto with another photo's shape, a face directory missing a file, face: with
    identity:."""
    import shutil

    from typer.testing import CliRunner

    from facesim.cli import app
    from facesim.face.photo import read_image

    runner = CliRunner()
    out = tmp_path / "frames"
    spec_file = tmp_path / "smile.yaml"
    shutil.copytree(faces["astronaut"], tmp_path / "me")
    spec_file.write_text("frames: 3\naus: {AU12: 1.0}\nface: me\n")
    done = runner.invoke(app, ["render", str(spec_file), "--onto", str(photos["astronaut"]), "-o", str(out)])
    assert done.exit_code == 0, done.output
    assert sorted(p.name for p in out.glob("frame_*.png")) == [f"frame_{k:04d}.png" for k in range(3)]
    assert iio.imread(out / "frame_0000.png").shape == read_image(photos["astronaut"]).shape

    wide = tmp_path / "wide.png"
    iio.imwrite(wide, np.zeros((100, 300, 3), dtype=np.uint8))
    broken = tmp_path / "broken"
    shutil.copytree(faces["astronaut"], broken)
    (broken / "head_onto.png").unlink()
    both = tmp_path / "both.yaml"
    both.write_text("aus: {AU12: 1.0}\nface: me\nidentity: 3\n")
    cases = [
        (["render", "happy", "--onto", str(photos["astronaut"])], "--onto: needs a face directory"),
        (["render", "happy", "--look", "photo"], "--look photo: needs a face directory"),
        (["render", "happy", "--face", str(faces["astronaut"]), "--onto", str(wide)], "was fitted to a photo of 512x512"),
        (["render", "happy", "--face", str(broken)], "head_onto.png missing"),
        (["render", "happy", "--face", str(tmp_path / "nowhere")], f"--face: {tmp_path / 'nowhere'}: not a face directory"),
        (["say", "Hello.", "--face", str(tmp_path / "nowhere")], f"--face: {tmp_path / 'nowhere'}: not a face directory"),
        (["render", str(both)], "face: a face directory brings its own head; leave out identity and mesh"),
        (["render", "happy", "--face", str(faces["astronaut"]), "--look", "plastic"], "--look: expected one of"),
    ]
    for args, message in cases:
        target = tmp_path / "never.mp4"
        result = runner.invoke(app, args + ["-o", str(target)])
        assert result.exit_code == 2 and message in result.output, (args, result.output)
        assert "Traceback" not in result.output and not target.exists()


@pytest.mark.parametrize("field, value", [
    ("translation", [float("nan"), 0.0]), ("translation", [float("inf"), 0.0]), ("translation", [1e9, 0.0]),
    ("scale", 1e300), ("scale", 1e-300), ("scale", 1e9), ("scale", float("inf")), ("width", 0), ("width", -512),
])
def test_an_implausible_fitted_camera_is_one_line_before_anything_is_drawn(faces, photos, tmp_path, field, value):
    """A face.yaml camera with a translation of NaN or inf, or a scale of 1e300, 1e-300 or
    1e9, rendered "wrote 3 frames" of the photo untouched, no head; a scale of inf was a
    traceback after the simulation had started, a width of 0 a ZeroDivisionError, and a
    width of -512 passed the check and failed later."""
    import shutil

    import yaml

    face = tmp_path / "me"
    shutil.copytree(faces["astronaut"], face)
    record = yaml.safe_load((face / "face.yaml").read_text())
    record["camera"][field] = value
    (face / "face.yaml").write_text(yaml.safe_dump(record))
    target = tmp_path / "a.gif"
    result = facesim_process(["render", "happy", "--face", str(face), "--onto", str(photos["astronaut"]), "-o",
                              str(target)], timeout=300)
    assert result.returncode == 2 and "Traceback" not in result.stderr, result.stderr
    (line,) = result.stderr.strip().splitlines()
    assert str(face / "face.yaml") in line and "camera" in line and field.split("_")[0] in line, line
    assert not target.exists()


def test_onto_draws_the_same_photo_with_either_backend(faces, photos, tmp_path):
    """--onto reads the frame's alpha back with its colour: with OSMesa, whose frame
    pyrender read without alpha, it stopped with a traceback (IndexError); now both
    backends lay the same face over the photo."""
    drawn = {}
    for backend in ("egl", "osmesa"):
        out = tmp_path / f"{backend}.png"
        result = facesim_process(["render", "happy", "--face", str(faces["astronaut"]), "--onto",
                                  str(photos["astronaut"]), "--frame", "30", "--backend", backend, "-o", str(out)],
                                 cwd=ROOT, timeout=600)
        assert result.returncode == 0, result.stderr
        drawn[backend] = iio.imread(out).astype(int)
    from facesim.face.photo import read_image

    photo = read_image(photos["astronaut"]).astype(int)
    box = face_box(photos["astronaut"])
    assert np.abs(drawn["egl"][box] - photo[box]).mean() > 2  # the face smiles over the photo
    assert np.abs(drawn["egl"] - drawn["osmesa"]).max() <= 4 and np.abs(drawn["egl"] - drawn["osmesa"]).mean() < 0.05


def test_onto_photos_too_small_or_too_large(faces, photos, tmp_path):
    """A 1x1 photo given to --onto was reported as a bad --size nobody gave; an 8000x8000
    one took 102 s and 8 GB for three frames with no word. Now the first is refused naming
    the photo, the second drawn at 2048 pixels on its longer side, said once."""
    import shutil

    from PIL import Image

    face = tmp_path / "me"
    shutil.copytree(faces["astronaut"], face)
    tiny, large = tmp_path / "tiny.png", tmp_path / "large.png"
    Image.new("RGB", (1, 1)).save(tiny)
    Image.open(photos["astronaut"]).resize((4096, 4096)).save(large)
    spec = tmp_path / "two.yaml"
    spec.write_text("frames: 2\naus: {AU12: 1.0}\n")

    def render(photo, target):
        return facesim_process(["render", str(spec), "--face", str(face), "--onto", str(photo), "-o", str(target)],
                               timeout=600)

    refused = render(tiny, tmp_path / "tiny_out")
    assert refused.returncode == 2 and str(tiny) in refused.stderr and "--size" not in refused.stderr
    assert len(refused.stderr.strip().splitlines()) == 1 and not (tmp_path / "tiny_out").exists()
    drawn = render(large, tmp_path / "large_out")
    assert drawn.returncode == 0, drawn.stderr
    notices = [line for line in drawn.stderr.splitlines() if "drawn at 2048x2048" in line]
    assert len(notices) == 1, drawn.stderr
    assert iio.imread(tmp_path / "large_out" / "frame_0001.png").shape == (2048, 2048, 3)


def test_a_face_yamls_numbers_are_refused_in_one_line_or_plausible(faces, tmp_path):
    """A seeded loop of out-of-range and non-finite values in face.yaml's identity weights
    and camera: each is refused with one line naming face.yaml, or loads as a camera and
    an identity within the documented bounds (facesim.face.fit.PHOTO_SIDE, HEAD_SPAN;
    facesim.face.head.IDENTITY_LIMIT)."""
    import random
    import shutil

    import yaml

    from facesim.face.fit import HEAD_SPAN, HEAD_WIDTH, PHOTO_SIDE
    from facesim.face.head import IDENTITY_LIMIT
    from facesim.face.own_face import load_face_directory

    rng = random.Random(44)
    bad = [float("nan"), float("inf"), -float("inf"), 1e300, -1e300, 1e9, -5.0, 0.0, 1e-300, 5.0, 0.25]
    record = yaml.safe_load((faces["astronaut"] / "face.yaml").read_text())
    fields = [("identity", k) for k in range(100)] + [("camera", "scale"), ("camera", "kappa"), ("camera", "width"),
                                                      ("camera", "height"), ("camera", "translation", 0),
                                                      ("camera", "translation", 1), ("camera", "rotation", 0, 0)]
    outcomes = set()
    for case in range(30):
        field, value = rng.choice(fields), rng.choice(bad)
        face = tmp_path / f"face{case}"
        shutil.copytree(faces["astronaut"], face)
        changed = yaml.safe_load(yaml.safe_dump(record))
        node = changed
        for key in field[:-1]:
            node = node[key]
        node[field[-1]] = value
        (face / "face.yaml").write_text(yaml.safe_dump(changed))
        try:
            loaded = load_face_directory(face)
        except InputError as error:
            assert "\n" not in str(error) and str(face / "face.yaml") in str(error), (field, value, error)
            outcomes.add("refused")
            continue
        camera = loaded.camera
        assert np.isfinite(loaded.identity).all() and np.abs(loaded.identity).max() <= IDENTITY_LIMIT, (field, value)
        assert PHOTO_SIDE[0] <= min(camera.width, camera.height) and max(camera.width, camera.height) <= PHOTO_SIDE[1]
        assert HEAD_SPAN[0] <= camera.scale * HEAD_WIDTH / camera.width <= HEAD_SPAN[1] and np.isfinite(camera.translation).all()
        outcomes.add("loaded")
    assert outcomes == {"refused", "loaded"}


@pytest.mark.parametrize("name, message", [("muscles.yaml", "no face's muscle"),
                                           ("face.yaml", "beyond 4.5 standard deviations")])
def test_a_face_directorys_implausible_muscles_or_identity_are_one_line(faces, tmp_path, name, message):
    """A face directory's muscles.yaml with a force of 1e150 ran to a face that never moved
    (exit 0); its face.yaml with weights of 5.0 on all 100 modes drew a torn head."""
    import shutil

    import yaml

    face = tmp_path / "me"
    shutil.copytree(faces["astronaut"], face)
    data = yaml.safe_load((face / name).read_text())
    if name == "muscles.yaml":
        data["muscles"][0]["force"] = 1e150
    else:
        data["identity"] = [5.0] * 100
    (face / name).write_text(yaml.safe_dump(data))
    target = tmp_path / "a.mp4"
    result = facesim_process(["render", "happy", "--face", str(face), "-o", str(target), "--size", "64x64"],
                             timeout=300)
    assert result.returncode == 2 and "Traceback" not in result.stderr, result.stderr
    (line,) = result.stderr.strip().splitlines()
    assert str(face / name) in line and message in line, line
    assert not target.exists()


def test_two_faces_side_by_side_are_found_and_the_choice_said(photos):
    """Two faces side by side in one photo gave "no face found": MediaPipe's detector sees
    the photo squeezed into its square, where each face is too small. Square crops of the
    photo are looked in too; both faces are found, one is used, and that is said once."""
    from facesim.face.photo import detect_landmarks, read_image

    one = read_image(photos["astronaut"])
    said = []
    landmarks = detect_landmarks(np.concatenate([one, one], axis=1), "two.png", said.append)
    alone = detect_landmarks(one, "one.png")
    assert said == [said[0]] and "2 faces found" in said[0]
    offset = landmarks[:, :2] - alone[:, :2]  # the same face, in one half or the other
    assert np.abs(offset - np.median(offset, axis=0)).max() < 0.05 * np.ptp(alone[:, 0])
    assert np.allclose(np.median(offset, axis=0), (0, 0), atol=3) or np.allclose(np.median(offset, axis=0), (512, 0), atol=3)


def test_a_face_directorys_rig_carries_its_photo_to_three_js(faces, tmp_path):
    """`facesim rig --face DIR` (issue 47): the Khronos validator finds no error or warning;
    the first 26,719 vertices are the fitted head's, in ICT's order, and each one after is a
    copy of the ICT vertex ``extras.seams`` names (split where the atlas's islands meet),
    moved by every target as its ICT vertex is; the photo's parts take the directory's own
    atlas. Drawn by three.js, the face reads as facesim's photo look draws it: the colour
    under each of MediaPipe's landmarks, found in both pictures, correlates at least 0.9
    (measured 0.96; with the texture upside down, -0.38)."""
    from test_cli import facesim
    from test_export import Glb, three_js_screenshot, validator_report

    from facesim.export.gltf import METRES
    from facesim.face.photo import detect_landmarks

    face = faces["astronaut"]
    facesim("rig", "--face", face, "-o", tmp_path / "astronaut.glb", check=0)
    report = validator_report(tmp_path / "astronaut.glb")
    assert report["issues"]["numErrors"] == 0 and report["issues"]["numWarnings"] == 0, report["issues"]["messages"][:5]
    assert report["info"]["hasTextures"] and report["info"]["hasMorphTargets"]

    glb = Glb(tmp_path / "astronaut.glb")
    assert glb.size <= 15 * 2**20  # issue 47's bound on a rig, its photo in it (measured: 11.9 MB)
    head = load_head(HEAD, yaml.safe_load((face / "face.yaml").read_text())["identity"])
    n = len(head.vertices)
    attributes = glb.mesh["primitives"][0]["attributes"]
    rest = glb.accessor(attributes["POSITION"]).astype(np.float64) / METRES
    seams = np.array(glb.mesh["extras"]["seams"])
    assert len(rest) == n + len(seams) and len(seams) > 0
    assert np.abs(rest[:n] - head.vertices).max() < 1e-4
    assert np.array_equal(rest[n:], rest[seams])
    smile = glb.target("mouthSmileLeft")
    assert np.abs(smile[:n]).max() > 1e-3 and np.array_equal(smile[n:], smile[seams])
    image = glb.json["images"][0]
    view = glb.json["bufferViews"][image["bufferView"]]
    assert glb.blob[view.get("byteOffset", 0):view.get("byteOffset", 0) + view["byteLength"]] == (face / "head.png").read_bytes()
    textured = {m["name"] for m in glb.json["materials"] if "baseColorTexture" in m["pbrMetallicRoughness"]}
    assert textured == {"M_Face", "M_BackHead", "M_ScleraLeft", "M_IrisLeft", "M_ScleraRight", "M_IrisRight"}

    three = three_js_screenshot(tmp_path, "astronaut.glb", 0.0, tmp_path / "three.png")
    facesim("render", EXPRESSIONS / "happy.yaml", "--face", face, "--look", "photo", "--frame", 0, "-o", tmp_path / "ours.png",
            check=0)
    ours = iio.imread(tmp_path / "ours.png")[:, :, :3]

    def under_landmarks(picture, source):
        points = np.rint(detect_landmarks(picture, source)[:468, :2]).astype(int)
        patches = np.stack([picture[y - 2:y + 3, x - 2:x + 3].reshape(-1, 3).mean(axis=0) for x, y in points])
        return patches.mean(axis=1)

    a, b = under_landmarks(three, "three.js"), under_landmarks(ours, "facesim")
    assert np.corrcoef(a, b)[0, 1] >= 0.9, np.corrcoef(a, b)[0, 1]
