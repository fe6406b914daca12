"""The face for other tools (issue 47): ``facesim rig -o head.glb`` and ``facesim render
x.yaml -o x.glb`` (glTF 2.0: ARKit's 52 shapes baked by the physics, a skeleton, the clip)
checked by the Khronos glTF-Validator and played by three.js in headless Chromium, and
``-o x.csv`` (ARKit's curves in Live Link Face's layout). The GLB's arrays are read here
from its bytes with NumPy alone (``Glb``), not through facesim's writer."""

import json
import shutil
import subprocess
import sys
from pathlib import Path

import imageio.v3 as iio
import numpy as np
import pytest
from conftest import EXPRESSIONS
from test_cli import facesim, one_line_error

from facesim.animation.arkit import ARKIT_52
from facesim.animation.blendshapes import bake, unturned
from facesim.animation.calibration import FACE_AREA
from facesim.animation.simulate import model_for, simulate
from facesim.animation.spec import load_spec
from facesim.export.gltf import JOINTS, METRES
from facesim.export.rig import LIVE_LINK_COLUMNS
from facesim.face.figure import figure_for

JS = Path(__file__).parent / "js"
HAPPY = EXPRESSIONS / "happy.yaml"
_COMPONENTS = {5121: np.uint8, 5122: np.int16, 5123: np.uint16, 5125: np.uint32, 5126: np.float32}
_WIDTH = {"SCALAR": 1, "VEC3": 3, "VEC4": 4, "MAT4": 16}


class Glb:
    """A GLB's JSON and binary chunk, and its accessors as arrays (sparse ones filled in)."""

    def __init__(self, path: Path):
        data = path.read_bytes()
        assert data[:4] == b"glTF" and int.from_bytes(data[8:12], "little") == len(data)
        length = int.from_bytes(data[12:16], "little")
        self.json = json.loads(data[20:20 + length])
        self.blob = data[28 + length:]
        self.size = len(data)

    def _view(self, index: int, offset: int, dtype, count: int) -> np.ndarray:
        view = self.json["bufferViews"][index]
        start = view.get("byteOffset", 0) + offset
        return np.frombuffer(self.blob, dtype=dtype, count=count, offset=start)

    def accessor(self, index: int) -> np.ndarray:
        a = self.json["accessors"][index]
        width = _WIDTH[a["type"]]
        dtype = _COMPONENTS[a["componentType"]]
        if "bufferView" in a:
            out = self._view(a["bufferView"], a.get("byteOffset", 0), dtype, a["count"] * width).copy()
        else:
            out = np.zeros(a["count"] * width, dtype=dtype)
        out = out.reshape(a["count"], width)
        if "sparse" in a:
            s = a["sparse"]
            rows = self._view(s["indices"]["bufferView"], 0, _COMPONENTS[s["indices"]["componentType"]], s["count"])
            out[rows.astype(np.int64)] = self._view(s["values"]["bufferView"], 0, dtype, s["count"] * width).reshape(-1, width)
        if a.get("normalized") and dtype == np.int16:  # KHR_mesh_quantization's signed shorts
            return np.maximum(out / 32767.0, -1.0)
        return out

    @property
    def mesh(self) -> dict:
        return self.json["meshes"][0]

    def target(self, name: str, attribute: str = "POSITION") -> np.ndarray:
        k = self.mesh["extras"]["targetNames"].index(name)
        return self.accessor(self.mesh["primitives"][0]["targets"][k][attribute]).astype(np.float64)

    def played(self, weights: np.ndarray) -> np.ndarray:
        """(N, 3) cm: the rest plus the weighted targets, as an engine plays them."""
        x = self.accessor(self.mesh["primitives"][0]["attributes"]["POSITION"]).astype(np.float64)
        for name, w in zip(self.mesh["extras"]["targetNames"], weights):
            if w:
                x += w * self.target(name)
        return x / METRES

    def clip_weights(self) -> np.ndarray:
        """(frames, targets) the clip's morph weights."""
        animation = self.json["animations"][0]
        channel = next(c for c in animation["channels"] if c["target"]["path"] == "weights")
        output = self.accessor(animation["samplers"][channel["sampler"]]["output"])
        return output.reshape(-1, len(self.mesh["extras"]["targetNames"]))


def validator_report(path: Path) -> dict:
    result = subprocess.run(["node", str(JS / "validate.mjs"), str(path)], capture_output=True, text=True, timeout=300)
    assert result.returncode == 0, result.stderr
    return json.loads(result.stdout)


@pytest.fixture(scope="module")
def exported(tmp_path_factory):
    """The default head's rig, happy's clip and happy's curves, written by the command line."""
    out = tmp_path_factory.mktemp("export")
    rig = facesim("rig", "-o", out / "head.glb", check=0)
    clip = facesim("render", HAPPY, "-o", out / "happy.glb", check=0)
    curves = facesim("render", HAPPY, "-o", out / "happy.csv", check=0)
    facesim("render", HAPPY, "-o", out / "happy.pc2", check=0)
    facesim("render", HAPPY, "-o", out / "happy.usdc", check=0)
    facesim("render", HAPPY, "-o", out / "happy.npz", check=0)
    return out, rig.stderr, clip.stderr, curves.stderr


@pytest.fixture(scope="module")
def happy():
    spec = load_spec(HAPPY)
    return spec, simulate(spec), bake(spec)


@pytest.mark.heavy(40)
def test_the_rig_and_the_clip_pass_the_khronos_validator(exported):
    out, *_ = exported
    for name, animations in (("head.glb", 0), ("happy.glb", 1)):
        report = validator_report(out / name)
        issues = report["issues"]
        assert issues["numErrors"] == 0 and issues["numWarnings"] == 0, issues["messages"][:5]
        info = report["info"]
        assert info["hasMorphTargets"] and info["hasSkins"] and info["animationCount"] == animations


def test_the_rig_is_icts_head_in_its_vertex_order_with_arkits_52_named_shapes(exported, happy):
    out, rig_line, *_ = exported
    spec, animation, shapes = happy
    rig = Glb(out / "head.glb")
    assert rig.mesh["extras"]["targetNames"] == list(ARKIT_52)
    primitives = rig.mesh["primitives"]
    assert all(len(p["targets"]) == 52 for p in primitives)
    rest = rig.accessor(primitives[0]["attributes"]["POSITION"])
    figure = figure_for(model_for(spec))
    assert rest.shape == (26719, 3)
    np.testing.assert_array_equal(rest, (figure.rest * METRES).astype(np.float32))  # ICT's order, in metres
    materials = [rig.json["materials"][p["material"]]["name"] for p in primitives]
    assert materials == [p.name for p in figure.parts]
    for p, part in zip(primitives, figure.parts):  # each part's triangles, as ICT's OBJ has them
        np.testing.assert_array_equal(rig.accessor(p["indices"]).reshape(-1, 3), part.triangles)
    assert [n["name"] for n in rig.json["nodes"][:len(JOINTS)]] == list(JOINTS)
    assert rig.size <= 15 * 2**20  # issue 47's bound
    assert "52 ARKit shapes" in rig_line


def test_a_target_is_the_physics_shape_and_moves_the_face_as_its_name_says(exported, happy):
    """mouthSmileLeft's offsets are facesim's baked shape (to the sparse storage's 0.01 mm)
    and lift the subject's left mouth corner up and outward, the right one barely; jawOpen
    drops the chin and the lower incisors with it; eyeBlinkLeft closes the left lids."""
    out, *_ = exported
    spec, animation, shapes = happy
    rig = Glb(out / "head.glb")
    head = animation.model.mesh.head
    for name in ("mouthSmileLeft", "jawOpen", "eyeBlinkLeft"):
        ours = shapes.deltas[ARKIT_52.index(name)].astype(np.float64)
        theirs = rig.target(name) / METRES
        assert np.abs(theirs - ours).max() < 1.1e-3
    smile = rig.target("mouthSmileLeft") / METRES
    left, right = (head.landmarks[c] for c in (291, 61))  # MediaPipe's mouth corners: 291 on the subject's left
    assert smile[left, 1] > 0.3 and smile[left, 0] > 0.2 and np.linalg.norm(smile[right]) < 0.3 * np.linalg.norm(smile[left])
    jaw = rig.target("jawOpen") / METRES
    assert jaw[head.landmarks[152], 1] < -1.0  # the chin drops more than a centimetre
    assert (jaw[figure_for(animation.model).jaw_rows, 1] < 0).mean() > 0.5


def test_the_clip_plays_facesims_frames_back_within_issue_47s_bounds(exported, happy):
    """The clip's weights are in [0, 1], smile at happy's apex and rest at its first frame;
    played back from the file (ARKit's 52 and the clip's correctives) every frame comes
    within 0.5 mm RMS and 2 mm at most of facesim's own over the face area, as the
    ``wrote`` line says; the clip (its curves and its correctives, stored as 16-bit
    integers: KHR_mesh_quantization) adds at most 100 KB to the rig (measured: 41 KB)."""
    out, rig_line, clip_line, _ = exported
    spec, animation, shapes = happy
    clip = Glb(out / "happy.glb")
    names = clip.mesh["extras"]["targetNames"]
    assert names[:52] == list(ARKIT_52) and all(n.startswith("corrective_") for n in names[52:])
    weights = clip.clip_weights()
    assert weights.shape == (animation.frames, len(names)) and weights.min() >= 0 and weights.max() <= 1
    smile = [ARKIT_52.index("mouthSmileLeft"), ARKIT_52.index("mouthSmileRight")]
    assert weights[animation.apex_frame, smile].min() > 0.5 and weights[0].max() < 0.05
    stated_rms = float(clip_line.split("within ")[1].split(" mm RMS")[0])
    stated_max = float(clip_line.split("mm RMS, ")[1].split(" mm at most")[0])
    rms, largest = [], []
    for k in range(animation.frames):
        error = np.linalg.norm(clip.played(weights[k])[:FACE_AREA] - unturned(animation, k)[:FACE_AREA], axis=1) * 10
        rms.append(np.sqrt(np.mean(error ** 2)))
        largest.append(error.max())
    assert max(rms) <= min(stated_rms + 0.01, 0.5) and max(largest) <= min(stated_max + 0.01, 2.0)
    assert clip.size - Glb(out / "head.glb").size <= 100 * 1024
    assert "KHR_mesh_quantization" in clip.json["extensionsRequired"]


def test_live_link_csv_carries_the_same_curves(exported):
    out, *_ = exported
    lines = (out / "happy.csv").read_text().splitlines()
    rows = [line.split(",") for line in lines]
    assert tuple(rows[0]) == LIVE_LINK_COLUMNS and LIVE_LINK_COLUMNS[2] == "EyeBlinkLeft"
    assert len(rows) == 36 and {r[1] for r in rows[1:]} == {"61"}
    assert [r[0] for r in rows[1:4]] == ["00:00:00:00.000", "00:00:00:01.000", "00:00:00:02.000"]  # 25 fps
    assert rows[26][0] == "00:00:01:00.000"
    values = np.array([[float(v) for v in r[2:54]] for r in rows[1:]])
    np.testing.assert_allclose(values, Glb(out / "happy.glb").clip_weights()[:, :52], atol=1e-6)  # the same fit


def three_js_screenshot(directory: Path, glb: str, seconds: float, out: Path) -> np.ndarray:
    """``glb`` (in ``directory``) played by three.js (tests/js/play.html) to ``seconds`` in
    headless Chromium (Debian's), screenshot at 512x512 (scripts/export_docs.three_js)."""
    assert shutil.which("chromium"), "Debian's chromium is not installed: `make test` installs it"
    sys.path.insert(0, str(Path(__file__).resolve().parent.parent / "scripts"))
    from export_docs import three_js

    three_js(directory, glb, seconds, out)
    return iio.imread(out)[:, :, :3]


@pytest.mark.heavy(40)
def test_three_js_plays_the_clip_as_facesim_draws_it(exported, happy, tmp_path):
    """happy.glb played in three.js to its apex: MediaPipe finds the face, and its mouth
    corners move from the first frame the way they do in facesim's own frames (cosine at
    least 0.9, each corner's motion in units of the eyes' distance)."""
    from facesim.face.photo import detect_landmarks

    out, *_ = exported
    spec, animation, _ = happy
    apex = animation.apex_frame

    def corners(image, source):
        landmarks = detect_landmarks(image, source)[:, :2]
        return landmarks[[61, 291]] / np.linalg.norm(landmarks[263] - landmarks[33])

    three = {k: corners(three_js_screenshot(out, "happy.glb", k / animation.fps, tmp_path / f"three{k}.png"),
                        f"three.js frame {k}") for k in (0, apex)}
    ours = {}
    for k in (0, apex):
        facesim("render", HAPPY, "-o", tmp_path / f"ours{k}.png", "--frame", k, check=0)
        ours[k] = corners(iio.imread(tmp_path / f"ours{k}.png")[:, :, :3], f"facesim frame {k}")
    a, b = (three[apex] - three[0]).ravel(), (ours[apex] - ours[0]).ravel()
    assert a @ b / (np.linalg.norm(a) * np.linalg.norm(b)) >= 0.9
    assert np.linalg.norm(a) > 0.05  # the corners move in three.js: a smile, not a still face


def test_bad_exports_are_one_line_errors_and_nothing_is_written(tmp_path):
    one_line_error(facesim("rig", "-o", tmp_path / "head.obj"), 2, "head.obj", ".glb")
    assert not (tmp_path / "head.obj").exists()
    mask = facesim("render", HAPPY, "--mesh", EXPRESSIONS.parent / "meshes" / "face.obj", "-o", tmp_path / "mask.glb")
    one_line_error(mask, 2, "face mask", "head")
    mask = facesim("render", HAPPY, "--mesh", EXPRESSIONS.parent / "meshes" / "face.obj", "-o", tmp_path / "mask.pc2")
    one_line_error(mask, 2, "face mask", "head")
    one_line_error(facesim("render", HAPPY, "-o", tmp_path / "a.glb", "--frame", "3"), 2, "--frame")
    mine = tmp_path / "mine.glb"
    mine.write_bytes(b"my own file")
    one_line_error(facesim("rig", "-o", mine), 2, "already exists")
    one_line_error(facesim("rig", "-o", mine, "--force"), 2)  # not a GLB facesim wrote: never replaced
    assert mine.read_bytes() == b"my own file"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["mine.glb"]


def test_the_point_cache_is_every_vertex_of_facesims_frames_with_its_rest_mesh(exported, tmp_path):
    """-o happy.pc2: PC2's header and, frame by frame, the head's vertices as the NPZ holds
    them (in metres); happy.obj beside it is the rest mesh in the same order; a user's
    happy.obj beside the cache is never taken."""
    out, *_ = exported
    data = (out / "happy.pc2").read_bytes()
    assert data[:12] == b"POINTCACHE2\0"
    version, points, start, rate, samples = np.frombuffer(data[12:32], dtype="<i4", count=5)
    assert (version, points, samples) == (1, 26719, 35)
    cache = np.frombuffer(data[32:], dtype="<f4").reshape(samples, points, 3)
    with np.load(out / "happy.npz") as npz:
        np.testing.assert_allclose(cache, npz["positions"] * METRES, atol=2e-8)  # float32 of the same metres
        rest, faces = npz["rest"], npz["faces"]
    lines = (out / "happy.obj").read_text().splitlines()
    vertices = np.array([[float(v) for v in line.split()[1:]] for line in lines if line.startswith("v ")])
    triangles = np.array([[int(v) - 1 for v in line.split()[1:]] for line in lines if line.startswith("f ")])
    np.testing.assert_allclose(vertices, rest * METRES, atol=1e-8)
    assert len(triangles) == len(faces) and set(map(tuple, triangles)) == set(map(tuple, faces))  # all of ICT's
    mine = tmp_path / "mine"
    mine.mkdir()
    (mine / "happy.obj").write_text("my own mesh\n")
    one_line_error(facesim("render", HAPPY, "-o", mine / "happy.pc2"), 2, "happy.obj", "already exists")
    assert sorted(p.name for p in mine.iterdir()) == ["happy.obj"]


def test_the_usd_point_cache_is_every_vertex_of_facesims_frames_with_icts_parts_and_uvs(exported):
    """-o happy.usdc (the usd extra): one mesh, the NPZ's vertices as its points' time
    samples, frame for frame, in centimetres at the clip's fps; ICT's triangles, its
    material parts as GeomSubsets covering every triangle once, its UVs face-varying."""
    from pxr import Usd, UsdGeom

    out, *_ = exported
    assert (out / "happy.usdc").read_bytes()[:8] == b"PXR-USDC"
    stage = Usd.Stage.Open(str(out / "happy.usdc"))
    mesh = UsdGeom.Mesh(stage.GetPrimAtPath("/Head/Head"))
    assert UsdGeom.GetStageMetersPerUnit(stage) == 0.01 and UsdGeom.GetStageUpAxis(stage) == "Y"
    assert stage.GetTimeCodesPerSecond() == 25 and mesh.GetPointsAttr().GetTimeSamples() == list(range(35))
    with np.load(out / "happy.npz") as npz:
        positions, faces = npz["positions"], npz["faces"]
    for k in range(35):
        assert np.abs(np.array(mesh.GetPointsAttr().Get(k)) - positions[k]).max() < 1e-5, k
    assert np.array_equal(np.array(mesh.GetFaceVertexIndicesAttr().Get()).reshape(-1, 3), faces)
    subsets = UsdGeom.Subset.GetGeomSubsets(mesh, UsdGeom.Tokens.face, "part")
    covered = np.concatenate([np.array(s.GetIndicesAttr().Get()) for s in subsets])
    assert "M_Face" in [s.GetPrim().GetName() for s in subsets] and np.array_equal(np.sort(covered), np.arange(len(faces)))
    st = UsdGeom.PrimvarsAPI(mesh).GetPrimvar("st")
    assert st.GetInterpolation() == UsdGeom.Tokens.faceVarying and len(st.Get()) == 3 * len(faces)


def test_usd_without_its_package_is_one_line(tmp_path, monkeypatch):
    import sys

    from facesim.errors import InputError
    from facesim.export.output import check_output

    monkeypatch.setitem(sys.modules, "pxr", None)
    with pytest.raises(InputError, match=r"needs Pixar's USD: pip install 'facesim\[usd\]'"):
        check_output(tmp_path / "x.usdc", force=False)


def _gltf_axes(x: np.ndarray) -> np.ndarray:
    """Blender's z-up coordinates back into glTF's y-up (its importer turns +y into +z)."""
    return np.stack([x[..., 0], x[..., 2], -x[..., 1]], axis=-1)


@pytest.mark.heavy(20)
def test_blender_plays_the_glb_and_the_point_cache_as_facesim_does(exported, happy, tmp_path):
    """Debian's Blender 3.4, headless (tests/blender/read_exports.py): the GLB's shape keys
    are ARKit's 52 by name (and the clip's correctives), its action spans the clip's 35
    frames, and at the apex Blender's evaluated face equals facesim's own playback of the
    weights within 0.1 mm; the OBJ with the PC2 in a Mesh Cache modifier equals facesim's
    NPZ within 0.01 mm at every frame."""
    out, *_ = exported
    spec, animation, _ = happy
    result = tmp_path / "blender.npz"
    subprocess.run(["blender", "-b", "--factory-startup", "--python", str(Path(__file__).parent / "blender" / "read_exports.py"),
                    "--", str(out / "happy.glb"), str(out / "happy.pc2"), str(result), "25"],
                   capture_output=True, timeout=600, check=True)
    blender = np.load(result)
    names = [str(n) for n in blender["names"]]
    assert names[1:53] == list(ARKIT_52) and names[0] == "Basis" and all(n.startswith("corrective_") for n in names[53:])
    assert (blender["key_start"], blender["key_end"]) == (0, animation.frames - 1)
    clip = Glb(out / "happy.glb")
    rest = clip.accessor(clip.mesh["primitives"][0]["attributes"]["POSITION"]).astype(np.float64)
    theirs_rest = _gltf_axes(blender["glb_rest"])
    order = {tuple(p): k for k, p in enumerate(rest)}
    shared = {tuple(p) for p, n in zip(*np.unique(rest, axis=0, return_counts=True)) if n > 1}
    found = [(b, order[tuple(p)]) for b, p in enumerate(theirs_rest) if tuple(p) in order and tuple(p) not in shared]
    assert len(found) > 0.95 * len(theirs_rest)  # Blender's vertices are ICT's, each found by its rest position
    b, k = np.array(found).T
    apex = animation.apex_frame
    ours = clip.played(clip.clip_weights()[apex]) * METRES
    error = np.linalg.norm(_gltf_axes(blender["glb_frames"][apex])[b] - ours[k], axis=1)
    assert error.max() < 1e-4  # metres: 0.1 mm
    assert blender["obj_count"] == 26719
    with np.load(out / "happy.npz") as npz:
        positions = npz["positions"] * METRES
    for f in range(animation.frames):
        assert np.abs(blender["pc2_frames"][f] - positions[f]).max() < 1e-5, f
