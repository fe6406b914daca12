"""Running a spec: model, activation table, the Numba simulation, diagnostics.

``simulate(spec)`` is the one entry point: it builds (and caches) the model of the spec's
mesh, muscles and material, turns the spec into a (frames, muscles) activation table,
runs it (facesim.physics.run) and wraps the result in an :class:`Animation`. A simulation
that blows up raises :class:`SimulationError` naming the frame and the vertex or triangle.

``simulate(spec, background=True)`` returns the Animation at once and simulates on a
thread of its own (the kernels release the GIL), frame by frame into its arrays, so
that ``facesim render`` draws and encodes the first frames while the later ones are
simulated (a face simulated on one thread; a larger mesh's simulation, which wants
every core, runs first: ``simulate``); ``Animation.ready(f)`` waits for frame f, and raises the simulation's error
for a frame it did not reach.
"""

from __future__ import annotations

import threading
import time
from dataclasses import dataclass, field

import numpy as np

from ..errors import SimulationError
from ..face.figure import figure_for
from ..face.head import identity_notice
from ..face.loading import load_face_model
from ..geometry import rotation
from ..physics.model import Model
from ..physics.muscles import GAZE_ANGLE, PUPIL, TONGUE
from ..physics.run import Progress, diagnostics, muscle_forces, run
from ..physics.twins import on_threads
from ..speech import placed_audio
from ..timings import phase
from .spec import Spec, activation_table, pose_table

#: A run expected to take longer than this (s) is announced before it starts.
LONG_RUN = 120.0
#: A clip this long or longer is timed on its first ``MEASURED_FRAMES`` frames, on the face
#: at hand, before it starts (``expected_seconds``). A rate assumed for every face (2
#: million vertex-steps a second) predicted 23 s for 100,000 frames of the head, whose
#: implicit steps then took 156 s.
LONG_CLIP, MEASURED_FRAMES = 2000, 32
#: The frames of positions a streamed run keeps (``simulate(stream=True)``): the renderer
#: holds two in flight, and the simulation runs a few ahead of it.
STREAMED_RING = 8
#: A run that keeps its whole clip (an NPZ, --show-muscles, --jobs) says up front when its
#: positions take more memory than this (bytes).
LARGE_CLIP = 1 << 30
#: A run in which muscles are activated but no vertex moves further than this (cm) from
#: rest has failed, whatever its numbers say: a muscle of 1e150 once overflowed into a
#: face that moved 0.0 cm in every frame, and the video was written. The weakest
#: activation of the library moves the face by tenths of a millimetre.
STILL = 1e-4


@dataclass(frozen=True)
class Animation:
    """The result of a simulation.

    positions : (frames, n, 3) cm; rest : (n, 3); faces : (t, 3);
    activations : (frames, M + controls); pose : (frames, 5) head and gaze angles in
    degrees (facesim.animation.spec.POSE), applied at render time; kinetic_energy, smallest_area :
    (frames,) float; inverted : (frames,) int (triangles turned over and folded against
    the skin around them, ``checks._triangle_checks``); face : the face directory
    (facesim.face.own_face.FaceDirectory) whose head this is, if any: its texture and camera;
    progress : set while it is simulated in the background (``ready``); muscle_force :
    (frames, n, 3) the muscles' forces on each frame (eq. 3.1-3.25), when simulated
    ``with_muscle_forces``; audio : the sound of the clip (float32, mono, -1..1, at
    ``audio_rate`` Hz, as long as the frames) when its spec speaks.
    """

    name: str
    positions: np.ndarray
    rest: np.ndarray
    faces: np.ndarray
    activations: np.ndarray
    muscle_names: tuple[str, ...]
    dt: float
    fps: float
    kinetic_energy: np.ndarray
    inverted: np.ndarray
    smallest_area: np.ndarray
    seconds: float = 0.0
    model: Model | None = field(default=None, repr=False, compare=False)
    pose: np.ndarray | None = None
    face: object = None
    progress: Progress | None = field(default=None, repr=False, compare=False)
    muscle_force: np.ndarray | None = field(default=None, repr=False, compare=False)
    audio: np.ndarray | None = field(default=None, repr=False, compare=False)
    audio_rate: int = 0

    def ready(self, frame: int | None = None) -> "Animation":
        """Wait until ``frame`` (by default the last) is simulated, when the animation is
        simulated in the background; raises the simulation's error (SimulationError) for
        a frame it did not reach."""
        if self.progress is not None:
            self.progress.wait(self.frames - 1 if frame is None else frame)
        return self

    def cancel(self) -> None:
        """Stop a background simulation after the frame it is on (a failed render)."""
        if self.progress is not None:
            self.progress.cancel()

    def positions_at(self, frame: int) -> np.ndarray:
        """(n, 3) the skin at ``frame`` (ready, and not yet released, when streamed)."""
        return self.positions[frame % len(self.positions)]

    def release(self, frame: int) -> None:
        """The caller is done with frames up to ``frame``: a streamed run may reuse their room."""
        if self.progress is not None:
            self.progress.release(frame)

    @property
    def streamed(self) -> bool:
        """Whether ``positions`` holds a few frames in turn rather than the whole clip."""
        return len(self.positions) < self.frames

    @property
    def simulation_seconds(self) -> float:
        """Seconds spent simulating (so far, in the background)."""
        return self.seconds if self.progress is None else self.progress.seconds

    def pose_at(self, frame: int) -> np.ndarray | None:
        return None if self.pose is None else self.pose[frame]

    def jaw_at(self, frame: int) -> np.ndarray:
        """The jaw at a frame: (4,) its angle (radians) and its glide (cm), as ``jaw``."""
        return self.jaw[frame]

    @property
    def jaw(self) -> np.ndarray:
        """(frames, 4) the jaw's angle (radians: its activation times its largest angle) and
        its glide (cm, (3,): the glide controls' activations times their glides)."""
        rig = None if self.model is None else self.model.rig
        if rig is None or rig.jaw_column < 0:
            return np.zeros((self.frames, 4))
        return np.column_stack([self.activations[:, rig.jaw_column] * rig.jaw_max,
                                self.activations[:, rig.jaw_glide_column] @ rig.jaw_glide])

    @property
    def figure(self):
        """The head this animation's face drives (facesim.face.figure), or None for a mask."""
        return None if self.model is None else figure_for(self.model)

    def head_at(self, frame: int) -> np.ndarray:
        """(N, 3) every vertex of the head at a frame, in ICT FaceKit's order, as the renderer
        draws it: the figure for the simulated skin, jaw, gaze and each eye's look
        (facesim.face.figure), turned by the head's pose about the neck."""
        figure = self.figure
        pose = np.zeros(5) if self.pose is None else self.pose[frame]
        x = figure.positions(self.positions[frame], self.jaw_at(frame), (pose[3], pose[4]), pose[5:] if len(pose) > 5 else None)
        head = rotation(pose[0], pose[1], pose[2])
        return (x - figure.neck) @ head.T + figure.neck

    @property
    def frames(self) -> int:
        return len(self.activations)

    @property
    def apex_frame(self) -> int:
        """The last frame at which the total activation is largest."""
        total = self.activations.sum(axis=1)
        return int(len(total) - 1 - np.argmax(total[::-1]))

    @property
    def active_muscles(self) -> tuple[str, ...]:
        return tuple(n for n, a in zip(self.muscle_names, self.activations.max(axis=0)) if a > 0)


def _identity_key(identity):
    return tuple(identity) if isinstance(identity, list) else identity


def model_for(spec: Spec) -> Model:
    """The (cached) model of a spec's mesh, muscles, material and identity."""
    return load_face_model(spec.mesh_path.resolve(), spec.muscles_path.resolve(), spec.material, _identity_key(spec.head_identity))


def expected_seconds(model: Model, table: np.ndarray, dt: float) -> float:
    """How long simulating ``table`` should take here: its first ``MEASURED_FRAMES``
    frames run (once before, so that no compiling is timed) and their time scaled."""
    sample = table[:MEASURED_FRAMES]
    run(model, sample[:1], dt, stop_on_inversion=False)
    start = time.perf_counter()
    run(model, sample, dt, stop_on_inversion=False)
    return (time.perf_counter() - start) * len(table) / len(sample)


def check_moved(model: Model, table: np.ndarray, moved: float, source: str) -> None:
    """SimulationError when muscles are activated in ``table`` and yet no vertex moved
    further than ``STILL`` from rest (``moved``, cm, the run's largest displacement)."""
    active = np.flatnonzero(table[:, :model.muscles.count].max(axis=0) > 0) if len(table) else []
    if len(active):
        if not moved > STILL:
            names = ", ".join(model.muscles.names[m] for m in active[:3]) + (" ..." if len(active) > 3 else "")
            raise SimulationError(f"{source}: the face did not move (at most {moved:.2g} cm) although {names} "
                                  "contract: a failed simulation, nothing written", len(table) - 1)


def _posed(pose: np.ndarray | None, look: np.ndarray | None) -> np.ndarray | None:
    """The pose table (frames, 5), with the drawn controls after it (``look_table``:
    frames, 13) when they act."""
    if look is None:
        return pose
    return np.column_stack([np.zeros((len(look), 5)) if pose is None else pose, look])


def look_table(model: Model, table: np.ndarray) -> np.ndarray | None:
    """(frames, 8) the controls the renderer draws rather than the skin simulates: each
    eye's turn in degrees from the gaze controls (yaw toward the subject's left, pitch
    up; the subject's left eye, then the right), their activations times ``GAZE_ANGLE``,
    each pupil's dilation (0-1, left, right), and the tongue's protrusion and tip raise
    (0-1: facesim.face.tongue.Tongue), on top of the pose's gaze; None when none acts."""
    columns = model.rig.gaze_column
    look = np.zeros((len(table), 8))
    for eye in range(2):
        if columns[eye, 0] >= 0:
            up, down, left, right = (table[:, columns[eye, g]] * GAZE_ANGLE[g] for g in range(4))
            look[:, 2 * eye], look[:, 2 * eye + 1] = left - right, up - down
    drawn = [f"{PUPIL}_l", f"{PUPIL}_r", *TONGUE]
    for k, control in enumerate(drawn):
        if control in model.muscles.names:
            look[:, 4 + k] = np.clip(table[:, model.muscles.index(control)], 0.0, 1.0)
    return look if look.any() else None


def simulate(spec: Spec, stop_on_inversion: bool = True, notice=None, background: bool = False,
             with_muscle_forces: bool = False, stream: bool = False) -> Animation:
    """Simulate an expression spec from the neutral face. ``notice`` receives a one-line
    estimate before a run expected to take minutes. ``background``: return at once and
    simulate on a thread of its own (module docstring) when the mesh runs the serial
    kernels (fewer than ``PARALLEL_FROM`` vertices: facesim.physics.twins); the spec,
    mesh and muscles are checked before it starts either way. ``with_muscle_forces``: the muscles' forces on every frame too
    (``Animation.muscle_force``, what ``--show-muscles`` draws), after a simulation on
    this thread. ``stream`` (with ``background``): keep ``STREAMED_RING`` frames of
    positions, each simulated once the caller has released the frame that many before
    it (``Animation.positions_at``, ``release``): a clip of any length in the same
    memory, for a caller that reads its frames once, in order (a video's writer). A
    simulation that cannot run in the background keeps the whole clip.

    A larger mesh is simulated first: its simulation wants every core, and the renderer
    (llvmpipe's rasteriser threads, the frames' preparation, the encoder) already keeps
    two busy. Happy on the Hopper face subdivided twice (6,990 vertices) to MP4 at 512²,
    side by side in one process on two cores (2026-12-03): 891 ms simulated first, 1,271
    overlapped with the simulation on two threads (whose loops wait at their ends for
    the thread the renderer holds off its core), 1,103 against 1,268 on one thread. The
    head's 468 vertices: 1,035 -> 988 ms and 1,048 -> 1,013."""
    with phase("model"):
        model = model_for(spec)
    table = activation_table(spec, model.muscles)
    unusual = identity_notice(spec.identity)  # weights the spec gives (a face directory's are its fit's)
    if notice and unusual:
        notice(f"{spec.source}: {unusual}")
    faps = spec.fap_drive() if spec.fap else None
    if notice and faps and faps.unshown:
        unshown = faps.unshown
        notice(f"{spec.source}: fap: FAP{'s' if len(unshown) > 1 else ''} {', '.join(map(str, unshown))} "
               "move what this face has no control for (docs/mpeg4.md) and are left out")
    if notice and len(table) >= LONG_CLIP:
        expected = expected_seconds(model, table, spec.dt)
        if expected > LONG_RUN:
            notice(f"{spec.source}: {len(table):,} frames of {model.vertex_count:,} vertices: about "
                   f"{expected / 60:.0f} minutes of simulation, as its first frames ran here (Ctrl-C stops it)")
    behind = background and not with_muscle_forces and not on_threads(model.vertex_count)
    capacity = STREAMED_RING if behind and stream and len(table) > STREAMED_RING else None
    held = len(table) * model.vertex_count * 3 * 8
    if notice and capacity is None and held > LARGE_CLIP:
        notice(f"{spec.source}: {len(table):,} frames of {model.vertex_count:,} vertices hold {held / 2**30:.1f} GB of "
               "positions in memory (a video, drawn as it is simulated, holds a few frames)")
    out = diagnostics(len(table), model.vertex_count, capacity)
    progress = Progress(held=len(table) - 1, capacity=capacity) if behind else None
    largest = [0.0]

    def moved(block):
        largest[0] = max(largest[0], float(np.abs(block - model.rest_position).max(initial=0.0)))

    shaping = None
    if spec.speech is not None:  # the jaw carries the face as the rest of the spec shapes it (physics.run)
        unspoken = spec.model_copy(update={"speech": None})
        unspoken._source = spec._source
        shaping = activation_table(unspoken, model.muscles)

    def simulated():
        run(model, table, spec.dt, stop_on_inversion, spec.source, out=out, progress=progress, on_frames=moved,
            shaping=shaping)
        if progress and progress.cancelled:
            return  # a failed render stopped it: neither checked nor reported whole
        check_moved(model, table, largest[0], spec.source)
        if progress:
            progress.complete(len(table))

    def in_background():
        try:
            simulated()
        except BaseException as error:  # for Animation.ready to raise where the frames are wanted
            progress.fail(error)

    start = time.perf_counter()
    if progress:
        threading.Thread(target=in_background, name="facesim-simulation", daemon=True).start()
    else:
        simulated()
    seconds = time.perf_counter() - start
    positions, energy, inverted, smallest = out
    force = np.stack([muscle_forces(model, p, a) for p, a in zip(positions, table)]) if with_muscle_forces else None
    return Animation(
        name=spec.title,
        positions=positions,
        rest=model.rest_position,
        faces=model.faces,
        activations=table,
        muscle_names=model.muscles.names,
        dt=spec.dt,
        fps=spec.fps,
        kinetic_energy=energy,
        inverted=inverted,
        smallest_area=smallest,
        seconds=seconds,
        model=model,
        pose=_posed(pose_table(spec) if spec.pose or (faps and faps.pose) else None, look_table(model, table)),
        face=spec.face_directory,
        progress=progress,
        muscle_force=force,
        audio=None if spec.speech is None else placed_audio(spec.speech.utterance, spec.speech.start,
                                                            len(table) * spec.dt),
        audio_rate=0 if spec.speech is None else spec.speech.utterance.rate,
    )


