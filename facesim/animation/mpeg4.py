"""MPEG-4's facial animation parameters (FAPs; ISO/IEC 14496-2, Annex C; Pandzic and
Forchheimer, "MPEG-4 Facial Animation", 2002): all 68, each mapped to facesim's controls
with its unit and direction (mpeg4.yaml), so that a spec can be given as a FAP stream.

A low-level FAP moves one feature point of the face by a distance in FAP units (FAPU):
a face distance of the neutral face over 1024 (``fap_units``: IRISD the eyelids' opening,
ES the eyes' separation, ENS the eyes' height over the nose's bottom, MNS the nose's
bottom over the mouth, MW the mouth's width), or an angle in 1e-5 rad (AU). facesim does
not move points: its muscles and rig do. A FAP's value therefore becomes an activation of
the control that moves its point that way, ``value / gain``, where the gain is how many
FAP units the control moves the point per unit of activation on the default head
(measured by scripts/mpeg4_gains.py). Being in FAP units, the gain carries to any face
whose motion scales with its features, which is MPEG-4's premise. A negative value of a
bidirectional FAP drives its ``minus`` controls (the antagonists: AU15's depressor for a
lowered corner). Rotations are exact: the head's pose and each eye's gaze in degrees.

FAP 1 (viseme) blends two of MPEG-4's 14 visemes (facesim/speech/visemes.yaml): its
values are viseme_select1, viseme_select2 and viseme_blend (0-63, the first's share);
FAP 2 (expression) two of the six expressions, each with an intensity 0-63.

``read_fap_file`` reads the ASCII FAP file of the standard's reference software: ``#``
comments, a header ``version name fps frames``, then per frame a line of 68 mask bits
and a line with the frame's number and the values of the FAPs its mask sets (FAP 1 takes
four values, FAP 2 six); the two lines of a frame may also be one (VREng's reader takes
them so).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, replace
from functools import lru_cache
from pathlib import Path

import numpy as np
import yaml

from ..errors import InputError
from ..physics.muscles import GAZE, GAZE_ANGLE

MPEG4_FILE = Path(__file__).with_name("mpeg4.yaml")
#: An angle unit (AU) in radians.
ANGLE_UNIT = 1e-5
#: FAP 2's expression_select: MPEG-4's six (Annex C, Table C-4), library specs by name.
EXPRESSIONS = {1: "joy", 2: "sadness", 3: "anger", 4: "fear", 5: "disgust", 6: "surprise"}
#: The largest viseme_blend and expression intensity.
HIGH_LEVEL_MAX = 63
#: Values each FAP takes in a FAP file's frame line: FAP 1's viseme_select1,
#: viseme_select2, viseme_blend and viseme_def; FAP 2's expression_select1,
#: expression_intensity1, expression_select2, expression_intensity2, init_face and
#: expression_def; one for each of the others.
FILE_VALUES = {1: 4, 2: 6}
#: Directions of a positive value in head coordinates (x the subject's left, y up, z out
#: of the face); "growing" is a pupil's widening, measured on its inner rim.
DIRECTIONS = {"left": (1.0, 0.0, 0.0), "right": (-1.0, 0.0, 0.0), "up": (0.0, 1.0, 0.0), "down": (0.0, -1.0, 0.0),
              "forward": (0.0, 0.0, 1.0)}
#: MediaPipe landmarks measuring the FAPUs: the eyelids' midpoints (FDP 3.1-3.4), the
#: eyes' corners (their middles stand for the pupils 3.5, 3.6), the nose's bottom (9.15),
#: the upper lip's inner middle (2.2) and the lips' outer corners (8.3, 8.4).
_LIDS = ((386, 374), (159, 145))
_EYE_CORNERS = ((362, 263), (33, 133))
_NOSE_BOTTOM, _MOUTH_MIDDLE, _CORNERS = 2, 13, (291, 61)


@dataclass(frozen=True)
class FAP:
    number: int
    name: str
    group: int
    unit: str = ""
    both: bool = False
    direction: str = ""
    point: str = ""
    landmark: int | None = None
    plus: dict[str, float] = field(default_factory=dict)
    minus: dict[str, float] = field(default_factory=dict)
    gain: tuple[float, float] = (0.0, 0.0)  # FAP units per unit of control: plus, minus
    pose: dict[str, float] = field(default_factory=dict)  # head angle: sign, for 48-50
    base: dict[str, float] = field(default_factory=dict)  # held under the measurement (FAP 45's jaw)
    none: str = ""

    @property
    def simulated(self) -> bool:
        return self.number <= 2 or bool(self.plus or self.pose)


@lru_cache(maxsize=1)
def fap_table(path: Path = MPEG4_FILE) -> dict[int, FAP]:
    """The 68 FAPs by number, with their controls and gains (mpeg4.yaml); a rotation's
    gain is exact: an eye's gaze control turns it GAZE_ANGLE degrees at 1."""
    table = {}
    for number, row in yaml.safe_load(path.read_text())["faps"].items():
        row = dict(row)
        gain = row.pop("gain", 0.0)
        gain = (float(gain), 0.0) if not isinstance(gain, list) else tuple(float(g) for g in gain)
        fap = FAP(number=int(number), gain=gain, **row)
        if fap.unit == "AU" and fap.plus:
            fap = _gaze_gain(fap)
        table[fap.number] = fap
    assert sorted(table) == list(range(1, 69)), "mpeg4.yaml lists MPEG-4's 68 FAPs"
    return table


def _gaze_gain(fap: FAP) -> FAP:
    """An eye's yaw or pitch: its gaze control at 1 turns it GAZE_ANGLE degrees."""
    def angle(controls: dict[str, float]) -> float:
        (control,) = controls
        degrees = GAZE_ANGLE[GAZE.index(control.rsplit("_", 1)[0])]
        return math.radians(degrees) / ANGLE_UNIT

    return replace(fap, gain=(angle(fap.plus), angle(fap.minus)))


def fap_number(key: int | str) -> int:
    """A FAP's number from its number or its name (``open_jaw``); ValueError otherwise."""
    table = fap_table()
    if isinstance(key, str) and key.strip().isdigit():
        key = int(key)
    if isinstance(key, int) and not isinstance(key, bool):
        if key in table:
            return key
        raise ValueError(f"FAP {key} does not exist: MPEG-4's are numbered 1-68")
    for fap in table.values():
        if fap.name == key:
            return fap.number
    raise ValueError(f"{key!r} is not an MPEG-4 FAP number (1-68) or name such as open_jaw (docs/mpeg4.md)")


def fap_units(landmarks: np.ndarray) -> dict[str, float]:
    """A neutral face's FAP units from its 468 MediaPipe landmarks (any face facesim
    simulates has them: facesim.face.head.Head.landmark_positions), each a distance / 1024
    in the landmarks' units; AU is 1e-5 rad."""
    def distance(a, b):
        return float(np.linalg.norm(landmarks[a] - landmarks[b]))

    eyes = [landmarks[list(corners)].mean(axis=0) for corners in _EYE_CORNERS]
    nose = landmarks[_NOSE_BOTTOM]
    return {
        "IRISD": np.mean([distance(*lid) for lid in _LIDS]) / 1024,
        "ES": float(np.linalg.norm(eyes[0] - eyes[1])) / 1024,
        "ENS": float((eyes[0][1] + eyes[1][1]) / 2 - nose[1]) / 1024,
        "MNS": float(nose[1] - landmarks[_MOUTH_MIDDLE][1]) / 1024,
        "MW": distance(*_CORNERS) / 1024,
        "AU": ANGLE_UNIT,
    }


@dataclass
class FapDrive:
    """What a FAP stream asks of the face, frame by frame: control curves (0-1, before
    the table's clipping), head angles in degrees (facesim.animation.spec.POSE), visemes'
    control curves, expressions' intensities (0-1), and the FAPs facesim cannot show."""

    controls: dict[str, np.ndarray] = field(default_factory=dict)
    pose: dict[str, np.ndarray] = field(default_factory=dict)
    expressions: dict[str, np.ndarray] = field(default_factory=dict)
    unshown: list[int] = field(default_factory=list)

    def add(self, into: dict, name: str, curve: np.ndarray) -> None:
        into[name] = into.get(name, 0.0) + curve


def fap_drive(values: dict[int, np.ndarray]) -> FapDrive:
    """The controls that show a FAP stream: ``values`` maps a FAP's number to its values
    per frame ((frames,) for a low-level FAP, (frames, k) for FAPs 1 and 2, k their
    values in a FAP file's order)."""
    from ..speech.coarticulation import viseme_table

    table, drive = fap_table(), FapDrive()
    for number, value in sorted(values.items()):
        fap = table[number]
        value = np.asarray(value, dtype=float)
        if number == 1:
            visemes = {v.number: v for v in viseme_table().visemes}
            share = np.clip(value[:, 2] / HIGH_LEVEL_MAX, 0.0, 1.0)
            for column, weight in ((0, share), (1, 1.0 - share)):
                for k, viseme in visemes.items():
                    chosen = np.where(value[:, column].round() == k, weight, 0.0)
                    if chosen.any():
                        for control, (target, _) in viseme.controls.items():
                            drive.add(drive.controls, control, chosen * target)
        elif number == 2:
            for select, intensity in ((0, 1), (2, 3)):
                for k, name in EXPRESSIONS.items():
                    chosen = np.where(value[:, select].round() == k, value[:, intensity] / HIGH_LEVEL_MAX, 0.0)
                    if chosen.any():
                        drive.add(drive.expressions, name, np.clip(chosen, 0.0, 1.0))
        elif fap.pose:
            for angle, sign in fap.pose.items():
                drive.add(drive.pose, angle, sign * np.degrees(value * ANGLE_UNIT))
        elif not fap.simulated:
            if np.any(value != 0):
                drive.unshown.append(number)
        else:
            for controls, gain, part in ((fap.plus, fap.gain[0], np.maximum(value, 0.0)),
                                         (fap.minus, fap.gain[1], np.maximum(-value, 0.0))):
                if controls and part.any():
                    for control, weight in controls.items():
                        drive.add(drive.controls, control, weight * part / gain)
    return drive


def read_fap_file(path: Path, source: str | None = None) -> tuple[float, dict[int, np.ndarray]]:
    """(fps, values) of an ASCII FAP file; a FAP a frame's mask leaves out holds its
    last value (MPEG-4's decoder does the same). One-line InputError naming the line."""
    where = source or str(path)
    try:
        lines = [(k + 1, line.split()) for k, line in enumerate(path.read_text().splitlines())]
    except (OSError, UnicodeDecodeError) as exc:
        raise InputError(f"{where}: cannot read the FAP file ({getattr(exc, 'strerror', None) or exc})") from None
    lines = [(k, words) for k, words in lines if words and not words[0].startswith("#")]
    if not lines:
        raise InputError(f"{where}: an empty FAP file (expected a header 'version name fps frames')")
    (k, header), body = lines[0], lines[1:]
    try:
        fps, frames = float(header[2]), int(header[3])
        if not (0 < fps <= 240 and frames >= 1 and len(header) == 4):
            raise ValueError
    except (ValueError, IndexError):
        raise InputError(f"{where}: line {k}: expected the header 'version name fps frames' (fps 0-240, frames >= 1), "
                         f"got {' '.join(header)!r}") from None
    values: dict[int, np.ndarray] = {}
    last: dict[int, list[float]] = {}
    at_line = 0
    for frame in range(frames):
        if at_line >= len(body):
            raise InputError(f"{where}: the header says {frames} frames, and the file ends after {frame}")
        k, mask = body[at_line]
        if len(mask) > 68:  # the mask and the values on one line (as VREng's reader takes them)
            mask, line, j = mask[:68], mask[68:], k
            at_line += 1
        elif at_line + 1 < len(body):
            (j, line), at_line = body[at_line + 1], at_line + 2
        else:
            raise InputError(f"{where}: line {k}: frame {frame}'s mask has no line of values after it")
        if len(mask) != 68 or any(m not in ("0", "1") for m in mask):
            raise InputError(f"{where}: line {k}: expected the mask of frame {frame}: 68 digits 0 or 1")
        numbers = [n + 1 for n, m in enumerate(mask) if m == "1"]
        expected = 1 + sum(FILE_VALUES.get(n, 1) for n in numbers)
        try:
            read = [float(w) for w in line]
        except ValueError:
            read = []
        if len(read) != expected or not all(math.isfinite(v) for v in read):
            raise InputError(f"{where}: line {j}: expected frame {frame}'s number and {expected - 1} finite values "
                             f"for the FAPs its mask sets, got {' '.join(line)!r}")
        at = 1
        for n in numbers:
            size = FILE_VALUES.get(n, 1)
            last[n] = read[at:at + size]
            at += size
        for n, held in last.items():
            values.setdefault(n, np.zeros((frames, FILE_VALUES.get(n, 1))))[frame] = held
    if at_line < len(body):
        raise InputError(f"{where}: line {body[at_line][0]}: more frames than the header's {frames}")
    return fps, {n: (v[:, 0] if n not in FILE_VALUES else v) for n, v in values.items()}


def point_motion(animation, fap: FAP, frame: int) -> float:
    """How far (in the head's units) a FAP's feature point has moved at ``frame`` along
    the FAP's positive direction, on the head as the renderer draws it
    (``Animation.head_at``): a landmark, an eye's pupil (its cornea's apex), an iris's
    inner rim (its widening), the tongue's tip. Measures a FAP's gain and direction."""
    figure, head = animation.figure, animation.model.mesh.head
    rest, x = figure.rest, animation.head_at(frame)
    side = 0 if fap.point.endswith("_l") else 1
    if fap.point.startswith("iris"):
        pupil = [p for p in figure.pupils if (p.centre[0] > 0) == (side == 0)][0]
        inner = pupil.rows[np.argmin(pupil.radius)]
        return float(2 * (np.linalg.norm(np.cross(x[inner] - pupil.centre, pupil.axis))
                          - np.linalg.norm(np.cross(rest[inner] - pupil.centre, pupil.axis))))
    if fap.point.startswith("pupil"):
        rows = head.part("eyeball_left" if side == 0 else "eyeball_right")
        apex = rows[np.argmax(rest[rows, 2])]
        moved = x[apex] - rest[apex]
    elif fap.point == "tongue_tip":
        rows = figure.tongue.rows
        tip = rows[np.argmax(rest[rows, 2])]
        moved = x[tip] - rest[tip]
    else:
        weights, rows = head.landmark_weight[fap.landmark], head.landmark_vertex[fap.landmark]
        moved = weights @ (x[rows] - rest[rows])
    return float(moved @ np.asarray(DIRECTIONS[fap.direction]))
