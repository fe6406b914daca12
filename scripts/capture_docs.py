"""The capture's picture and figures for the README and docs/capture.md (``make docs``).

- ``docs/capture.gif``: expressions/performance.yaml rendered on the default head (the
  source clip) beside its capture replayed on identity 7, every second frame.
- docs/capture.md's table: the round trip (render, capture, compare with the curves
  that made the clip) on the default head, on identity 7 (a face the solver was not
  built on), in the photo look of the astronaut's face directory, and drawn --onto its
  photo: each main control's Pearson correlation, their mean over the controls that
  move, the largest lag, the head's largest error, and whose turns the capture read the
  clip's by (facesim.capture.subject).

The astronaut's face directory is written to out/capture/ (made afresh each run).
"""

from __future__ import annotations

import sys
from pathlib import Path

import imageio.v3 as iio
import numpy as np

ROOT = Path(__file__).resolve().parent.parent
OUT = ROOT / "out" / "capture"
CELL = 192
MAIN = ("jawOpen", "eyeBlinkLeft", "eyeBlinkRight", "mouthSmileLeft", "mouthSmileRight", "browInnerUp")


def row(name: str, spec, performance) -> str:
    from facesim.animation.spec import pose_table
    from facesim.capture.solver import SOLVED

    found = {}
    for track in spec.timeline:
        true = track.values(spec.dt, spec.frames)
        got = performance.weights[:, SOLVED.index(track.target)]
        lag = int(np.argmax(np.correlate(got - got.mean(), true - true.mean(), "full"))) - (spec.frames - 1)
        found[track.target] = (float(np.corrcoef(true, got)[0, 1]), lag)
    head = np.abs(performance.head - pose_table(spec)[:, :3]).max()
    cells = [f"{found[n][0]:.2f}" for n in MAIN]
    mean = np.mean([r for r, _ in found.values()])
    lag = max(abs(lag) for _, lag in found.values())
    turns = "the subject's" if performance.turns_read_on.startswith("the subject") else "the default head's"
    return f"| {name} | " + " | ".join(cells) + f" | {mean:.2f} | {lag} | {head:.1f} | {turns} |"


def main() -> int:
    from skimage import data

    import facesim
    from facesim.animation.spec import load_spec
    from facesim.capture.performance import capture
    from facesim.face.own_face import face_from_photo
    from facesim.renderer.settings import RenderSettings

    OUT.mkdir(parents=True, exist_ok=True)
    spec = load_spec(ROOT / "expressions" / "performance.yaml")
    photo = OUT / "astronaut.png"
    iio.imwrite(photo, data.astronaut())
    face = OUT / "astronaut"
    face_from_photo(photo, face, replace=True)
    cases = [("the default head", spec, RenderSettings(width=320, height=320)),
             ("identity 7", spec.with_overrides(identity=7), RenderSettings(width=320, height=320)),
             ("the astronaut's photo look", spec.with_overrides(face=face), RenderSettings(width=320, height=320, look="photo")),
             ("the astronaut, --onto her photo", spec.with_overrides(face=face), RenderSettings(onto=photo, width=512, height=512))]
    rows = []
    for k, (name, case, settings) in enumerate(cases):
        video = OUT / f"case{k}.mp4"
        facesim.render(facesim.simulate(case), video, settings, force=True)
        performance = capture(video, OUT / f"case{k}.yaml", replace=True)
        rows.append(row(name, case, performance))
        print(rows[-1], flush=True)
        if k == 0:
            source = iio.imread(video)
            replay = facesim.simulate(load_spec(OUT / "case0.yaml").with_overrides(identity=7))
            facesim.render(replay, OUT / "replay.mp4", RenderSettings(width=320, height=320), force=True)
            replayed = iio.imread(OUT / "replay.mp4")
    from PIL import Image

    def small(frame):
        return np.asarray(Image.fromarray(frame).resize((CELL, CELL), Image.LANCZOS))

    frames = [np.concatenate([small(a), small(b)], axis=1) for a, b in zip(source[::2], replayed[::2])]
    iio.imwrite(ROOT / "docs" / "capture.gif", np.stack(frames), duration=80, loop=0)
    table = ("| clip | jaw | blink L | blink R | smile L | smile R | inner brows | mean | largest lag (frames) "
             "| head's largest error (degrees) | turns read as on |\n|---|---|---|---|---|---|---|---|---|---|---|\n"
             + "\n".join(rows) + "\n")
    doc = ROOT / "docs" / "capture.md"
    text = doc.read_text()
    start = text.index("| clip | jaw |")
    end = text.index("\n\n", start) + 1
    doc.write_text(text[:start] + table + text[end:])
    return 0


if __name__ == "__main__":
    sys.exit(main())
