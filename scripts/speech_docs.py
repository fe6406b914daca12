"""The speech pictures for the README (``make docs``).

- ``docs/speech.mp4``: "Bob made a map, Pam pays." said by the default head and by
  Grace Hopper's face directory (``facesim face from-photo`` on matplotlib's sample photo),
  each once neutral and once with happy under the words, 2 x 2 at 256² a face, with the
  sound.
- ``docs/speech.png``: the default head at the middle of each of the sentence's phonemes,
  labelled with it.

The face directory is written to out/faces/ (made afresh each run).
"""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import imageio.v3 as iio
import numpy as np
from PIL import Image, ImageDraw, ImageFont

ROOT = Path(__file__).resolve().parent.parent
SENTENCE = "Bob made a map, Pam pays."
CELL = 256


def clip(spec, out: Path) -> np.ndarray:
    """The spec's frames (frames, CELL, CELL, 3), drawn by facesim.render."""
    import facesim
    from facesim.renderer.settings import RenderSettings

    animation = facesim.simulate(spec)
    facesim.render(animation, f"{out}/", RenderSettings(width=CELL, height=CELL), force=True)
    return np.stack([iio.imread(p) for p in sorted(out.glob("frame_*.png"))]), animation


def main() -> int:
    from facesim.animation.spec import Spec
    from facesim.export.output import write_frames

    out = ROOT / "out" / "speech-docs"
    out.mkdir(parents=True, exist_ok=True)
    import matplotlib.cbook

    # Grace Hopper's portrait (matplotlib's sample data), whose lips are closed: a photo with
    # an open smile (scikit-image's astronaut) paints its teeth onto the closed lips
    photo = Path(matplotlib.cbook.get_sample_data("grace_hopper.jpg", asfileobj=False))
    face = out / "hopper"
    subprocess.run([sys.executable, "-m", "facesim", "face", "from-photo", str(photo), "-o", str(face), "--force"],
                   check=True)
    cells, animation = [], None
    for who in (None, face):
        for under in ([], [dict(spec="happy", weight=0.8)]):
            spec = Spec.model_validate(dict(name="said", speech=dict(text=SENTENCE), include=under, face=who))
            frames, animation = clip(spec, out / f"{'head' if who is None else 'face'}{len(under)}")
            cells.append(frames)
    n = min(len(c) for c in cells)
    grid = np.concatenate([np.concatenate([cells[0][:n], cells[1][:n]], axis=2),
                           np.concatenate([cells[2][:n], cells[3][:n]], axis=2)], axis=1)
    write_frames(grid, ROOT / "docs" / "speech.mp4", "mp4", animation.fps, audio=(animation.audio, animation.audio_rate))

    spec = Spec.model_validate(dict(name="said", speech=dict(text=SENTENCE)))
    frames = cells[0]
    phones = [p for p in spec.speech.utterance.phones if p.symbol]
    from matplotlib import font_manager

    font = ImageFont.truetype(font_manager.findfont("DejaVu Sans"), 18)  # it has IPA's letters
    tiles = []
    for p in phones:
        k = min(int(round((p.start + p.end) / 2 / spec.dt)), len(frames) - 1)
        tile = Image.fromarray(frames[k][CELL * 11 // 20:CELL * 17 // 20, CELL // 4:CELL * 3 // 4]).resize((192, 115))
        ImageDraw.Draw(tile).text((6, 4), f"/{p.symbol}/", fill=(20, 20, 20), font=font)
        tiles.append(tile)
    columns = 8
    sheet = Image.new("RGB", (192 * columns, 115 * -(-len(tiles) // columns)), "white")
    for k, tile in enumerate(tiles):
        sheet.paste(tile, (192 * (k % columns), 115 * (k // columns)))
    sheet.save(ROOT / "docs" / "speech.png")
    print("wrote docs/speech.mp4 and docs/speech.png")
    return 0


if __name__ == "__main__":
    sys.exit(main())
