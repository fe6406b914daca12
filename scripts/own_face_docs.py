"""The pictures of `facesim face from-photo` for the README (``make docs``).

- ``docs/own_face.png``: for scikit-image's astronaut and matplotlib's Grace Hopper, one
  row each: the photo | the fitted head in clay, drawn through the photo's fitted camera
  over it | the textured head at neutral | happy | surprise (the photo look, facesim's
  front camera).
- ``docs/animated_photo.gif``: the astronaut's photo going from neutral to surprise and
  back (``render --face DIR --onto PHOTO``), cropped to her head and enlarged twice.

The face directories are written to out/faces/ (made afresh each run).
"""

from __future__ import annotations

import argparse
import shutil
from pathlib import Path

import imageio.v3 as iio
import numpy as np

ROOT = Path(__file__).resolve().parent.parent
PHOTOS = ("astronaut", "hopper")
CELL = 320


def photos(out: Path) -> dict[str, Path]:
    import matplotlib.cbook
    from skimage import data

    astronaut = out / "astronaut.png"
    iio.imwrite(astronaut, data.astronaut())
    return {"astronaut": astronaut, "hopper": Path(matplotlib.cbook.get_sample_data("grace_hopper.jpg", asfileobj=False))}


def head_box(face, photo_shape, margin=1.6) -> tuple[slice, slice]:
    """A square around the fitted head's face in the photo, ``margin`` times its landmarks' extent."""
    from facesim.config import HEAD
    from facesim.face.head import load_head

    head = load_head(HEAD, list(face.identity))
    points = face.camera.project(head.landmark_positions)
    centre = (points.min(axis=0) + points.max(axis=0)) / 2
    half = margin * np.ptp(points, axis=0).max() / 2
    (x0, y0), (x1, y1) = np.maximum(centre - half, 0).astype(int), np.minimum(centre + half, photo_shape[1::-1]).astype(int)
    return slice(y0, y1), slice(x0, x1)


def cell(image: np.ndarray) -> np.ndarray:
    from PIL import Image

    return np.asarray(Image.fromarray(image).resize((CELL, CELL), Image.LANCZOS))


def enlarged(image: np.ndarray, factor: int = 2) -> np.ndarray:
    """The crop of a small face, enlarged for the README (the astronaut's face is 94 pixels wide)."""
    from PIL import Image

    return np.asarray(Image.fromarray(image).resize((factor * image.shape[1], factor * image.shape[0]), Image.LANCZOS))


def main() -> None:
    from facesim.animation.simulate import simulate
    from facesim.animation.spec import Envelope, Spec, Track, load_spec
    from facesim.export.plots import contact_sheet
    from facesim.face.own_face import face_from_photo, load_face_directory
    from facesim.face.photo import read_image
    from facesim.renderer.scene import FaceRenderer
    from facesim.renderer.settings import RenderSettings

    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", type=Path, default=ROOT / "out" / "faces")
    args = parser.parse_args()
    shutil.rmtree(args.out, ignore_errors=True)
    args.out.mkdir(parents=True)
    images, labels = [], []
    sources = photos(args.out)
    for name in PHOTOS:
        face_from_photo(sources[name], args.out / name)
        face = load_face_directory(args.out / name)
        photo = read_image(sources[name])
        box = head_box(face, photo.shape)
        neutral = simulate(load_spec("happy").with_overrides(face=face.path, frames=1))
        clay = RenderSettings(photo.shape[1], photo.shape[0], look="clay", onto=sources[name])
        with FaceRenderer.of(neutral, clay) as renderer:
            fitted = renderer.render(neutral.rest)
        row = [cell(photo[box]), cell(fitted[box])]
        with FaceRenderer.of(neutral, RenderSettings(CELL, CELL, look="photo")) as renderer:
            row.append(renderer.render(neutral.rest))
            for expression in ("happy", "surprise"):
                animation = simulate(load_spec(expression).with_overrides(face=face.path))
                row.append(renderer.frame(animation, animation.apex_frame))
        images += row
        labels += [f"{name}: photo", "fitted head (clay) over it", "textured, neutral", "happy", "surprise"]
    contact_sheet(images, labels, ROOT / "docs" / "own_face.png", columns=5, replace=True)
    print("wrote docs/own_face.png")

    # the astronaut's photo comes alive: neutral, surprise, and back
    face = load_face_directory(args.out / "astronaut")
    photo = read_image(sources["astronaut"])
    box = head_box(face, photo.shape, margin=2.0)
    spec = Spec(name="surprise and back", frames=44, timeline=[
        Track(target="surprise", envelope=Envelope(start=4, onset=10, apex=14, offset=10))]).with_overrides(face=face.path)
    animation = simulate(spec)
    with FaceRenderer.of(animation, RenderSettings(photo.shape[1], photo.shape[0], onto=sources["astronaut"])) as renderer:
        frames = [enlarged(renderer.frame(animation, k)[box]) for k in range(animation.frames)]
    from facesim.export.output import write_frames

    write_frames(frames, ROOT / "docs" / "animated_photo.gif", "gif", fps=25.0)
    print("wrote docs/animated_photo.gif")


if __name__ == "__main__":
    main()
