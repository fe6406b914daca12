"""Expression specs: which muscles contract, how strongly, over how many frames, at what
time step. A spec is a YAML file validated by pydantic (unknown fields are errors):

    name: happy                 # optional; the file name by default
    frames: 35                  # frames of animation, one per Δt (thesis Table 3.1)
    dt: 0.01                    # Δt per frame, seconds
    onset: 10                   # frames over which activations ease in (Parke's cosine)
    activations:                # muscle: activation in [0, 1]; a paired muscle's name without _l/_r drives both
      zygomaticus_major_l: 1.0
    aus: {AU12: D}              # FACS action units (facesim.animation.timeline), AU12_L one side
    arkit: {mouthSmileLeft: 0.7}   # ARKit's 52 blendshapes, ICT's spellings too (facesim.animation.arkit)
    expressions: {joy: 0.5}     # MPEG-4 expressions by name
    timeline: [...]             # key-framed tracks of muscles, AUs, ARKit shapes, expressions, jaw, eyelids
    pose: [...]                 # key-framed head yaw/pitch/roll and gaze yaw/pitch (degrees)
    include: [{spec: happy, weight: 0.6}]   # blends of other specs
    sequence: [...]             # expressions one after another
    material: {damping: 40}     # optional overrides of the material (facesim.face.material); {preset: thesis}: the thesis's model
    mesh: my_face.obj           # optional, relative to the spec (default: ICT's head, meshes/ict/head.npz)
    identity: 3                 # the head's identity: a seed, or weights of its 100 modes
    muscles: my_face.muscles.yaml
    face: me/                   # a face directory (facesim face from-photo): its identity, muscles, texture
    speech: {text: "Hello there", voice: en, rate: 175, start: 0.2}   # words said (facesim.speech)
    fap: {open_jaw: 300, 12: [[0, 0], [20, 200]]}   # MPEG-4 FAPs in FAP units (facesim.animation.mpeg4), or a FAP file

``load_spec`` checks the file alone; ``activation_table`` checks the muscle names against
the muscle file and turns the spec into a (frames, muscles) table once, before simulation.
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import Annotated, Literal

import numpy as np
from pydantic import Field, PrivateAttr, ValidationError, ValidationInfo, field_validator, model_validator

from ..config import DEFAULT_MESH, DEFAULT_MUSCLES, LIBRARY, MUSCLE_PRESETS
from ..errors import InputError
from ..face.head import IDENTITY_MODES, identity_problem
from ..face.material import MaterialSpec
from ..physics.muscles import TONGUE, MuscleSet
from ..schema import Strict, load_model
from ..speech import RATE, RATES, Utterance, recorded, speech_curves, synthesize
from .arkit import is_shape_name, shape_facs
from .mpeg4 import FILE_VALUES, FapDrive, fap_drive, fap_number, read_fap_file
from .timeline import (
    AU_NAME,
    INTERPOLATIONS,
    MPEG4_FAPS,
    apply_cooccurrence,
    au_muscles,
    envelope_keys,
    interpolate,
    parse_intensity,
)

Activation = Annotated[float, Field(ge=0.0, le=1.0)]
#: More frames than this is taken for a typo: 100k frames is over an hour at 25 fps.
MAX_FRAMES = 100_000
#: MPEG-4's six high-level expressions (with FACS/Ekman names as aliases) and their specs.
EKMAN = {"joy": "happy", "happy": "happy", "sadness": "sad", "sad": "sad", "anger": "angry", "angry": "angry",
         "fear": "fear", "disgust": "disgust", "surprise": "surprise"}


class Envelope(Strict):
    """The common onset / apex / offset shape of an expression or action."""

    start: float = Field(0.0, ge=0)
    onset: float = Field(..., ge=0)
    apex: float = Field(..., ge=0)
    offset: float = Field(0.0, ge=0)
    intensity: Activation = 1.0


class _Curve(Strict):
    """What every key-framed curve has: its time unit and interpolation."""

    unit: Literal["frame", "second"] = "frame"
    interpolation: Literal[INTERPOLATIONS] = "hold"  # type: ignore[valid-type]
    tension: float = Field(0.0, ge=0.0, le=1.0)

    @field_validator("keys", check_fields=False)
    @classmethod
    def _increasing(cls, keys):
        if keys is not None:
            if not keys:
                raise ValueError("at least one key-frame")
            times = [k[0] for k in keys]
            if any(b <= a for a, b in zip(times, times[1:])):
                raise ValueError(f"out of order, times must increase strictly, got {times}")
        return keys

    def curve(self, keys, dt: float, frames: int) -> np.ndarray:
        """The curve through ``keys`` (time, value) at every frame."""
        times, values = (np.array(v, dtype=float) for v in zip(*keys))
        times = times / dt if self.unit == "second" else times
        return interpolate(times, values, np.arange(frames, dtype=float), self.interpolation, self.tension)


class Track(_Curve):
    """A key-framed curve for one muscle (``zygomaticus_major_l``), one action unit
    (``AU12``), one named expression (``happy``, a spec in expressions/, or a path), or a
    control of the jaw and eyelids (``jaw``, ``eyelid_l``)."""

    target: str = Field(..., min_length=1)
    keys: list[tuple[float, Activation]] | None = None
    envelope: Envelope | None = None

    @model_validator(mode="after")
    def _keys_or_envelope(self):
        if (self.keys is None) == (self.envelope is None):
            raise ValueError("give either keys or an envelope")
        return self

    def values(self, dt: float, frames: int) -> np.ndarray:
        if self.envelope is not None:
            e = self.envelope
            return self.curve(envelope_keys(e.start, e.onset, e.apex, e.offset, e.intensity), dt, frames)
        return self.curve(self.keys, dt, frames)


#: Head and eye angles a pose track can drive, in degrees: head yaw turns the face toward
#: the subject's left (+x), pitch lifts the chin, roll tilts the head toward the subject's
#: left shoulder; gaze yaw turns the eyes toward the subject's left, gaze pitch up.
POSE = ("head_yaw", "head_pitch", "head_roll", "gaze_yaw", "gaze_pitch")
Angle = Annotated[float, Field(ge=-90.0, le=90.0)]


class PoseTrack(_Curve):
    """A key-framed head or eye angle (degrees), applied at render time."""

    target: Literal[POSE]  # type: ignore[valid-type]
    keys: list[tuple[float, Angle]]

    def values(self, dt: float, frames: int) -> np.ndarray:
        return self.curve(self.keys, dt, frames)


class Speech(Strict):
    """Words said (facesim.speech): eSpeak NG's ``voice`` says ``text`` at ``rate`` words
    a minute, or a recording (``audio``, relative to the spec) of ``text`` is aligned to
    its words, from ``start`` (s); the phonemes become visemes and the visemes the jaw's,
    the lips' and the tongue's controls, on top of everything else the spec does. A spec
    that speaks plays in real time: a frame is 1/fps s (its dt), and its frames cover the
    words unless it gives them. ``long``: a recording over two minutes is wanted."""

    text: str = Field(..., min_length=1)
    voice: str = Field("en", min_length=1)
    rate: int = Field(RATE, ge=RATES[0], le=RATES[1], description="words a minute")
    start: float = Field(0.0, ge=0, description="seconds")
    audio: Path | None = Field(None, description="a recording of the text (any format ffmpeg reads)")
    long: bool = False

    @model_validator(mode="after")
    def _sayable(self, info: ValidationInfo):
        if self.audio is not None and {"voice", "rate"} & self.model_fields_set:
            raise ValueError("voice and rate are eSpeak NG's; a recording (audio) is said as it was recorded")
        directory = (info.context or {}).get("directory")
        if self.audio is not None and not self.audio.is_absolute() and directory is not None:
            object.__setattr__(self, "audio", Path(directory) / self.audio)
        try:
            self.utterance
        except InputError as exc:
            raise ValueError(str(exc)) from None
        return self

    @property
    def utterance(self) -> Utterance:
        if self.audio is not None:
            return recorded(self.audio, self.text, self.long)
        return synthesize(self.text, self.voice, self.rate)


#: Frames a speaking spec runs on after its last word (s), for the face to come to rest.
SPEECH_TAIL = 0.4


class Include(Strict):
    """Another spec blended in with a weight."""

    spec: str = Field(..., min_length=1)
    weight: float = Field(1.0, ge=0.0, le=1.0)


class Segment(Strict):
    """One expression of a sequence, held for ``frames``, reached over ``transition``."""

    expression: str = Field(..., min_length=1)
    frames: int = Field(..., ge=1)
    transition: int = Field(0, ge=0)
    intensity: Activation = 1.0

    @model_validator(mode="after")
    def _transition_fits(self):
        if self.transition > self.frames:
            raise ValueError(f"transition ({self.transition}) longer than the segment ({self.frames} frames)")
        return self


class Spec(Strict):
    name: str | None = Field(None, min_length=1)
    description: str = ""
    frames: int = Field(35, ge=1, le=MAX_FRAMES)
    dt: float = Field(0.01, gt=0, le=1.0)
    onset: int = Field(10, ge=0, description="frames to ease constant activations in; 0 for a step")
    fps: float = Field(25.0, gt=0, le=240, description="playback rate of the rendered video")
    activations: dict[str, Activation] = Field(default_factory=dict)
    aus: dict[str, float | str] = Field(default_factory=dict, description="FACS action units: A-E or 0-1")
    arkit: dict[str, Activation] = Field(default_factory=dict, description="ARKit's blendshapes (ICT's spellings too): 0-1")
    expressions: dict[str, Activation] = Field(default_factory=dict, description="MPEG-4 expressions by name")
    timeline: list[Track] = Field(default_factory=list)
    pose: list[PoseTrack] = Field(default_factory=list, description="head and gaze angles over time")
    include: list[Include] = Field(default_factory=list)
    sequence: list[Segment] = Field(default_factory=list)
    material: MaterialSpec = MaterialSpec()
    mesh: Path | None = None
    muscles: Path | None = None
    identity: int | list[float] | None = Field(None, description=(
        "a head's identity (facesim.face.head): a seed for weights from the standard normal distribution, or the weights"))
    face: Path | None = Field(None, description="a face directory written by `facesim face from-photo`")
    speech: Speech | None = Field(None, description="words said: text, voice, rate, start (s)")
    fap: dict[int, float | list] | Path | None = Field(None, description=(
        "MPEG-4 FAPs by number or name: a value in FAP units, [[frame, value], ...] keys, or an ASCII FAP file"))
    _source: Path | None = PrivateAttr(None)
    _given: frozenset = PrivateAttr(frozenset())  # fields the command line set (with_overrides)
    _fap_stream: tuple | None = PrivateAttr(None)

    @field_validator("fap", mode="before")
    @classmethod
    def _faps(cls, fap, info: ValidationInfo):
        if fap is None:
            return None
        if isinstance(fap, (str, Path)):
            directory = (info.context or {}).get("directory")
            path = Path(fap)
            return directory / path if directory is not None and not path.is_absolute() else path
        if not isinstance(fap, dict):
            raise ValueError("expected FAPs by number or name, or the path of a FAP file")
        out = {}
        for key, value in fap.items():
            number = fap_number(key)
            out[number] = _fap_value(number, value)
        return out

    @field_validator("identity", mode="before")
    @classmethod
    def _person(cls, identity):
        if isinstance(identity, list):
            if len(identity) > IDENTITY_MODES:
                raise ValueError(f"expected a seed or at most {IDENTITY_MODES} weights, got {len(identity)}")
            for k, w in enumerate(identity):
                if isinstance(w, bool) or not isinstance(w, (int, float)) or not math.isfinite(w):
                    raise ValueError(f"weight {k} is {w!r}: expected a seed or a list of finite numbers")
            problem = identity_problem(np.asarray(identity, dtype=np.float64))
            if problem:
                raise ValueError(problem)
        return identity

    @field_validator("aus")
    @classmethod
    def _facs(cls, aus):
        out = {}
        for au, value in aus.items():
            if not AU_NAME.fullmatch(au):
                raise ValueError(f"{au!r} is not an action unit name such as AU12 or AU12_L")
            out[au] = parse_intensity(value)
        return out

    @field_validator("arkit")
    @classmethod
    def _shapes(cls, arkit):
        for name in arkit:
            shape_facs(name)  # a ValueError names an unknown shape
        return arkit

    @field_validator("expressions")
    @classmethod
    def _ekman(cls, expressions):
        for name in expressions:
            if name not in EKMAN:
                raise ValueError(f"{name!r} is not one of the six expressions ({', '.join(sorted(set(EKMAN.values())))})")
        return expressions

    @model_validator(mode="after")
    def _sequence_frames(self):
        if self.sequence:
            total = sum(s.frames for s in self.sequence)
            if "frames" in self.model_fields_set and self.frames != total:
                raise ValueError(f"frames ({self.frames}) differs from the sequence's {total} frames; leave it out")
            object.__setattr__(self, "frames", total)
        return self

    @model_validator(mode="after")
    def _fap_file(self):
        if not isinstance(self.fap, Path):
            return self
        fps, values = read_fap_file(self.fap, f"fap: {self.fap}")
        count = len(next(iter(values.values()))) if values else 1  # a file whose masks set nothing holds no values
        self._fap_stream = (fps, count, values)
        if "fps" not in self.model_fields_set:
            object.__setattr__(self, "fps", fps)
        if "frames" not in self.model_fields_set and not self.sequence:
            object.__setattr__(self, "frames", min(math.ceil(count * self.fps / fps), MAX_FRAMES))
        return self

    @model_validator(mode="after")
    def _real_time(self):
        if self.speech is None and self._fap_stream is None:
            return self
        what = "speech" if self.speech is not None else "a FAP file"
        if "dt" in self.model_fields_set and abs(self.dt * self.fps - 1.0) > 1e-6:
            raise ValueError(f"dt ({self.dt}) and fps ({self.fps}) differ: a spec with {what} plays in real time, "
                             "a frame every 1/fps s; leave dt out")
        object.__setattr__(self, "dt", 1.0 / self.fps)
        if self.speech is not None and "frames" not in self.model_fields_set and not self.sequence:
            end = self.speech.start + self.speech.utterance.duration + SPEECH_TAIL
            object.__setattr__(self, "frames", min(math.ceil(end / self.dt), MAX_FRAMES))
        return self

    def fap_values(self) -> dict[int, np.ndarray]:
        """The spec's FAPs per frame, in FAP units: a FAP file's frames at this spec's
        times (the nearest), inline values eased in over ``onset`` like ``aus``, inline
        keys ([frame, value], as a timeline's) linearly between them."""
        frames = self.frames
        if self._fap_stream is not None:
            fps, count, values = self._fap_stream
            index = np.minimum(np.round(np.arange(frames) * self.dt * fps).astype(int), count - 1)
            return {n: v[index] for n, v in values.items()}
        out = {}
        for number, value in (self.fap or {}).items():
            if number in FILE_VALUES:
                out[number] = np.tile(np.asarray(value + [0.0] * (FILE_VALUES[number] - len(value))), (frames, 1))
            elif isinstance(value, list):
                times, keyed = zip(*value)
                out[number] = interpolate(times, keyed, np.arange(frames, dtype=float))
            else:
                out[number] = _ease(frames, self.onset) * value
        return out

    def fap_drive(self) -> FapDrive:
        return fap_drive(self.fap_values())

    @model_validator(mode="after")
    def _one_head(self):
        if self.face is not None and (self.identity is not None or self.mesh is not None):
            raise ValueError("face: a face directory brings its own head; leave out identity and mesh")
        return self

    @property
    def source(self) -> str:
        return str(self._source) if self._source else "<spec>"

    @property
    def title(self) -> str:
        return self.name or (self._source.stem if self._source else "expression")

    def _relative(self, path: Path | None, default: Path) -> Path:
        if path is None:
            return default
        return path if path.is_absolute() or self._source is None else self._source.parent / path

    @property
    def mesh_path(self) -> Path:
        return self._relative(self.mesh, DEFAULT_MESH)

    @property
    def muscles_path(self) -> Path:
        face = self.face_directory
        if self.muscles is not None and str(self.muscles) in MUSCLE_PRESETS:
            return MUSCLE_PRESETS[str(self.muscles)]
        # the thesis's model on a face of its own scale is its skin and its muscles
        thesis = self.material.preset == "thesis" and self.mesh_path.suffix.lower() != ".npz"
        return self._relative(self.muscles, face.muscles if face else MUSCLE_PRESETS["thesis"] if thesis else DEFAULT_MUSCLES)

    @property
    def face_directory(self):
        """The spec's face directory read back (facesim.face.own_face.FaceDirectory), or None."""
        from ..face.own_face import load_face_directory

        where = "--face" if "face" in self._given else f"{self.source}: face"
        return None if self.face is None else load_face_directory(self._relative(self.face, Path()), where)

    @property
    def head_identity(self):
        """The head's identity: the face directory's weights, or the spec's own."""
        face = self.face_directory
        return face.identity if face else self.identity

    def with_overrides(self, **changes) -> "Spec":
        """A copy with fields replaced (used by the CLI's --mesh, --muscles, --identity,
        --face). A path given here is relative to the working directory, not to the spec;
        a face given here replaces the spec's identity and mesh, an identity or mesh its face."""
        if changes.get("face") is not None and (changes.get("identity") is not None or changes.get("mesh") is not None):
            given = "--identity" if changes.get("identity") is not None else "--mesh"
            raise InputError(f"--face: not with {given}: a face directory brings its own head, identity and muscles")
        for key in ("mesh", "muscles", "face"):
            if changes.get(key) is not None and str(changes[key]) not in MUSCLE_PRESETS:
                changes[key] = Path(changes[key]).resolve()
        update = {k: v for k, v in changes.items() if v is not None}
        if "face" in update:
            update.update(identity=None, mesh=None)
        elif "identity" in update or "mesh" in update:
            update["face"] = None
        spec = self.model_copy(update=update)
        spec._source = self._source
        spec._given = self._given | {k for k, v in changes.items() if v is not None}
        return spec

    def resolve(self, name: str) -> Path | None:
        """An expression named in this spec: a spec file (relative to this one), a spec of
        the library in expressions/ (happy, happy_surprise, ...), an MPEG-4 name (joy, ...),
        or None for ``neutral``."""
        if name == "neutral":
            return None
        here = self._source.parent if self._source else Path.cwd()
        for candidate in (here / name, LIBRARY / f"{EKMAN.get(name, name)}.yaml"):
            if candidate.suffix in (".yaml", ".yml") and candidate.is_file():
                return candidate
        raise InputError(f"{self.source}: {name!r} is neither a muscle, an action unit, nor an expression spec")


def _fap_value(number: int, value):
    """One inline FAP: a value in its units or [[frame, value], ...] keys; FAP 1's
    [viseme_select1, viseme_select2, viseme_blend], FAP 2's [expression_select1,
    expression_intensity1, expression_select2, expression_intensity2] (the rest 0)."""
    def finite(v):
        return not isinstance(v, bool) and isinstance(v, (int, float)) and math.isfinite(v)

    if number in FILE_VALUES:
        size = FILE_VALUES[number] - 1 if number == 1 else FILE_VALUES[number] - 2
        if not (isinstance(value, list) and 1 <= len(value) <= size and all(finite(v) and 0 <= v <= 63 for v in value)):
            what = "viseme_select1, viseme_select2, viseme_blend" if number == 1 else (
                "expression_select1, expression_intensity1, expression_select2, expression_intensity2")
            raise ValueError(f"FAP {number}: expected [{what}], numbers 0-63, got {value!r}")
        return [float(v) for v in value]
    if finite(value):
        return float(value)
    if isinstance(value, list) and value and all(isinstance(k, (list, tuple)) and len(k) == 2 and finite(k[0]) and finite(k[1])
                                                 for k in value):
        times = [float(k[0]) for k in value]
        if any(b <= a for a, b in zip(times, times[1:])) or times[0] < 0:
            raise ValueError(f"FAP {number}: key frames must start at 0 or later and increase, got {times}")
        return [(float(t), float(v)) for t, v in value]
    raise ValueError(f"FAP {number}: expected a value in FAP units or [[frame, value], ...] keys, got {value!r}")


def library_spec(path: str | Path) -> Path:
    """``path`` itself, or, when no such file exists and it is a bare name (``happy``,
    ``surprise.yaml``), that spec of the library shipped with facesim."""
    path = Path(path)
    if not path.exists() and path.parent == Path("."):
        known = LIBRARY / (path.name if path.suffix in (".yaml", ".yml") else f"{EKMAN.get(path.name, path.name)}.yaml")
        if known.is_file():
            return known
    return path


def load_spec(path: str | Path) -> Spec:
    """Read and validate an expression spec (one-line InputError on any problem): a file,
    or a name of the library (``happy``)."""
    path = library_spec(path)
    spec = load_model(path, Spec, context={"directory": path.parent})  # a recording's path is relative to the spec
    spec._source = path
    return spec


def blend_spec(blend: str, frames: int | None = None) -> Spec:
    """A spec from the CLI's ``--blend happy=0.6,surprise=0.4``."""
    includes = []
    for part in blend.split(","):
        name, _, weight = part.partition("=")
        try:
            includes.append(Include(spec=name.strip(), weight=float(weight) if weight else 1.0))
        except (ValueError, ValidationError):
            raise InputError(f"--blend: expected name=weight pairs with weights in [0, 1], got {part!r}") from None
    spec = Spec(name="blend_" + "_".join(i.spec for i in includes), include=includes, **({"frames": frames} if frames else {}))
    for i in includes:
        spec.resolve(i.spec)  # an unknown name fails now, with the option's name
    return spec


def pose_table(spec: Spec) -> np.ndarray:
    """(frames, 5) head and gaze angles in degrees, in the order of ``POSE``; zero where
    no track drives them. Several tracks of one angle add up."""
    table = np.zeros((spec.frames, len(POSE)))
    for track in spec.pose:
        table[:, POSE.index(track.target)] += track.values(spec.dt, spec.frames)
    if spec.fap:
        for angle, curve in spec.fap_drive().pose.items():
            table[:, POSE.index(angle)] += curve
    return table


def _ease(frames: int, onset: int) -> np.ndarray:
    frame = np.arange(1, frames + 1)
    return np.ones(frames) if onset == 0 else 0.5 - 0.5 * np.cos(np.pi * np.minimum(frame / onset, 1.0))


def activation_table(spec: Spec, muscles: MuscleSet, _depth: int = 0) -> np.ndarray:
    """(frames, muscles) activations, in [0, 1]: the sum of

    - ``activations``, eased in over ``onset`` frames with Parke's cosine and held;
    - ``expressions`` (MPEG-4): each named expression's final activations times its
      intensity, eased in the same way;
    - ``aus``: FACS action units through their muscles, eased in the same way, together
      with the action-unit tracks after the co-occurrence rules;
    - ``arkit``: ARKit's (and ICT's) shapes through the FACS form each stands for
      (facesim.animation.arkit), eased in the same way, with their tracks, as weights: no
      co-occurrence rules;
    - ``timeline``: key-framed curves of muscles, action units and expressions;
    - ``include``: other specs' tables (at this spec's frames and Δt) times their weights;
    - ``sequence``: expressions one after another, each reached over its transition;
    - ``speech``: the visemes of the words said, coarticulated (facesim.speech);
    - ``fap``: MPEG-4's FAPs through the controls that show them (facesim.animation.mpeg4).

    The sum is clipped to [0, 1]; below that it is linear in every weight and intensity.
    """
    if _depth > 8:
        raise InputError(f"{spec.source}: include: specs include each other in a cycle")
    names = muscles.names
    frames = spec.frames
    table = np.zeros((frames, len(names)))
    ease = _ease(frames, spec.onset)

    def fail(where: str, message: str):
        raise InputError(f"{spec.source}: {where}: {message}")

    def muscle_vector(name: str, where: str) -> np.ndarray:
        """A muscle's column; a pair's name without its side (``frontalis_galea``, paired on
        the head, one midline muscle on the thesis's face) both of its sides."""
        name = MPEG4_FAPS.get(name, name)
        columns = [names.index(name)] if name in names else both_sides(name)
        if name not in names and len(columns) != 2:
            fail(where, f"{name} moves a head's tongue, and this face has none (a mask: render it on the default head)"
                 if name in TONGUE else "unknown muscle (see `facesim muscles`)")
        v = np.zeros(len(names))
        v[columns] = 1.0
        return v

    def expression_vector(name: str) -> np.ndarray:
        path = spec.resolve(name)
        if path is None:
            return np.zeros(len(names))
        return activation_table(load_spec(path), muscles, _depth + 1)[-1]

    def both_sides(control: str) -> list[int]:
        """The columns of a control and of its two sides (``risorius``: ``_l`` and ``_r``)."""
        return [names.index(n) for n in names if n in (control, f"{control}_l", f"{control}_r")]

    def au_vector(au: str, where: str) -> np.ndarray:
        try:
            weights = au_muscles(au, names)
        except ValueError as exc:
            fail(where, str(exc))
        v = np.zeros(len(names))
        for muscle, weight in weights.items():
            v[names.index(muscle)] = weight
        return v

    for name, value in spec.activations.items():
        table += np.outer(ease * value, muscle_vector(name, f"activations -> {name}"))
    for name, intensity in spec.expressions.items():
        table += np.outer(ease * intensity, expression_vector(name))

    au_curves = {au: ease * value for au, value in spec.aus.items()}
    shape_curves = {name: ease * value for name, value in spec.arkit.items()}
    for k, track in enumerate(spec.timeline):
        curve = track.values(spec.dt, frames)
        where = f"timeline -> {k} -> target"
        if AU_NAME.fullmatch(track.target):
            au_curves[track.target] = au_curves.get(track.target, 0) + curve
        elif is_shape_name(track.target):
            try:
                shape_facs(track.target)
            except ValueError as exc:
                fail(where, str(exc))
            shape_curves[track.target] = shape_curves.get(track.target, 0) + curve
        elif track.target in names or track.target in MPEG4_FAPS:
            table += np.outer(curve, muscle_vector(track.target, where))
        else:
            table += np.outer(curve, expression_vector(track.target))
    for au, curve in apply_cooccurrence({a: np.clip(c, 0, 1) for a, c in au_curves.items()}).items():
        table += np.outer(curve, au_vector(au, f"aus -> {au}"))
    for name, curve in shape_curves.items():
        unit, where = shape_facs(name), f"arkit -> {name}"
        table += np.outer(np.clip(curve, 0, 1), au_vector(unit, where) if AU_NAME.fullmatch(unit) else muscle_vector(unit, where))

    if spec.speech is not None:
        times = np.arange(frames) * spec.dt - spec.speech.start
        for control, curve in speech_curves(spec.speech.utterance, times, f"{spec.source}: speech").items():
            columns = both_sides(control)
            if not columns and control not in TONGUE:  # a mask has no tongue to speak with
                fail("speech", f"the visemes need the {control.replace('_', ' ')}, which this face's muscle file "
                     "does not have")
            table[:, columns] += curve[:, None]

    if spec.fap:
        drive = spec.fap_drive()
        for control, curve in drive.controls.items():
            where = f"fap -> {control}"
            if AU_NAME.fullmatch(control):
                table += np.outer(curve, au_vector(control, where))
                continue
            columns = both_sides(control)
            if not columns:
                muscle_vector(control, where)  # the error: which control this face lacks
            table[:, columns] += curve[:, None]
        for name, curve in drive.expressions.items():
            table += np.outer(curve, expression_vector(name))

    for k, include in enumerate(spec.include):
        path = spec.resolve(include.spec)
        if path is None:
            continue
        included = load_spec(path).with_overrides(frames=frames, dt=spec.dt)
        table += include.weight * activation_table(included, muscles, _depth + 1)

    start, previous = 0, np.zeros(len(names))
    for segment in spec.sequence:
        target = segment.intensity * expression_vector(segment.expression)
        ramp = np.ones(segment.frames)
        if segment.transition:
            step = np.minimum(np.arange(1, segment.frames + 1) / segment.transition, 1.0)
            ramp = (1 - np.cos(np.pi * step)) / 2
        table[start:start + segment.frames] += previous + np.outer(ramp, target - previous)
        start, previous = start + segment.frames, target
    return np.clip(table, 0.0, 1.0)
