"""Speech synthesised offline by eSpeak NG (Debian's ``libespeak-ng1``), through its C
library's API (``speak_lib.h``), loaded with ctypes: the waveform, and the phonemes
with the sample each starts at, from the library's phoneme events
(``espeakINITIALIZE_PHONEME_EVENTS``, in IPA with ``espeakINITIALIZE_PHONEME_IPA``).

A phoneme event marks where a phoneme's sound starts in the output; it ends where the
next one starts. eSpeak's pauses (between phrases, at the end) are events with an empty
name and become silences, one for each run of them (a comma gives two). Stress marks are dropped (what the face shows of stress is in
the timing and the jaw's opening, not in the symbol).

The library keeps one synthesiser per process, and what one text leaves in it changes
how the next is said: the same sentence said twice in one process came out up to 12 ms
apart in its phonemes' times (its length by 250 samples), and neither seeding the C
library's ``rand()``, ``espeak_Cancel`` nor an end pause kept it the same; starting it
again after ``espeak_Terminate`` hangs. So each text is said by a process of its own
(``python -m facesim.speech.espeak``, 0.2-0.3 s), as eSpeak NG's own command does it:
the same text, voice and rate give the same samples and times, whatever was said before.
"""

from __future__ import annotations

import ctypes
import ctypes.util
import io
import os
import subprocess
import sys
from dataclasses import dataclass
from functools import lru_cache

import numpy as np

from ..errors import InputError

#: speak_lib.h: espeak_AUDIO_OUTPUT, espeak_EVENT_TYPE, the options of espeak_Initialize,
#: espeak_POSITION_TYPE, the flags of espeak_Synth and espeak_PARAMETER.
AUDIO_OUTPUT_SYNCHRONOUS = 2
EVENT_LIST_TERMINATED, EVENT_WORD, EVENT_PHONEME = 0, 1, 7
INITIALIZE_PHONEME_EVENTS, INITIALIZE_PHONEME_IPA = 0x0001, 0x0002
POS_CHARACTER = 1
CHARS_UTF8 = 1
PARAMETER_RATE = 1
#: eSpeak's speaking rate, words per minute: its default, and the range it accepts.
RATE, RATES = 175, (80, 450)
#: The longest text ``synthesize`` takes (characters): a paragraph, not a book.
MAX_TEXT = 5000
#: Stress and syllable marks eSpeak's IPA carries on a phoneme's name.
_MARKS = str.maketrans("", "", "ˈˌ.")


class _Id(ctypes.Union):
    _fields_ = [("number", ctypes.c_int), ("name", ctypes.c_char_p), ("string", ctypes.c_char * 8)]


class _Event(ctypes.Structure):
    """speak_lib.h's espeak_EVENT."""

    _fields_ = [("type", ctypes.c_int), ("unique_identifier", ctypes.c_uint), ("text_position", ctypes.c_int),
                ("length", ctypes.c_int), ("audio_position", ctypes.c_int), ("sample", ctypes.c_int),
                ("user_data", ctypes.c_void_p), ("id", _Id)]


class _Voice(ctypes.Structure):
    """speak_lib.h's espeak_VOICE."""

    _fields_ = [("name", ctypes.c_char_p), ("languages", ctypes.c_void_p), ("identifier", ctypes.c_char_p),
                ("gender", ctypes.c_ubyte), ("age", ctypes.c_ubyte), ("variant", ctypes.c_ubyte), ("xx1", ctypes.c_ubyte),
                ("score", ctypes.c_int), ("spare", ctypes.c_void_p)]


_CALLBACK = ctypes.CFUNCTYPE(ctypes.c_int, ctypes.POINTER(ctypes.c_short), ctypes.c_int, ctypes.POINTER(_Event))


@dataclass(frozen=True)
class Phone:
    """One phoneme: its IPA symbol ('' for a pause), start and end (s)."""

    symbol: str
    start: float
    end: float


@dataclass(frozen=True)
class Utterance:
    """What was said: the waveform (float32, mono, -1..1) at ``rate`` Hz, its phonemes
    in order, covering it from the first phoneme's start to the end, and the text."""

    samples: np.ndarray
    rate: int
    phones: tuple[Phone, ...]
    text: str

    @property
    def duration(self) -> float:
        return len(self.samples) / self.rate


class _Library:
    """libespeak-ng, initialised once for synchronous output with phoneme events."""

    def __init__(self):
        name = ctypes.util.find_library("espeak-ng")
        if name is None:
            raise InputError("speech needs eSpeak NG's library, which is not installed: "
                             "sudo apt-get install libespeak-ng1 (Debian; `make setup` does it)")
        self.lib = lib = ctypes.CDLL(name)
        lib.espeak_Initialize.argtypes = [ctypes.c_int, ctypes.c_int, ctypes.c_char_p, ctypes.c_int]
        lib.espeak_SetVoiceByName.argtypes = [ctypes.c_char_p]
        lib.espeak_ListVoices.argtypes = [ctypes.c_void_p]
        lib.espeak_ListVoices.restype = ctypes.POINTER(ctypes.POINTER(_Voice))
        lib.espeak_SetParameter.argtypes = [ctypes.c_int, ctypes.c_int, ctypes.c_int]
        lib.espeak_Synth.argtypes = [ctypes.c_char_p, ctypes.c_size_t, ctypes.c_uint, ctypes.c_int, ctypes.c_uint,
                                     ctypes.c_uint, ctypes.c_void_p, ctypes.c_void_p]
        self.rate = lib.espeak_Initialize(AUDIO_OUTPUT_SYNCHRONOUS, 0, None,
                                          INITIALIZE_PHONEME_EVENTS | INITIALIZE_PHONEME_IPA)
        if self.rate <= 0:
            raise InputError("eSpeak NG's library did not start (its data, espeak-ng-data, may be missing)")
        self.chunks: list[np.ndarray] = []
        self.events: list[tuple[int, str]] = []
        self.callback = _CALLBACK(self._collect)  # kept: the library holds a pointer to it
        lib.espeak_SetSynthCallback(self.callback)

    @property
    def voices(self) -> dict[str, str]:
        """Every name a voice answers to, lower case, and the voice's file (its
        identifier, ``gmw/en-US``): its name and its file, or else a language it speaks
        (``languages``: a priority byte then a name, to an empty name), the first voice
        listed for each."""
        named, spoken, listed, k = {}, {}, self.lib.espeak_ListVoices(None), 0
        while listed[k]:
            voice = listed[k].contents
            identifier = voice.identifier.decode()
            for alias in (voice.name.decode(), identifier, identifier.rsplit("/", 1)[-1]):
                named.setdefault(alias.lower(), identifier)
            at = voice.languages
            while ctypes.c_ubyte.from_address(at).value:
                language = ctypes.string_at(at + 1)
                spoken.setdefault(language.decode().lower(), identifier)
                at += len(language) + 2
            k += 1
        names = {**spoken, **named}
        return names

    def _collect(self, wav, count, events) -> int:
        if count > 0:
            self.chunks.append(np.ctypeslib.as_array(wav, (count,)).copy())
        k = 0
        while events[k].type != EVENT_LIST_TERMINATED:
            event = events[k]
            if event.type == EVENT_PHONEME:
                self.events.append((event.sample, event.id.string.decode("utf-8", "replace")))
            k += 1
        return 0

    def synthesize(self, text: str, voice: str, rate: int) -> tuple[np.ndarray, list[tuple[int, str]]]:
        identifier = self.voices.get(voice.lower())
        if identifier is None or self.lib.espeak_SetVoiceByName(identifier.encode()) != 0:
            raise InputError(f"voice: eSpeak NG has no voice {voice!r} (espeak-ng --voices lists them)")
        self.lib.espeak_SetParameter(PARAMETER_RATE, rate, 0)
        self.chunks, self.events = [], []
        data = text.encode()
        if self.lib.espeak_Synth(data, len(data) + 1, 0, POS_CHARACTER, 0, CHARS_UTF8, None, None) != 0:
            raise InputError(f"text: eSpeak NG could not speak {text[:40]!r}")
        self.lib.espeak_Synchronize()
        samples = np.concatenate(self.chunks) if self.chunks else np.zeros(0, np.int16)
        return samples, self.events


def _said(text: str, voice: str, rate: int) -> tuple[np.ndarray, list[tuple[int, str]], int]:
    """eSpeak NG's samples, phoneme events (sample, name) and rate for ``text``, from a
    process of its own (module docstring); InputError with its one line."""
    package = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
    env = dict(os.environ, PYTHONPATH=os.pathsep.join(filter(None, [package, os.environ.get("PYTHONPATH")])))
    result = subprocess.run([sys.executable, "-m", "facesim.speech.espeak", voice, str(rate)], input=text.encode(),
                            capture_output=True, env=env, timeout=600)
    if result.returncode != 0:
        lines = result.stderr.decode(errors="replace").strip().splitlines()
        raise InputError(lines[-1] if lines else f"eSpeak NG failed (exit code {result.returncode})")
    said = np.load(io.BytesIO(result.stdout))
    return said["samples"], list(zip(said["at"].tolist(), said["names"].tolist())), int(said["rate"])


def check_text(text: str, where: str) -> str:
    """``text`` stripped, or an InputError naming ``where``: empty, too long, or nothing
    a voice says."""
    text = text.strip()
    if not text:
        raise InputError(f"{where}: empty text; expected words to say")
    if len(text) > MAX_TEXT:
        raise InputError(f"{where}: {len(text):,} characters; expected at most {MAX_TEXT:,} (split it into specs)")
    if not any(c.isalnum() for c in text):
        raise InputError(f"{where}: {text[:40]!r} has no words to say")
    return text


@lru_cache(maxsize=16)
def synthesize(text: str, voice: str = "en", rate: int = RATE, where: str = "speech") -> Utterance:
    """``text`` said by eSpeak NG's ``voice`` at ``rate`` words a minute: its waveform and
    timed phonemes. InputError (naming ``where``) for a text or voice it cannot say."""
    text = check_text(text, f"{where} -> text")
    if not RATES[0] <= rate <= RATES[1]:
        raise InputError(f"{where} -> rate: {rate}; expected {RATES[0]}-{RATES[1]} words a minute")
    try:
        samples, events, fs = _said(text, voice, rate)
    except InputError as exc:
        raise InputError(f"{where} -> {exc}") from None
    if len(samples) == 0 or not any(name for _, name in events):
        raise InputError(f"{where} -> text: eSpeak NG said nothing for {text[:40]!r}")
    starts = [sample / fs for sample, _ in events] + [len(samples) / fs]
    phones: list[Phone] = []
    for k, (_, name) in enumerate(events):
        symbol = name.translate(_MARKS)
        if starts[k + 1] <= starts[k]:
            continue
        if phones and not symbol and not phones[-1].symbol:  # eSpeak ends a phrase with two pauses: one silence
            phones[-1] = Phone("", phones[-1].start, starts[k + 1])
        else:
            phones.append(Phone(symbol, starts[k], starts[k + 1]))
    audio = (samples.astype(np.float32) / 32768.0)
    audio.flags.writeable = False
    return Utterance(audio, fs, tuple(phones), text)


def _main() -> int:
    """``python -m facesim.speech.espeak VOICE RATE`` < text: the samples, the phoneme
    events and the rate as an NPZ on standard output; an InputError's line on standard
    error and exit code 2."""
    try:
        library = _Library()
        samples, events = library.synthesize(sys.stdin.read(), sys.argv[1], int(sys.argv[2]))
    except InputError as exc:
        print(exc, file=sys.stderr)
        return 2
    out = io.BytesIO()
    np.savez(out, samples=samples, at=np.array([a for a, _ in events], dtype=np.int64),
             names=np.array([n for _, n in events], dtype=str), rate=np.array(library.rate))
    sys.stdout.buffer.write(out.getvalue())
    return 0


if __name__ == "__main__":
    sys.exit(_main())
