"""Speech, a way into facesim below the animation: words said by eSpeak NG (``espeak``:
the waveform and its timed phonemes), the phonemes as MPEG-4's visemes and the visemes
as curves of facesim's controls, coarticulated by Cohen and Massaro's dominance model
(``coarticulation``, the table in ``visemes.yaml``); or a recording's sound and its
phonemes, aligned to its words by PocketSphinx (``recording``). A spec's ``speech:`` track becomes
these curves in its activation table (facesim.animation.spec), and the waveform the
sound of its video.
"""

from __future__ import annotations

import numpy as np

from .coarticulation import control_curves, segments
from .espeak import RATE, RATES, Phone, Utterance, synthesize
from .recording import recorded

__all__ = ["RATE", "RATES", "Phone", "Utterance", "placed_audio", "recorded", "speech_curves", "synthesize"]


def speech_curves(utterance: Utterance, times: np.ndarray, where: str = "speech") -> dict[str, np.ndarray]:
    """Each control's curve at ``times`` (s, from the utterance's start)."""
    return control_curves(segments(utterance.phones, where), times)


def placed_audio(utterance: Utterance, start: float, seconds: float) -> np.ndarray:
    """The utterance's waveform starting ``start`` s into a clip of ``seconds``: silence
    before it, cut or padded with silence to the clip's length."""
    total = int(round(seconds * utterance.rate))
    audio = np.zeros(total, dtype=np.float32)
    first = int(round(start * utterance.rate))
    part = utterance.samples[:max(total - first, 0)]
    audio[first:first + len(part)] = part
    return audio
