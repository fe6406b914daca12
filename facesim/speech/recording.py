"""Speech from a recording: its sound read by ffmpeg (imageio-ffmpeg's: any format and
rate, any number of channels, mixed to mono and resampled), its phonemes found by
forced alignment against the words said, with PocketSphinx and the US English acoustic
model and CMU pronouncing dictionary that ship in its wheel (nothing downloaded).

Alignment runs PocketSphinx's two passes: the words through the recording (a grammar of
the transcript), then each word's phones and their frames (10 ms) in it; best-path
rescoring is off, which otherwise gave phones a frame long that the second pass could
not place. A phone's frames are placed at their windows' middles. The phones come in CMU's ARPAbet and are named in IPA (``ARPABET``), the
names the viseme table knows; a silence between words is a pause.
"""

from __future__ import annotations

import os
import re
import subprocess
from functools import lru_cache
from pathlib import Path

import numpy as np

from ..errors import InputError
from .espeak import Phone, Utterance

#: The aligner's rate (Hz) and the rate the sound is read at and kept for the video (the
#: aligner's resampled from it: one reading of the file).
ALIGN_RATE, PLAYBACK_RATE = 16000, 44100
#: A recording longer than this (s) is refused unless asked for (``long``): a typo'd path
#: to an audiobook would otherwise align for minutes.
LONG_RECORDING = 120.0
#: Where a frame of PocketSphinx's features lies in time: frame k is the window of
#: 25.625 ms (its ``wlen``) from k times 10 ms, so it stands for its middle.
FRAME, WINDOW_MIDDLE = 0.01, 0.025625 / 2
#: CMU's ARPAbet (the dictionary's phone set) in IPA; stress digits are not in the model.
ARPABET = {
    "AA": "ɑ", "AE": "æ", "AH": "ʌ", "AO": "ɔ", "AW": "aʊ", "AY": "aɪ", "B": "b", "CH": "tʃ", "D": "d", "DH": "ð",
    "EH": "ɛ", "ER": "ɝ", "EY": "eɪ", "F": "f", "G": "ɡ", "HH": "h", "IH": "ɪ", "IY": "i", "JH": "dʒ", "K": "k",
    "L": "l", "M": "m", "N": "n", "NG": "ŋ", "OW": "oʊ", "OY": "ɔɪ", "P": "p", "R": "ɹ", "S": "s", "SH": "ʃ",
    "T": "t", "TH": "θ", "UH": "ʊ", "UW": "u", "V": "v", "W": "w", "Y": "j", "Z": "z", "ZH": "ʒ", "SIL": "",
}


def read_audio(path: Path, rate: int, where: str) -> np.ndarray:
    """The sound of ``path`` as mono float32 at ``rate`` Hz; InputError naming ``where``
    for a file ffmpeg cannot read or one with no sound."""
    import imageio_ffmpeg

    if not path.is_file():
        raise InputError(f"{where}: {path}: file not found")
    result = subprocess.run([imageio_ffmpeg.get_ffmpeg_exe(), "-v", "error", "-nostdin", "-i", str(path), "-vn", "-f",
                             "s16le", "-ac", "1", "-ar", str(rate), "-"], capture_output=True, timeout=600)
    if result.returncode != 0:
        reason = result.stderr.decode(errors="replace").strip().splitlines()
        raise InputError(f"{where}: {path}: not a recording ffmpeg can read ({reason[-1] if reason else 'no stream'})")
    samples = np.frombuffer(result.stdout, dtype="<i2").astype(np.float32) / 32768.0
    if len(samples) == 0:
        raise InputError(f"{where}: {path}: holds no sound")
    if np.abs(samples).max() < 1e-3:
        raise InputError(f"{where}: {path}: is silent")
    return samples


def words_of(text: str) -> list[str]:
    """The transcript as the dictionary spells words: lower case, letters and apostrophes."""
    return re.sub(r"[^a-z' ]+", " ", text.lower().replace("’", "'")).split()


@lru_cache(maxsize=1)
def _dictionary() -> set[str]:
    from pocketsphinx import get_model_path

    with open(os.path.join(get_model_path(), "en-us", "cmudict-en-us.dict"), encoding="utf-8") as lines:
        return {line.split(" ", 1)[0] for line in lines}


def _decoder():
    from pocketsphinx import Decoder, get_model_path

    model = get_model_path()
    return Decoder(hmm=os.path.join(model, "en-us", "en-us"), dict=os.path.join(model, "en-us", "cmudict-en-us.dict"),
                   lm=None, loglevel="FATAL", bestpath=False, beam=1e-100, wbeam=1e-80, pbeam=1e-100)


def align(samples: np.ndarray, text: str, where: str) -> tuple[Phone, ...]:
    """The phonemes of ``text`` in ``samples`` (mono, ``ALIGN_RATE``), with their times;
    InputError naming a word the dictionary lacks, or where the alignment stopped."""
    words = words_of(text)
    if not words:
        raise InputError(f"{where} -> text: {text[:40]!r} has no words to align")
    unknown = [w for w in words if w not in _dictionary()]
    if unknown:
        raise InputError(f"{where} -> text: {', '.join(sorted(set(unknown)))}: not in the aligner's English "
                         "dictionary (CMU's); spell numbers and names as they are said")
    pcm = (np.clip(samples, -1.0, 1.0) * 32767).astype("<i2").tobytes()
    decoder = _decoder()
    decoder.set_align_text(" ".join(words))
    decoder.start_utt()
    decoder.process_raw(pcm, full_utt=True)
    decoder.end_utt()
    found = [s.word for s in decoder.seg()] if decoder.hyp() is not None else []
    said = [w.split("(")[0] for w in found if not w.startswith(("<", "["))]
    if not said:
        raise InputError(f"{where}: the transcript does not align with the recording: no way through its "
                         f"{len(words)} words fits its {len(samples) / ALIGN_RATE:.1f} s of sound (a word missing, "
                         "or one too many?)")
    if said != words:
        reached = next(k for k, (w, v) in enumerate(zip(words + [""], said + [""])) if w != v)
        raise InputError(f"{where}: the transcript does not align with the recording: it stops after "
                         f"{' '.join(words[max(0, reached - 3):reached])!r} ({reached} of {len(words)} words)")
    try:
        decoder.set_alignment()
        decoder.start_utt()
        decoder.process_raw(pcm, full_utt=True)
        decoder.end_utt()
    except RuntimeError:
        raise InputError(f"{where}: the transcript's phones do not align with the recording") from None
    phones = []
    for phone in decoder.get_alignment().phones():
        start = phone.start * FRAME + WINDOW_MIDDLE
        end = (phone.start + phone.duration) * FRAME + WINDOW_MIDDLE
        phones.append(Phone(ARPABET.get(phone.name.rstrip("012"), phone.name), start, end))
    return tuple(phones)


@lru_cache(maxsize=4)
def _recorded(path: str, text: str, stamp: int, long: bool, where: str) -> Utterance:
    from scipy.signal import resample_poly

    sound = read_audio(Path(path), PLAYBACK_RATE, where)
    seconds = len(sound) / PLAYBACK_RATE
    if seconds > LONG_RECORDING and not long:
        raise InputError(f"{where}: {path} lasts {seconds:.0f} s; expected at most {LONG_RECORDING:.0f} s "
                         "(--force-long, or long: true in a spec, for a longer one)")
    phones = align(resample_poly(sound, ALIGN_RATE, PLAYBACK_RATE).astype(np.float32), text, where)
    sound.flags.writeable = False
    return Utterance(sound, PLAYBACK_RATE, phones, text)


def recorded(path: Path, text: str, long: bool = False, where: str = "speech") -> Utterance:
    """A recording of ``text``: its sound (mono, ``PLAYBACK_RATE``) and its phonemes,
    aligned. InputError (naming ``where``) for a file that is missing, unreadable, empty
    or silent, longer than ``LONG_RECORDING`` unless ``long``, a word the dictionary
    lacks, or a transcript that does not align (where it stopped)."""
    stamp = path.stat().st_mtime_ns if path.is_file() else 0
    return _recorded(str(path), text, stamp, long, where)
