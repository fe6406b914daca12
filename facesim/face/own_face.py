"""Your own face on a full head: ``facesim face from-photo PHOTO -o DIR``.

A photo in (:func:`face_from_photo`): MediaPipe's 468 landmarks (facesim.face.photo, offline),
ICT's head fitted to them with a camera (facesim.face.fit), the photo baked into the fitted
head's texture (facesim.face.bake). A face directory out, written whole or not at all (built
under a temporary name, read back, then renamed):

- ``head.obj``, ``head.mtl``, ``head.png``: the fitted neutral head in ICT's vertex order
  (written line by line: a library's OBJ writer would re-index it at the texture's seams),
  its textured parts (the skin, the eyes) mapped into the baked atlas, the others (teeth,
  gums and tongue, lashes, the eyes' shells) with facesim's colours; Blender and trimesh
  load it as it is;
- ``head_onto.png``: for ``--onto``, how much of each texel the render shows over the
  photo (facesim.face.bake: less where the photo saw it at a grazing angle);
- ``face.yaml``: the identity weights (ICT's 100 modes), the fitted camera, the photo it
  came from and how well the landmarks fit (the median and 90th percentile of their
  distance from MediaPipe's, in face widths);
- ``muscles.yaml``: the head's muscle file, by landmark index, which fits any identity.

A face directory read back (:func:`load_face_directory`, ``--face DIR`` or ``face:`` in a
spec) gives the simulation its identity and muscles, the renderer its texture
(``--look photo``) and, for ``--onto PHOTO``, the camera the photo was taken with.
"""

from __future__ import annotations

import shutil
from dataclasses import dataclass
from functools import lru_cache
from pathlib import Path

import numpy as np

from ..errors import InputError

#: The files of a face directory (what ``--force`` may replace).
FACE_FILES = frozenset({"head.obj", "head.mtl", "head.png", "head_onto.png", "face.yaml", "muscles.yaml"})
#: Materials without texture, with the MTL colour each gets (facesim.face.figure's).
HIDDEN = ("M_LacrimalFluid", "M_EyeBlend", "M_EyeOcclusion")


@dataclass(frozen=True, eq=False)
class FaceDirectory:
    """A face directory read back: where it is, the identity weights (100,) as a tuple,
    the fitted camera (facesim.face.fit.Camera) and its files."""

    path: Path
    identity: tuple
    camera: object

    @property
    def texture(self) -> Path:
        return self.path / "head.png"

    @property
    def onto_alpha(self) -> Path:
        return self.path / "head_onto.png"

    @property
    def muscles(self) -> Path:
        return self.path / "muscles.yaml"


def load_face_directory(path: str | Path, where: str = "--face") -> FaceDirectory:
    """A face directory written by ``facesim face from-photo``, checked: every file
    there, face.yaml's identity (100 finite weights) and camera, the texture a readable
    image of the atlas's size. One-line InputError naming the file otherwise."""
    path = Path(path).resolve()
    if not path.is_dir():
        raise InputError(f"{where}: {path}: not a face directory (make one with `facesim face from-photo PHOTO -o DIR`)")
    stamp = tuple((path / name).stat().st_mtime_ns if (path / name).is_file() else 0 for name in sorted(FACE_FILES))
    return _load_face_directory(path, stamp)


@lru_cache(maxsize=8)
def _load_face_directory(path: Path, stamp: tuple) -> FaceDirectory:
    """load_face_directory's work, once per directory as its files stand (``stamp``):
    every spec naming it gets the same FaceDirectory, so they share a renderer."""
    import yaml
    from PIL import Image

    from .figure import COLUMNS, TILE, TILES
    from .fit import Camera
    from .head import IDENTITY_MODES, identity_problem

    missing = sorted(name for name in FACE_FILES if not (path / name).is_file())
    if missing:
        raise InputError(f"{path}: not a face directory: {', '.join(missing)} missing")
    record_path = path / "face.yaml"
    try:
        record = yaml.safe_load(record_path.read_text())
    except (yaml.YAMLError, UnicodeDecodeError) as exc:
        raise InputError(f"{record_path}: not valid YAML ({type(exc).__name__})") from None
    if not isinstance(record, dict):
        raise InputError(f"{record_path}: expected a mapping with identity and camera")
    identity = record.get("identity")
    try:
        weights = np.asarray(identity, dtype=np.float64)
    except (TypeError, ValueError):
        weights = np.zeros(0)
    if weights.shape != (IDENTITY_MODES,):
        raise InputError(f"{record_path}: identity: expected {IDENTITY_MODES} finite weights")
    problem = identity_problem(weights)  # finite, and a person's
    if problem:
        raise InputError(f"{record_path}: identity: {problem}")
    if not isinstance(record.get("camera"), dict):
        raise InputError(f"{record_path}: camera: expected the fitted camera (a mapping)")
    camera = Camera.from_dict(record["camera"], f"{record_path}: camera")
    expected = (TILE * COLUMNS, TILE * len(TILES) // COLUMNS)
    for name in ("head.png", "head_onto.png"):
        try:
            with Image.open(path / name) as image:
                size = image.size
                image.verify()
        except Exception as exc:  # Pillow raises many kinds for a damaged file
            raise InputError(f"{path / name}: not a readable image ({type(exc).__name__})") from None
        if size != expected:
            raise InputError(f"{path / name}: expected the {expected[0]}x{expected[1]} atlas face from-photo bakes, "
                             f"got {size[0]}x{size[1]}")
    return FaceDirectory(path, tuple(float(w) for w in weights), camera)


#: The longest side (pixels) of an --onto render's frames: a larger photo is downscaled
#: to it for the composite. An 8000x8000 photo drawn at its own size took 102 s and 8 GB
#: for three frames.
ONTO_LIMIT = 2048


def onto_photo(face: FaceDirectory, photo: str | Path, size: tuple[int, int] | None = None):
    """--onto: the photo (h, w, 3) float in [0, 255] and the face's fitted camera for it.
    The photo must be the one the face was fitted to, or that photo resized (the camera is
    scaled with it), at least 16 pixels a side; one longer than ``ONTO_LIMIT`` is
    downscaled to it (``onto_size`` says by how much). ``size`` (w, h), when given, must
    be the size drawn at."""
    from .fit import PHOTO_SIDE
    from .photo import read_image

    image = read_image(photo)
    height, width = image.shape[:2]
    if min(width, height) < PHOTO_SIDE[0]:
        raise InputError(f"--onto: {photo} is {width}x{height} pixels: too small to draw a face into "
                         f"(at least {PHOTO_SIDE[0]} a side)")
    if max(width, height) > ONTO_LIMIT:
        from PIL import Image

        width, height = onto_size(width, height)
        image = np.asarray(Image.fromarray(image).resize((width, height), Image.Resampling.LANCZOS))
    if size is not None and tuple(size) != (width, height):
        raise InputError(f"--onto: {photo} is {width}x{height}; the frames must be the photo's size, got {size[0]}x{size[1]}")
    camera = face.camera
    ratio = width / camera.width
    if abs(height / camera.height - ratio) > 0.01 * ratio:
        raise InputError(f"--onto: {photo} is {width}x{height}, but {face.path.name} was fitted to a photo of "
                         f"{camera.width}x{camera.height}: give that photo (or it resized)")
    return image.astype(np.float64), camera.resized(width, height)


def onto_size(width: int, height: int) -> tuple[int, int]:
    """The size an --onto render of a photo of ``width`` x ``height`` draws at."""
    factor = min(1.0, ONTO_LIMIT / max(width, height))
    return max(1, round(width * factor)), max(1, round(height * factor))


def _colours():
    from .colours import GUMS, LASHES, TEETH

    return {"M_GumsTongue": GUMS, "M_Teeth": TEETH, "M_EyeLashes": LASHES}


def head_obj(head, uv_rows: np.ndarray, uv: np.ndarray, header: str) -> tuple[str, str]:
    """The OBJ and MTL text of ``head`` with the atlas UVs ``uv`` (k, 3, 2) of its
    triangles ``uv_rows`` (k,) (facesim.face.bake.atlas_uv's, by triangle index); the eyes'
    hidden shells are left out."""
    lines = [f"# {line}" for line in header.splitlines()] + ["mtllib head.mtl"]
    lines += [f"v {x:.6f} {y:.6f} {z:.6f}" for x, y, z in head.vertices]
    lines += [f"vt {u:.6f} {v:.6f}" for u, v in uv.reshape(-1, 2)]
    texture_of = np.full(len(head.triangles), -1)
    texture_of[uv_rows] = np.arange(len(uv_rows))
    textured = sorted({head.materials[m] for m in head.triangle_material[uv_rows]})
    colours = _colours()
    materials = ["# facesim face from-photo"]
    for index, name in enumerate(head.materials):
        if name in HIDDEN:
            continue
        triangles = np.flatnonzero(head.triangle_material == index)
        if name in textured:
            triangles = triangles[texture_of[triangles] >= 0]  # as the figure draws them (the sclera without its cornea)
            materials += [f"newmtl {name}", "Ka 1 1 1", "Kd 1 1 1", "Ks 0 0 0", "illum 1", "map_Kd head.png"]
        else:
            r, g, b = colours.get(name, (0.5, 0.5, 0.5, 1.0))[:3]
            materials += [f"newmtl {name}", "Ka 1 1 1", f"Kd {r:.4f} {g:.4f} {b:.4f}", "Ks 0 0 0", "illum 1"]
        lines += [f"g {name}", f"usemtl {name}"]
        for t in triangles:
            a, b, c = head.triangles[t] + 1
            if name in textured:
                k = 3 * texture_of[t] + 1
                lines.append(f"f {a}/{k} {b}/{k + 1} {c}/{k + 2}")
            else:
                lines.append(f"f {a} {b} {c}")
    return "\n".join(lines) + "\n", "\n".join(materials) + "\n"


def read_obj_vertices(path: Path) -> np.ndarray:
    """The ``v`` lines of an OBJ in their order (ICT's, for a face directory's head)."""
    rows = [line.split()[1:4] for line in path.read_text().splitlines() if line.startswith("v ")]
    return np.array(rows, dtype=np.float64)


def face_from_photo(photo: str | Path, output: str | Path, replace: bool = False, notice=None) -> dict:
    """The whole pipeline of the module docstring. Returns what ``face.yaml`` holds."""
    import imageio.v3 as iio
    import yaml

    from ..config import HEAD, HEAD_MUSCLES, VERSION
    from ..files import atomic_path
    from .bake import bake
    from .figure import atlas_uv, figure_for
    from .fit import PHOTO_AT_REST, fit_head
    from .head import load_head
    from .loading import load_face_model
    from .photo import detect_landmarks, read_image

    try:
        import mediapipe  # noqa: F401
    except ImportError:
        raise InputError("face from-photo needs MediaPipe: pip install -e '.[photo]' (or make mesh)") from None
    photo, output = Path(photo), Path(output)
    image = read_image(photo)
    landmarks = detect_landmarks(image, str(photo), notice, refine=True)
    fit = fit_head(load_head(HEAD), HEAD, landmarks, image.shape[1], image.shape[0], str(photo))
    apart, raised = fit.mouth_against_rest()
    shown = [what for what, shows in ((f"its lips {10 * apart:.0f} mm apart", apart > PHOTO_AT_REST[0]),
                                      (f"its mouth's corners {10 * raised:.0f} mm raised", raised > PHOTO_AT_REST[1]))
             if shows]
    if shown and notice is not None:
        notice(f"{photo}: the face is not at rest ({' and '.join(shown)}, against the fitted head's): the photo is "
               "baked into the skin as it is, so the face at rest shows its expression (a smile's teeth on closed "
               "lips) and moves it; a photo of the face relaxed, lips closed, animates truer")
    identity = tuple(float(w) for w in fit.identity)
    model = load_face_model(HEAD.resolve(), HEAD_MUSCLES.resolve(), identity=identity)
    head = model.mesh.head
    atlas = atlas_uv(head)
    texture, onto = bake(head, fit.camera, image, figure_for(model).colour, atlas)
    uv_rows, _, uv = atlas
    residual = fit.residual
    record = dict(
        created_by=f"facesim {VERSION} face from-photo",
        photo=photo.name,
        identity=list(identity),
        camera=fit.camera.as_dict(),
        landmarks=dict(detector="MediaPipe Face Mesh, 468 landmarks", face_width_pixels=round(fit.face_width, 1),
                       median_residual_face_widths=round(float(np.median(residual)), 5),
                       p90_residual_face_widths=round(float(np.percentile(residual, 90)), 5)),
        # what of an expression the photo shows, baked into the texture (fit.Fit.mouth_against_rest)
        expression=dict(lips_parted_mm=round(10 * apart, 1), mouth_corners_raised_mm=round(10 * raised, 1),
                        at_rest=not shown),
        licence="the head: ICT FaceKit (USC ICT), MIT licence (meshes/ict/LICENSE); the texture: the photo's own",
    )
    header = (f"facesim face from-photo: ICT FaceKit's head (MIT licence, USC ICT) fitted to {photo.name}\n"
              "cm, +x the subject's left, +y up, +z forward; vertices in ICT's order")
    obj, mtl = head_obj(head, uv_rows, uv, header)

    def verify(directory: Path) -> None:
        vertices = read_obj_vertices(directory / "head.obj")
        if vertices.shape != head.vertices.shape or np.abs(vertices - head.vertices).max() > 1e-5:
            raise InputError(f"{output}: the head written does not read back")
        if iio.imread(directory / "head.png").shape != texture.shape or iio.imread(directory / "head_onto.png").shape != onto.shape:
            raise InputError(f"{output}: the texture written does not read back")

    with atomic_path(output, directory=True, replace=replace, verify=verify) as tmp:
        (tmp / "head.obj").write_text(obj)
        (tmp / "head.mtl").write_text(mtl)
        iio.imwrite(tmp / "head.png", texture)
        iio.imwrite(tmp / "head_onto.png", onto)
        (tmp / "face.yaml").write_text(yaml.safe_dump(record, sort_keys=False))
        shutil.copyfile(HEAD_MUSCLES, tmp / "muscles.yaml")
    return record
