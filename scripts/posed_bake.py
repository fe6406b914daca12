"""A measurement for docs/capture.md (issue 49): what the astronaut's painted smile costs her
capture, and what baking her photo from her head posed in its expression gives back.

`face from-photo` bakes a photo onto the fitted head at rest, so a smiling photo's smile,
teeth and all, is painted onto closed lips (it says so: facesim.face.fit.Fit.mouth_against_rest).
Here her photo's expression is fitted with facesim's own controls instead: ARKit's mouth and
jaw shapes (``SHAPES``), each held by the physics on her fitted identity, its landmarks
(ICT's measurement of where MediaPipe's fall on the head) projected through her fitted
camera; bounded least squares for their weights, the identity fitted again to the landmarks
with that motion taken out, ``ROUNDS`` times. Her texture is then baked from the posed
head, and the round trip of ``make docs`` (expressions/performance.yaml in the photo look,
captured back) is run on her face as `face from-photo` makes it and as posed, one row each
in docs/capture.md's layout (scripts/capture_docs.py).

Not in facesim yet: the route, and what --onto must keep, are in docs/capture.md.
Written to out/posed_bake/.
"""

from __future__ import annotations

import dataclasses
import shutil
import sys
from pathlib import Path

import imageio.v3 as iio
import numpy as np

ROOT = Path(__file__).resolve().parent.parent
OUT = ROOT / "out" / "posed_bake"
#: Her photo's expression is fitted with these. With the upper lip's raise (mouthUpperUpLeft,
#: -Right) too, the posed skin under her nose moved into her nostrils' shadow and baked a dark
#: spot there, for much the same figures (docs/capture.md).
SHAPES = ("mouthSmileLeft", "mouthSmileRight", "jawOpen", "mouthStretchLeft", "mouthStretchRight", "mouthDimpleLeft",
          "mouthDimpleRight", "mouthLowerDownLeft", "mouthLowerDownRight")
ROUNDS = 3
#: Frames each pose is held by the physics (the capture's basis holds its shapes as long).
HELD = 30


def posed(identity: tuple, weights: np.ndarray):
    """The head's vertices (ICT's order) held at ``weights`` of ``SHAPES`` on ``identity``, and the model."""
    from facesim.animation.simulate import simulate
    from facesim.animation.spec import Spec
    from facesim.face.figure import figure_for

    arkit = {name: float(w) for name, w in zip(SHAPES, weights) if w > 0}
    animation = simulate(Spec(name="photo pose", frames=HELD, identity=list(identity), arkit=arkit))
    last = animation.frames - 1
    return figure_for(animation.model).positions(animation.positions[last], animation.jaw_at(last)), animation.model


def photo_pose(image: np.ndarray, detected: np.ndarray):
    """The fit (identity and camera) of the photo's face with its expression taken out, the
    expression's weights, and the head posed in it (``posed``)."""
    from scipy.optimize import lsq_linear

    from facesim.config import HEAD
    from facesim.face.fit import fit_head
    from facesim.face.head import load_head

    target, weights = detected.copy(), np.zeros(len(SHAPES))
    for _ in range(ROUNDS):
        fit = fit_head(load_head(HEAD), HEAD, target, image.shape[1], image.shape[0], "photo")
        identity = tuple(float(w) for w in fit.identity)
        rest, model = posed(identity, np.zeros(len(SHAPES)))
        head = model.mesh.head

        def seen(vertices):
            return fit.camera.project(dataclasses.replace(head, vertices=vertices).landmark_positions)

        at_rest = seen(rest)
        motion = np.stack([(seen(posed(identity, one)[0]) - at_rest).ravel() for one in np.eye(len(SHAPES))], axis=1)
        ridge = 0.01 * np.abs(motion).max() * np.eye(len(SHAPES))
        misfit = (detected - at_rest).ravel()
        weights = lsq_linear(np.vstack([motion, ridge]), np.r_[misfit, np.zeros(len(SHAPES))], bounds=(0, 1)).x
        target = detected - (motion @ weights).reshape(-1, 2)
    return fit, weights, posed(identity, weights)


def main() -> int:
    import yaml
    from capture_docs import row
    from skimage import data

    import facesim
    from facesim.animation.spec import load_spec
    from facesim.capture.performance import capture
    from facesim.face.bake import bake
    from facesim.face.figure import atlas_uv, figure_for
    from facesim.face.own_face import face_from_photo, head_obj
    from facesim.face.photo import detect_landmarks, read_image
    from facesim.renderer.scene import FaceRenderer
    from facesim.renderer.settings import RenderSettings

    OUT.mkdir(parents=True, exist_ok=True)
    photo = OUT / "astronaut.png"
    iio.imwrite(photo, data.astronaut())
    face, posed_face = OUT / "astronaut", OUT / "astronaut_posed"
    face_from_photo(photo, face, replace=True)

    image = read_image(photo)
    fit, weights, (vertices, model) = photo_pose(image, detect_landmarks(image, str(photo), refine=True)[:, :2])
    print("her photo's expression:", {n: round(float(w), 2) for n, w in zip(SHAPES, weights) if w > 0.05}, flush=True)
    head = model.mesh.head
    atlas = atlas_uv(head)
    texture, onto = bake(dataclasses.replace(head, vertices=vertices), fit.camera, image, figure_for(model).colour, atlas)
    shutil.rmtree(posed_face, ignore_errors=True)
    shutil.copytree(face, posed_face)
    # the identity fitted again: its neutral head, as face from-photo writes one
    obj, _ = head_obj(head, atlas[0], atlas[2], "scripts/posed_bake.py: the astronaut's head, her expression fitted apart")
    (posed_face / "head.obj").write_text(obj)
    iio.imwrite(posed_face / "head.png", texture)
    iio.imwrite(posed_face / "head_onto.png", onto)
    record = yaml.safe_load((posed_face / "face.yaml").read_text())
    record.update(identity=[float(w) for w in fit.identity], camera=fit.camera.as_dict())
    (posed_face / "face.yaml").write_text(yaml.safe_dump(record, sort_keys=False))

    spec = load_spec(ROOT / "expressions" / "performance.yaml")
    settings = RenderSettings(width=320, height=320, look="photo")
    for name, directory in (("as face from-photo bakes it", face), ("baked from her posed head", posed_face)):
        case = spec.with_overrides(face=directory)
        video = OUT / f"{directory.name}.mp4"
        facesim.render(facesim.simulate(case), video, settings, force=True)
        print(row(f"the astronaut's photo look, {name}", case, capture(video, OUT / f"{directory.name}.yaml",
                                                                          replace=True)), flush=True)
        at_rest = facesim.simulate(case.with_overrides(frames=1))
        with FaceRenderer.of(at_rest, RenderSettings(width=384, height=384, look="photo")) as renderer:
            iio.imwrite(OUT / f"{directory.name}_rest.png", renderer.frame(at_rest, 0))
    return 0


if __name__ == "__main__":
    sys.path.insert(0, str(Path(__file__).resolve().parent))
    sys.exit(main())
