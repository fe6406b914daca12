"""Your own face on a full head: ``facesim face from-photo PHOTO -o DIR``.

A photo in (:func:`face_from_photo`): MediaPipe's 468 landmarks (facesim.photo, offline),
ICT's head fitted to them with a camera (facesim.fit), the photo baked into the fitted
head's texture (facesim.bake). A face directory out, written whole or not at all (built
under a temporary name, read back, then renamed):

- ``head.obj``, ``head.mtl``, ``head.png``: the fitted neutral head in ICT's vertex order
  (written line by line: a library's OBJ writer would re-index it at the texture's seams),
  its textured parts (the skin, the eyes) mapped into the baked atlas, the others (teeth,
  gums and tongue, lashes, the eyes' shells) with facesim's colours; Blender and trimesh
  load it as it is;
- ``face.yaml``: the identity weights (ICT's 100 modes), the fitted camera, the photo it
  came from and how well the landmarks fit (the median and 90th percentile of their
  distance from MediaPipe's, in face widths);
- ``muscles.yaml``: the head's muscle file, by landmark index, which fits any identity.
"""

from __future__ import annotations

import shutil
from pathlib import Path

import numpy as np

from .errors import InputError

#: The files of a face directory (what ``--force`` may replace).
FACE_FILES = frozenset({"head.obj", "head.mtl", "head.png", "face.yaml", "muscles.yaml"})
#: Materials without texture, with the MTL colour each gets (facesim.figure's).
HIDDEN = ("M_LacrimalFluid", "M_EyeBlend", "M_EyeOcclusion")


def _colours():
    from .figure import GUMS, LASHES, TEETH

    return {"M_GumsTongue": GUMS, "M_Teeth": TEETH, "M_EyeLashes": LASHES}


def head_obj(head, uv_rows: np.ndarray, uv: np.ndarray, header: str) -> tuple[str, str]:
    """The OBJ and MTL text of ``head`` with the atlas UVs ``uv`` (k, 3, 2) of its
    triangles ``uv_rows`` (k,) (facesim.bake.atlas_uv's, by triangle index); the eyes'
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

    from . import __version__
    from .bake import atlas_uv, bake
    from .config import HEAD, HEAD_MUSCLES
    from .fit import fit_head
    from .head import load_head
    from .photo import detect_landmarks, read_image
    from .model import Material
    from .simulate import _model, figure_for
    from .writers import atomic_path

    try:
        import mediapipe  # noqa: F401
    except ImportError:
        raise InputError("face from-photo needs MediaPipe: pip install -e '.[photo]' (or make mesh)") from None
    photo, output = Path(photo), Path(output)
    image = read_image(photo)
    landmarks = detect_landmarks(image, str(photo), notice)
    fit = fit_head(load_head(HEAD), HEAD, landmarks, image.shape[1], image.shape[0], str(photo))
    identity = tuple(float(w) for w in fit.identity)
    model = _model(HEAD.resolve(), HEAD_MUSCLES.resolve(), Material(), identity)
    head = model.mesh.head
    atlas = atlas_uv(head)
    texture = bake(head, fit.camera, image, figure_for(model).colour, atlas)
    uv_rows, _, uv = atlas
    residual = fit.residual
    record = dict(
        created_by=f"facesim {__version__} face from-photo",
        photo=photo.name,
        identity=list(identity),
        camera=fit.camera.as_dict(),
        landmarks=dict(detector="MediaPipe Face Mesh, 468 landmarks", face_width_pixels=round(fit.face_width, 1),
                       median_residual_face_widths=round(float(np.median(residual)), 5),
                       p90_residual_face_widths=round(float(np.percentile(residual, 90)), 5)),
        licence="the head: ICT FaceKit (USC ICT), MIT licence (meshes/ict/LICENSE); the texture: the photo's own",
    )
    header = (f"facesim face from-photo: ICT FaceKit's head (MIT licence, USC ICT) fitted to {photo.name}\n"
              "cm, +x the subject's left, +y up, +z forward; vertices in ICT's order")
    obj, mtl = head_obj(head, uv_rows, uv, header)

    def verify(directory: Path) -> None:
        vertices = read_obj_vertices(directory / "head.obj")
        if vertices.shape != head.vertices.shape or np.abs(vertices - head.vertices).max() > 1e-5:
            raise InputError(f"{output}: the head written does not read back")
        if iio.imread(directory / "head.png").shape != texture.shape:
            raise InputError(f"{output}: the texture written does not read back")

    with atomic_path(output, directory=True, replace=replace, verify=verify) as tmp:
        (tmp / "head.obj").write_text(obj)
        (tmp / "head.mtl").write_text(mtl)
        iio.imwrite(tmp / "head.png", texture)
        (tmp / "face.yaml").write_text(yaml.safe_dump(record, sort_keys=False))
        shutil.copyfile(HEAD_MUSCLES, tmp / "muscles.yaml")
    return record
