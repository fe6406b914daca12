"""How far each FACS action unit facesim drives is from ICT FaceKit's scanned shape for it.

For every action unit of ICT's FACS table that issue 16 names, simulate it alone at full
intensity on the default head (eased in over 10 frames, held to frame 80), take the
head's face area (ICT vertices 0-9408) at the last frame, and compare its displacement
from the neutral with ICT's shape for that unit (the sum of its shapes' deltas, from
``shapes.npz`` beside ICT's README), vertex for vertex:

- direction: the cosine between the two displacement fields, over the vertices that
  either moves by at least 1 mm;
- amplitude: the ratio of their norms over the same vertices, and of the mean
  displacement at the 20 vertices ICT moves most.

Writes the table to REALISM.md (``make realism``). ICT's shapes are measurements here,
never an input to the simulation. Reads ICT's data from ``--ict`` (default
``../shared/ict-facekit``, where the project's build scripts read it).
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent

#: ICT's FACS table (its README): action unit -> (shapes, weight). AU26 is half of jawOpen.
ICT_SHAPES = {
    "AU1": ["browInnerUp_L", "browInnerUp_R"], "AU2": ["browOuterUp_L", "browOuterUp_R"],
    "AU4": ["browDown_L", "browDown_R"], "AU5": ["eyeWide_L", "eyeWide_R"],
    "AU6": ["cheekSquint_L", "cheekSquint_R"], "AU7": ["eyeSquint_L", "eyeSquint_R"],
    "AU9": ["noseSneer_L", "noseSneer_R"], "AU10": ["mouthShrugUpper"],
    "AU11": ["mouthUpperUp_L", "mouthUpperUp_R"], "AU12": ["mouthSmile_L", "mouthSmile_R"],
    "AU14": ["mouthDimple_L", "mouthDimple_R"], "AU15": ["mouthFrown_L", "mouthFrown_R"],
    "AU16": ["mouthLowerDown_L", "mouthLowerDown_R"], "AU17": ["mouthShrugLower"], "AU18": ["mouthPucker"],
    "AU20": ["mouthStretch_L", "mouthStretch_R"], "AU22": ["mouthFunnel"], "AU24": ["mouthPress_L", "mouthPress_R"],
    "AU26": ["jawOpen"], "AU27": ["jawOpen"], "AU45": ["eyeBlink_L", "eyeBlink_R"],
}
ICT_WEIGHT = {"AU26": 0.5}
FACE_AREA = 9409  # ICT's face area: vertices 0-9408
MOVES = 0.1  # cm: a vertex takes part in the comparison when either field moves it this far
TOP = 20  # vertices ICT moves most, for the peak amplitude
#: Issue 16's bounds.
COSINE, AMPLITUDE = 0.8, (0.75, 1.33)


def ict_displacement(shapes, au: str) -> np.ndarray:
    names = list(shapes["expression_names"])
    deltas = shapes["expression_deltas"]
    total = sum(deltas[names.index(n)].astype(np.float64) for n in ICT_SHAPES[au])
    return ICT_WEIGHT.get(au, 1.0) * total[:FACE_AREA]


def facesim_displacement(au: str) -> tuple[np.ndarray, int] | None:
    """The face area's displacement with ``au`` held at 1.0 and the most inverted
    triangles in any frame, or None when facesim does not drive that unit."""
    import facesim
    from facesim.simulate import figure_for
    from facesim.spec import Spec
    from facesim.timeline import ACTION_UNITS

    if au not in ACTION_UNITS:
        return None
    spec = Spec.model_validate(dict(name=au, frames=80, onset=10, aus={au: 1.0}))
    animation = facesim.simulate(spec, stop_on_inversion=False)
    figure = figure_for(animation.model)
    last = animation.frames - 1
    moved = figure.positions(animation.positions[last], animation.jaw_at(last))
    return (moved - figure.rest)[:FACE_AREA], int(animation.inverted.max())


def compare(ours: np.ndarray, theirs: np.ndarray) -> dict[str, float]:
    either = (np.linalg.norm(ours, axis=1) >= MOVES) | (np.linalg.norm(theirs, axis=1) >= MOVES)
    a, b = ours[either].ravel(), theirs[either].ravel()
    top = np.argsort(np.linalg.norm(theirs, axis=1))[-TOP:]
    return dict(
        cosine=float(a @ b / max(np.linalg.norm(a) * np.linalg.norm(b), 1e-12)),
        amplitude=float(np.linalg.norm(a) / max(np.linalg.norm(b), 1e-12)),
        peak=float(np.linalg.norm(ours[top], axis=1).mean() / np.linalg.norm(theirs[top], axis=1).mean()),
        ict_peak=float(np.linalg.norm(theirs[top], axis=1).mean()),
        ours_peak=float(np.linalg.norm(ours[top], axis=1).mean()),
    )


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--ict", type=Path, default=ROOT.parent / "shared" / "ict-facekit")
    parser.add_argument("-o", "--output", type=Path, default=ROOT / "REALISM.md")
    args = parser.parse_args()
    started = time.perf_counter()
    shapes = np.load(args.ict / "shapes.npz")
    rows, passed = [], 0
    for au in ICT_SHAPES:
        theirs = ict_displacement(shapes, au)
        simulated = facesim_displacement(au)
        if simulated is None:
            rows.append(f"| {au} | {' + '.join(ICT_SHAPES[au])} | not driven | | | | | | fails |")
            print(f"{au}: not driven", flush=True)
            continue
        ours, inverted = simulated
        c = compare(ours, theirs)
        ok = c["cosine"] >= COSINE and AMPLITUDE[0] <= c["amplitude"] <= AMPLITUDE[1] and inverted == 0
        passed += ok
        rows.append(f"| {au} | {' + '.join(ICT_SHAPES[au])} | {c['cosine']:.2f} | {c['amplitude']:.2f} | {c['peak']:.2f} "
                    f"| {10 * c['ours_peak']:.1f} | {10 * c['ict_peak']:.1f} | {inverted} | {'passes' if ok else 'fails'} |")
        print(rows[-1], flush=True)
    text = (
        "# Realism: facesim's action units against ICT FaceKit's scanned FACS shapes\n\n"
        f"Produced by `make realism` (`python scripts/realism.py`) on {time.strftime('%Y-%m-%d')} in "
        f"{time.perf_counter() - started:.0f} s, on the default head. Each action unit alone at full intensity "
        "(eased in over 10 frames, held to frame 80), the face area (ICT vertices 0-9408) at the last frame, "
        "against the sum of ICT's shapes for that unit (ICT's own FACS table; AU26 is half of jawOpen). "
        f"Cosine: of the two displacement fields over the vertices either moves by at least {10 * MOVES:.0f} mm. "
        f"Amplitude: the ratio of their norms there; peak: of the mean displacement at the {TOP} vertices ICT "
        f"moves most. Inverted triangles: the most in any frame of the simulated mesh. Issue 16's bounds: cosine "
        f"at least {COSINE}, amplitude {AMPLITUDE[0]}-{AMPLITUDE[1]}, no inverted triangle.\n\n"
        f"**{passed} of {len(ICT_SHAPES)} action units within the bounds.**\n\n"
        "| AU | ICT shapes | cosine | amplitude | peak ratio | facesim peak (mm) | ICT peak (mm) | inverted triangles | |\n"
        "|---|---|---|---|---|---|---|---|---|\n" + "\n".join(rows) + "\n"
    )
    args.output.write_text(text)
    print(f"wrote {args.output}: {passed} of {len(ICT_SHAPES)} within the bounds")
    return 0


if __name__ == "__main__":
    sys.exit(main())
