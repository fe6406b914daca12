"""Animation control on top of the physics: key-frame curves, FACS action units, the
MPEG-4 style expressions and their blends, and sequences. Everything here ends in one
(frames, muscles) activation table, built once before the simulation.

Interpolation between key-frames (the parametric key-frame seed, section 3):

- ``linear``    straight lines between keys;
- ``cosine``    Parke's ease in and out, v0 + (v1 - v0) (1 - cos πF) / 2;
- ``bspline``   the uniform cubic B-spline with the keys as control points (its eq. 3),
                which approximates rather than passes through the inner keys;
- ``cardinal``  the cardinal spline through every key with tangents
                (1 - tension) (p[i+1] - p[i-1]) / 2 (its eq. 4-6);
- ``hold``      the seed's modified cardinal spline: where two neighbouring keys are
                equal the curve holds flat, and at every key that is a local extremum the
                tangent is zero, so it neither drifts between equal keys nor overshoots.

F runs from 0 to 1 across each segment; before the first key and after the last the curve
holds the end values. The outer control points are the end keys reflected
(p[-1] = 2 p[0] - p[1]), so every curve starts and ends exactly on its end keys.
"""

from __future__ import annotations

import re

import numpy as np

INTERPOLATIONS = ("linear", "cosine", "bspline", "cardinal", "hold")


def _segments(times: np.ndarray, query: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """For each query time: its segment i (keys i, i+1) and F in [0, 1]."""
    clamped = np.clip(query, times[0], times[-1])
    i = np.clip(np.searchsorted(times, clamped, side="right") - 1, 0, len(times) - 2)
    return i, (clamped - times[i]) / (times[i + 1] - times[i])


def interpolate(times, values, query, kind: str = "linear", tension: float = 0.0) -> np.ndarray:
    """The curve through key-frames (times strictly increasing) at the query times."""
    times = np.asarray(times, dtype=float)
    values = np.asarray(values, dtype=float)
    query = np.asarray(query, dtype=float)
    if len(times) == 1:
        return np.full(query.shape, values[0])
    i, f = _segments(times, query)
    padded = np.concatenate([[2 * values[0] - values[1]], values, [2 * values[-1] - values[-2]]])
    p0, p1, p2, p3 = padded[i], padded[i + 1], padded[i + 2], padded[i + 3]
    if kind == "linear":
        return p1 + f * (p2 - p1)
    if kind == "cosine":
        return p1 + (p2 - p1) * (1 - np.cos(np.pi * f)) / 2
    if kind == "bspline":
        return ((1 - f) ** 3 * p0 + (3 * f**3 - 6 * f**2 + 4) * p1 + (-3 * f**3 + 3 * f**2 + 3 * f + 1) * p2 + f**3 * p3) / 6
    if kind in ("cardinal", "hold"):
        tangent = (1 - tension) * (padded[2:] - padded[:-2]) / 2  # at every key
        if kind == "hold":
            flat = (padded[1:-1] - padded[:-2]) * (padded[2:] - padded[1:-1]) <= 0
            tangent = np.where(flat, 0.0, tangent)
        m1, m2 = tangent[i], tangent[i + 1]
        return ((2 * f**3 - 3 * f**2 + 1) * p1 + (-2 * f**3 + 3 * f**2) * p2 + (f**3 - 2 * f**2 + f) * m1
                + (f**3 - f**2) * m2)
    raise ValueError(f"unknown interpolation {kind!r}")


def envelope_keys(start: float, onset: float, apex: float, offset: float, intensity: float) -> list[tuple[float, float]]:
    """The common onset / apex / offset envelope as key-frames: rise, hold, fall."""
    keys = [(start, 0.0), (start + onset, intensity), (start + onset + apex, intensity)]
    if offset > 0:
        keys.append((start + onset + apex + offset, 0.0))
    return keys


# --- FACS action units ----------------------------------------------------------------

#: Action unit -> (name, muscles and how much of each). Muscles are given without side;
#: an AU drives both sides, and its one-sided form (FACS's L and R: ``AU12_L``, the
#: subject's left) the muscles of that side alone (``au_muscles``). The jaw and the eyelids (facesim.physics.rig) count as muscles here:
#: AU26 opens the jaw half way (half its max_angle), AU27 fully. AUs whose muscles the
#: face does not have are errors.
ACTION_UNITS: dict[str, tuple[str, dict[str, float]]] = {
    "AU1": ("inner brow raiser", {"frontalis_medial": 1.0, "frontalis_galea": 1.0}),
    "AU2": ("outer brow raiser", {"frontalis_lateral": 1.0, "frontalis_outer": 1.0, "frontalis_medial": 0.2, "frontalis_galea": 0.2}),
    "AU4": ("brow lowerer", {"corrugator_supercilii": 1.0, "procerus": 1.0}),
    "AU5": ("upper lid raiser", {"levator_palpebrae": 1.0}),
    "AU6": ("cheek raiser", {"malaris": 1.0, "orbicularis_oculi": 0.3}),
    "AU7": ("lid tightener", {"orbicularis_oculi_palpebral": 1.0}),
    "AU9": ("nose wrinkler", {"levator_labii_superioris_alaeque_nasi": 1.0}),
    "AU10": ("upper lip raiser", {"levator_labii_superioris": 1.0}),
    "AU11": ("nasolabial deepener", {"zygomaticus_minor": 1.0}),
    "AU12": ("lip corner puller", {"zygomaticus_major": 1.0}),
    "AU13": ("sharp lip puller", {"levator_anguli_oris": 1.0}),
    "AU14": ("dimpler", {"buccinator": 1.0}),
    "AU15": ("lip corner depressor", {"depressor_anguli_oris": 1.0}),
    "AU16": ("lower lip depressor", {"depressor_labii_inferioris": 1.0}),
    # The mentalis raises the chin, whose bunched tissue pushes the lower lip up and
    # everts it: ICT's chin raiser moves the lower lip 5 mm forward and the chin 2 mm. A
    # single-layer skin cannot carry the chin's bulge onto the lip, and a push on the
    # mentalis itself carried the chin 13 mm forward; the lower incisivi, drawing the lip
    # toward the incisive fossa and, squeezed, forward, stand for it (0.74 -> 0.89)
    "AU17": ("chin raiser", {"mentalis": 1.0, "incisivus_labii_inferioris": 1.0}),
    "AU18": ("lip pucker", {"incisivus_labii": 1.0}),
    # FACS scores the tongue shown with the lips parted and the jaw dropped (AU25, AU26):
    # the unit opens the jaw as AU26 does, enough for the tongue to pass between the
    # incisors (facesim.face.tongue.Tongue: it stays behind them while they are closer)
    "AU19": ("tongue show", {"tongue_out": 1.0, "jaw": 0.5}),
    "AU20": ("lip stretcher", {"risorius": 1.0}),
    # the funnel's lips drawn apart by the lower lip depressor and the upper lip raiser,
    # weighted so as ICT's funnel (0.82) with the lips' inclined contact
    "AU22": ("lip funneler", {"incisivus_labii": 1.0, "depressor_labii_inferioris": 0.5, "levator_labii_superioris": 0.4}),
    "AU23": ("lip tightener", {"orbicularis_oris": 0.8}),
    # ICT's lip press (mouthPress) is more than the ring: the chin and lower lip rise 3-5 mm
    # and come forward, the upper lip comes down 1 mm, the corners in a little. The ring
    # alone moved the skin nearly at right angles to it (cosine 0.34); with 0.4 of the chin
    # raiser's two muscles, weights searched with them (scripts/calibrate.py), 0.81
    "AU24": ("lip pressor", {"mentalis": 0.42, "orbicularis_oris": 0.29, "incisivus_labii_inferioris": 0.34}),
    # FACS: the lips part by the lower lip's depressor (or the mentalis and the ring
    # letting go), the jaw still; with a little of the upper lip's raiser the lips' middles
    # part 4.5 mm and the corners stay (ICT has no shape for it to calibrate against)
    "AU25": ("lips part", {"depressor_labii_inferioris": 0.5, "levator_labii_superioris": 0.2}),
    "AU26": ("jaw drop", {"jaw": 0.5}),
    "AU27": ("mouth stretch", {"jaw": 1.0}),
    # the condyles glide along the articular eminence (facesim.physics.rig): forward, and
    # to one side (FACS scores AU30 with L or R: the side the jaw moves to)
    "AU29": ("jaw thrust", {"jaw_thrust": 1.0}),
    # the orbicularis oris's marginal part rolls both lips in over the teeth (the jaw's
    # rig); each at 0.7: both at 1, the rolled lips meet behind the teeth's line and fold
    # 2 triangles where they do (ARKit's mouthRollUpper and mouthRollLower are each alone)
    "AU28": ("lip suck", {"lip_roll_upper": 0.7, "lip_roll_lower": 0.7}),
    # air held in the closed mouth pushes the cheeks out (facesim.physics.pressure); the
    # lips are held shut against it (the jaw rig's seal: facesim.physics.contacts)
    "AU34": ("cheek puff", {"cheek_puff": 1.0, "lip_seal": 1.0}),
    "AU30": ("jaw sideways", {"jaw_sideways": 1.0}),
    "AU43": ("eyes closed", {"eyelid": 1.0}),
    "AU45": ("blink", {"eyelid": 1.0}),
    "AU46": ("wink", {"eyelid": 1.0}),
    # the eyes turned (FACS's eye positions), the lids following them (facesim.physics.rig);
    # each eye alone with _L or _R (ARKit's eyeLookOutLeft is AU61_L, eyeLookInLeft AU62_L)
    "AU61": ("eyes turned left", {"gaze_left": 1.0}),
    "AU62": ("eyes turned right", {"gaze_right": 1.0}),
    "AU63": ("eyes up", {"gaze_up": 1.0}),
    "AU64": ("eyes down", {"gaze_down": 1.0}),
}
#: MPEG-4 facial animation parameters that name a control of this face (FAPs 3, 14 and
#: 19-22), usable wherever a muscle name is, with values in [0, 1] of the control's range
#: rather than in FAP units. MPEG-4's left is the subject's left, as ``_l`` is here.
MPEG4_FAPS = {"open_jaw": "jaw", "thrust_jaw": "jaw_thrust", "close_t_l_eyelid": "eyelid_l", "close_b_l_eyelid": "eyelid_l",
              "close_t_r_eyelid": "eyelid_r", "close_b_r_eyelid": "eyelid_r"}
#: FACS intensity letters, trace (A) to maximum (E).
FACS_LETTERS = {"A": 0.2, "B": 0.4, "C": 0.6, "D": 0.8, "E": 1.0}

#: Co-occurrence rules, applied to AU intensities frame by frame, in this order:
#: domination: when both act, the dominated AU is weakened by the dominant one,
#:   I_dominated * (1 - I_dominant) (FACS: AU15 dominates AU12);
#: opposition: antagonists acting on the same tissue cancel, the stronger keeps the
#:   difference (AU16 pulls the lower lip down, AU17 pushes it up).
DOMINATION = [("AU15", "AU12")]
OPPOSITION = [("AU16", "AU17")]


def parse_intensity(value) -> float:
    """A FACS letter A-E or a number in [0, 1]."""
    if isinstance(value, str):
        letter = value.strip().upper()
        if letter not in FACS_LETTERS:
            raise ValueError(f"intensity must be a FACS letter A-E or a number 0-1, got {value!r}")
        return FACS_LETTERS[letter]
    value = float(value)
    if not 0.0 <= value <= 1.0:
        raise ValueError(f"intensity must be between 0 and 1, got {value}")
    return value


#: An action unit's name: FACS's number, and L or R for its one-sided form (``AU12_L``).
AU_NAME = re.compile(r"AU(\d+)(?:_([LR]))?")
#: Units FACS scores on one side only: a wink, the jaw moved to one side.
ONE_SIDED = {"AU46", "AU30"}


def apply_cooccurrence(intensity: dict[str, np.ndarray]) -> dict[str, np.ndarray]:
    """Domination and opposition rules on per-frame AU intensities, between the units of
    both sides and between those of one side (AU15_L dominates AU12_L)."""
    out = dict(intensity)
    for side in ("", "_L", "_R"):
        for dominant, dominated in DOMINATION:
            dominant, dominated = dominant + side, dominated + side
            if dominant in out and dominated in out:
                out[dominated] = out[dominated] * (1 - out[dominant])
        for a, b in OPPOSITION:
            a, b = a + side, b + side
            if a in out and b in out:
                out[a], out[b] = np.maximum(out[a] - out[b], 0), np.maximum(out[b] - out[a], 0)
    return out


def au_muscles(au: str, muscle_names: tuple[str, ...]) -> dict[str, float]:
    """The muscles (with sides) an AU drives on this face; an error naming what is missing.
    A one-sided unit (``AU12_L``) drives its muscles of that side (``_l``: the subject's
    left); a midline muscle (the procerus; on the thesis's face, the frontalis over the
    galea, which the head has one a side), which lies across both sides, at half its
    weight; a unit of midline muscles or the jaw alone (AU23's lip ring, AU26's jaw) has
    no one-sided form."""
    match = AU_NAME.fullmatch(au)
    if match is None or f"AU{match[1]}" not in ACTION_UNITS:
        raise ValueError(f"unknown action unit {au!r} (known: {', '.join(ACTION_UNITS)}, each also with _L or _R)")
    unit, side = f"AU{match[1]}", match[2]
    name, muscles = ACTION_UNITS[unit]
    if side is None and unit in ONE_SIDED:
        raise ValueError(f"{unit} ({name}) acts on one side: give {unit}_L or {unit}_R")
    out = {}
    for muscle, weight in muscles.items():
        found = [n for n in muscle_names if n == muscle or n in (f"{muscle}_l", f"{muscle}_r")]
        if not found:
            raise ValueError(f"{au} ({name}) needs the {muscle.replace('_', ' ')}, which this face's muscle file does not have")
        if side is not None:
            found = [n for n in found if n == muscle or n.endswith(f"_{side.lower()}")]
            weight = weight / 2 if found == [muscle] else weight
        out.update({n: weight for n in found})
    if side is not None and all(n in muscles for n in out):
        raise ValueError(f"{au}: {unit} ({name}) moves both sides at once ({', '.join(n.replace('_', ' ') for n in out)}); "
                         f"it has no one-sided form")
    return out
