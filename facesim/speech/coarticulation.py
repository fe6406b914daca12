"""Coarticulation: timed phonemes into curves of facesim's controls, by Cohen and
Massaro's dominance model (M. M. Cohen and D. W. Massaro, "Modeling coarticulation in
synthetic visual speech", Models and Techniques in Computer Animation, 1993).

Each phoneme s is a viseme (MPEG-4's 14, facesim/speech/visemes.yaml) with, for each
control c, a target T_sc and a dominance that falls off with the time τ from the
phoneme (Cohen and Massaro's eq. 1):

    D_sc(τ) = α_sc exp(-θ_c |τ|^k),    θ_c: θ←_c before the phoneme, θ→_c after it

and a control's value at time t is the dominance-weighted mean of every phoneme's
target (their eq. 2):

    F_c(t) = Σ_s D_sc(t - t_s) T_sc / Σ_s D_sc(t - t_s)

τ is measured from the middle half of the phoneme (0 inside it), at least ``HOLD`` long,
so that a long vowel holds its shape and a short consonant still reaches its own. What the model gives:
a bilabial's seal dominates whatever surrounds it (α = 10 against its neighbours' 0.1-0.5),
so /p b m/ close the lips; the lips round ahead of a rounded vowel (the rounding's
anticipatory rate θ← is the lowest: it spreads over the consonants before it, whose
own dominance on rounding is low); and the jaw, which vowels dominate and consonants
hardly do, does not close between the syllables of a word.

The curves are sampled at the sound's own times: the lips' opening and the sound's
energy are best aligned within a frame (tests/test_speech.py), so no lead is added.
"""

from __future__ import annotations

import unicodedata
from dataclasses import dataclass
from functools import cached_property, lru_cache
from pathlib import Path

import numpy as np
import yaml

from ..errors import InputError
from .espeak import Phone

VISEMES_FILE = Path(__file__).with_name("visemes.yaml")
#: θ (1/s) before and after a phoneme, per control: the lips' rounding anticipates
#: furthest, the seal and the tongue are quick.
RATES = {"jaw": (35.0, 35.0), "lip_seal": (60.0, 200.0), "incisivus_labii": (9.0, 14.0), "risorius": (18.0, 18.0),
         "lip_roll_lower": (40.0, 40.0), "levator_labii_superioris": (35.0, 35.0), "tongue_up": (40.0, 40.0),
         "tongue_out": (40.0, 40.0)}
#: Cohen and Massaro's exponent k.
POWER = 1.0
#: The shortest time a segment holds its own shape (s), around its middle: eSpeak's
#: stops after a pause are 30-35 ms (their closure is in the pause), and a bilabial's
#: closure lasts 70-100 ms in speech.
HOLD = 0.08


@dataclass(frozen=True)
class Viseme:
    number: int
    name: str
    example: str
    phonemes: tuple[str, ...]
    dominance: float
    controls: dict[str, tuple[float, float]]

    def pattern(self, controls: tuple[str, ...]) -> tuple[np.ndarray, np.ndarray]:
        """(targets, dominances) over ``controls``."""
        pairs = [self.controls.get(c, (0.0, self.dominance)) for c in controls]
        return np.array([t for t, _ in pairs]), np.array([a for _, a in pairs])


@dataclass(frozen=True)
class VisemeTable:
    controls: tuple[str, ...]
    visemes: tuple[Viseme, ...]

    @cached_property
    def by_phoneme(self) -> dict[str, Viseme]:
        return {p: v for v in self.visemes for p in v.phonemes}

    def split(self, symbol: str) -> list[Viseme] | None:
        """A phoneme's visemes: its own, or a diphthong's (or a sequence's) parts, each
        the longest symbol of the table it starts with; None if some part has none."""
        table, parts, rest = self.by_phoneme, [], symbol
        while rest:
            for size in range(len(rest), 0, -1):
                if rest[:size] in table:
                    parts.append(table[rest[:size]])
                    rest = rest[size:]
                    break
            else:
                bare = _bare(rest)
                if bare == rest:
                    return None
                rest = bare
        return parts or [table[""]]


def _bare(symbol: str) -> str:
    """``symbol`` without its diacritics (combining marks), length marks and eSpeak's
    ``-`` (French's unstressed schwa, ``ə-``)."""
    return "".join(c for c in unicodedata.normalize("NFD", symbol) if not unicodedata.combining(c) and c not in "ːˑ-")


@lru_cache(maxsize=1)
def viseme_table(path: Path = VISEMES_FILE) -> VisemeTable:
    data = yaml.safe_load(path.read_text())
    controls = tuple(data["controls"])
    visemes = tuple(Viseme(int(number), str(v["name"]), str(v["example"]), tuple(str(p) for p in v["phonemes"]),
                           float(v["dominance"]), {c: (float(t), float(a)) for c, (t, a) in v["controls"].items()})
                    for number, v in data["visemes"].items())
    return VisemeTable(controls, visemes)


@dataclass(frozen=True)
class Segment:
    """A viseme over [start, end) s: a phoneme, or half of a diphthong's."""

    viseme: Viseme
    start: float
    end: float


def segments(phones: tuple[Phone, ...], where: str = "speech") -> list[Segment]:
    """The phonemes as viseme segments, diphthongs split in equal parts. InputError
    naming the phonemes the table has no viseme for."""
    table = viseme_table()
    out, unknown = [], []
    for phone in phones:
        parts = table.split(phone.symbol)
        if parts is None:
            unknown.append(phone.symbol)
            continue
        step = (phone.end - phone.start) / len(parts)
        out.extend(Segment(v, phone.start + k * step, phone.start + (k + 1) * step) for k, v in enumerate(parts))
    if unknown:
        raise InputError(f"{where}: phonemes with no viseme: {' '.join(sorted(set(unknown)))} "
                         f"(facesim/speech/visemes.yaml lists eSpeak NG's English ones)")
    return out


def control_curves(segs: list[Segment], times: np.ndarray) -> dict[str, np.ndarray]:
    """Each control's value F_c(t) at ``times`` (s) (Cohen and Massaro's eq. 1-2);
    silence (viseme 0) before the first segment and after the last."""
    table = viseme_table()
    controls = table.controls
    rest = next(v for v in table.visemes if v.number == 0)
    edge = (segs[0].start if segs else 0.0, segs[-1].end if segs else 0.0)
    padded = [Segment(rest, edge[0] - 1.0, edge[0]), *segs, Segment(rest, edge[1], edge[1] + 1.0)]
    t = np.asarray(times, dtype=float)[:, None]
    numerator = np.zeros((len(t), len(controls)))
    denominator = np.zeros_like(numerator)
    before = np.array([RATES[c][0] for c in controls])
    after = np.array([RATES[c][1] for c in controls])
    for seg in padded:
        target, alpha = seg.viseme.pattern(controls)
        middle, half = (seg.start + seg.end) / 2, max((seg.end - seg.start) / 4, HOLD / 2)
        early = np.maximum(middle - half - t, 0.0)  # τ before the middle half (or HOLD)
        late = np.maximum(t - (middle + half), 0.0)  # and after it
        dominance = alpha * np.exp(-(before * early ** POWER + after * late ** POWER))
        numerator += dominance * target
        denominator += dominance
    values = numerator / np.maximum(denominator, 1e-300)
    return {c: values[:, k] for k, c in enumerate(controls)}

