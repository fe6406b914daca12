"""Measure each low-level MPEG-4 FAP's gain on the default head: how many FAP units its
controls move its feature point along its direction per unit of activation
(facesim.animation.mpeg4), the controls held at HALF and the motion doubled.

    .venv/bin/python scripts/mpeg4_gains.py            # print the gains
    .venv/bin/python scripts/mpeg4_gains.py --write    # and write them into mpeg4.yaml
    .venv/bin/python scripts/mpeg4_gains.py --docs     # only docs/mpeg4.md's table

Each run writes docs/mpeg4.md's table from mpeg4.yaml.
"""

import re
import sys

import facesim
from facesim.animation.mpeg4 import MPEG4_FILE, fap_table, fap_units, point_motion
from facesim.animation.spec import Spec
from facesim.animation.timeline import AU_NAME

#: The activation the gain is measured at: the middle of the controls' range.
HALF = 0.5
FRAMES = 60


def held(controls: dict[str, float], level: float, base: dict[str, float] | None = None) -> Spec:
    """A spec holding ``controls`` at ``level`` (on top of ``base``, held at its own)."""
    levels = {**(base or {}), **{c: w * level for c, w in controls.items()}}
    aus = {c: v for c, v in levels.items() if AU_NAME.fullmatch(c)}
    activations = {c: v for c, v in levels.items() if c not in aus}
    return Spec(name="gain", frames=FRAMES, aus=aus, activations=activations)


def motion(fap, controls: dict[str, float], level: float) -> tuple[float, object]:
    """The feature point's motion along the FAP's direction with ``controls`` held at
    ``level``, less the motion of the FAP's base alone."""
    animation = facesim.simulate(held(controls, level, fap.base))
    moved = point_motion(animation, fap, FRAMES - 1)
    if fap.base:
        moved -= point_motion(facesim.simulate(held({}, 0.0, fap.base)), fap, FRAMES - 1)
    return moved, animation


def measured_gains() -> dict[int, tuple[float, float]]:
    units = None
    gains = {}
    for fap in fap_table().values():
        if not fap.simulated or fap.number <= 2 or fap.pose or fap.unit == "AU":
            continue
        pair = []
        for controls, sign in ((fap.plus, 1.0), (fap.minus, -1.0)):
            if not controls:
                pair.append(0.0)
                continue
            moved, animation = motion(fap, controls, HALF)
            if units is None:
                units = fap_units(animation.model.mesh.head.landmark_positions)
            pair.append(sign * moved / units[fap.unit] / HALF)
        gains[fap.number] = tuple(pair)
        print(f"{fap.number:3d} {fap.name:24s} {fap.unit:5s} plus {pair[0]:8.1f}  minus {pair[1]:8.1f}", flush=True)
    return gains


def write(gains: dict[int, tuple[float, float]]) -> None:
    text = MPEG4_FILE.read_text()
    for number, (plus, minus) in gains.items():
        fap = fap_table()[number]
        value = f"{plus:.0f}" if not fap.both else f"[{plus:.0f}, {minus:.0f}]"
        text, found = re.subn(rf"^(  {number}: \{{.*gain: )(\[[^\]]*\]|[-\d.]+)\}}$", rf"\g<1>{value}}}", text, flags=re.M)
        assert found == 1, number
    MPEG4_FILE.write_text(text)




def table_markdown() -> str:
    """docs/mpeg4.md's table: every FAP with its unit, direction, point and controls."""
    def controls(c: dict[str, float]) -> str:
        return ", ".join(f"`{name}`" + ("" if w == 1 else f" ×{w:g}") for name, w in c.items())

    rows = ["| FAP | name | unit | B/U | positive | point | + drives (gain) | − drives (gain) |",
            "|---:|---|---|---|---|---|---|---|"]
    for fap in fap_table().values():
        if fap.number == 1:
            plus, minus = "two of the 14 visemes (facesim/speech/visemes.yaml), blended", ""
        elif fap.number == 2:
            plus, minus = "two of the six expressions (the library's specs), each 0-63", ""
        elif fap.pose:
            (angle, sign), = fap.pose.items()
            plus, minus = f"the pose's `{angle}` ({'+' if sign > 0 else '−'}degrees)", "the other way"
        elif fap.none:
            plus, minus = f"none: {fap.none}", ""
        else:
            plus = f"{controls(fap.plus)} ({fap.gain[0]:.0f})" + (f", with {controls(fap.base)} held" if fap.base else "")
            minus = f"{controls(fap.minus)} ({fap.gain[1]:.0f})" if fap.minus else ("none" if fap.both else "")
        both = "" if fap.number <= 2 else ("B" if fap.both else "U")
        rows.append(f"| {fap.number} | {fap.name} | {fap.unit} | {both} | {fap.direction} | {fap.point} | {plus} | {minus} |")
    return "\n".join(rows) + "\n"


def write_docs() -> None:
    path = MPEG4_FILE.parents[2] / "docs" / "mpeg4.md"
    text = path.read_text()
    start = text.index("| FAP | name |")
    end = text.find("\n\n", start)
    end = len(text) if end < 0 else end + 1
    path.write_text(text[:start] + table_markdown() + text[end:])


if __name__ == "__main__":
    if "--docs" not in sys.argv:
        gains = measured_gains()
        if "--write" in sys.argv:
            write(gains)
    write_docs()
