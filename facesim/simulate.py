"""Running a spec: model, activation table, the Numba simulation, diagnostics.

``simulate(spec)`` is the one entry point: it builds (and caches) the model of the spec's
mesh, muscles and material, turns the spec into a (frames, muscles) activation table,
runs ``solver._simulate`` and wraps the result in an :class:`Animation`. A simulation
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
from collections import OrderedDict
from dataclasses import dataclass, field
from functools import lru_cache
from pathlib import Path

import numba
import numpy as np

from . import kernels, solver
from .config import PARALLEL_FROM
from .errors import SimulationError
from .mesh import FaceMesh, load_face
from .model import Material, Model, build_model
from .muscles import MuscleSet, load_muscles
from .spec import Spec, activation_table, pose_table

#: Vertex-steps per call of the simulation kernel (about 0.2 s): a long run returns to
#: Python between calls, where Ctrl-C and SIGTERM are handled.
STEPS_PER_CALL = 1_000_000
#: Frames per call of the simulation kernel when it runs in the background: a frame is
#: handed to the renderer as soon as it is simulated.
STREAMED_FRAMES = 1
#: A run expected to take longer than this (s) is announced before it starts.
LONG_RUN = 120.0
#: Vertex-steps per second assumed for that estimate (BENCHMARKS.md: 2-4 million).
STEP_RATE = 2e6

#: A run is "runaway" when its kinetic energy exceeds that of every vertex crossing a
#: tenth of the face in one frame: far beyond any expression, short of overflow.
RUNAWAY_FRACTION = 0.1


class Progress:
    """How far a simulation running in the background has come (``simulate``): the frames
    done, the seconds spent so far, the error that stopped it; ``cancelled`` asks it to
    stop after the frame it is on."""

    def __init__(self):
        self._condition = threading.Condition()
        self.done = 0
        self.seconds = 0.0
        self.error: BaseException | None = None
        self.cancelled = False

    def advance(self, done: int, seconds: float) -> None:
        with self._condition:
            self.done, self.seconds = done, seconds
            self._condition.notify_all()

    def fail(self, error: BaseException) -> None:
        with self._condition:
            self.error = error
            self._condition.notify_all()

    def wait(self, frame: int) -> None:
        """Return once frame ``frame`` is simulated; raise the error that stopped the
        simulation before it."""
        with self._condition:
            self._condition.wait_for(lambda: self.done > frame or self.error is not None)
            if self.done <= frame:
                raise self.error


@dataclass(frozen=True)
class Animation:
    """The result of a simulation.

    positions : (frames, n, 3) cm; rest : (n, 3); faces : (t, 3);
    activations : (frames, M + controls); pose : (frames, 5) head and gaze angles in
    degrees (facesim.spec.POSE), applied at render time; kinetic_energy, smallest_area :
    (frames,) float; inverted : (frames,) int (triangles turned over and folded against
    the skin around them, ``kernels._triangle_checks``); face : the face directory
    (facesim.own_face.FaceDirectory) whose head this is, if any: its texture and camera;
    progress : set while it is simulated in the background (``ready``).
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
            self.progress.cancelled = True

    @property
    def simulation_seconds(self) -> float:
        """Seconds spent simulating (so far, in the background)."""
        return self.seconds if self.progress is None else self.progress.seconds

    def pose_at(self, frame: int) -> np.ndarray | None:
        return None if self.pose is None else self.pose[frame]

    def jaw_at(self, frame: int) -> float:
        """The jaw's angle (radians) at a frame: its activation times its largest angle."""
        return float(self.jaw[frame])

    @property
    def jaw(self) -> np.ndarray:
        """(frames,) the jaw's angle (radians): its activation times its largest angle."""
        rig = None if self.model is None else self.model.rig
        if rig is None or rig.jaw_column < 0:
            return np.zeros(self.frames)
        return self.activations[:, rig.jaw_column] * rig.jaw_max

    @property
    def figure(self):
        """The head this animation's face drives (facesim.figure), or None for a mask."""
        return None if self.model is None else figure_for(self.model)

    @property
    def frames(self) -> int:
        return len(self.positions)

    @property
    def active_muscles(self) -> tuple[str, ...]:
        return tuple(n for n, a in zip(self.muscle_names, self.activations.max(axis=0)) if a > 0)


@lru_cache(maxsize=8)
def _mesh_and_muscles(mesh_path: Path, muscles_path: Path, identity=None) -> tuple[FaceMesh, MuscleSet]:
    mesh = load_face(mesh_path, identity)  # the checks of `facesim mesh info`, before any simulation
    return mesh, load_muscles(muscles_path, mesh)


@lru_cache(maxsize=8)
def _model(mesh_path: Path, muscles_path: Path, material: Material, identity=None) -> Model:
    return build_model(*_mesh_and_muscles(mesh_path, muscles_path, identity), material)


def _identity_key(identity):
    return tuple(identity) if isinstance(identity, list) else identity


def model_for(spec: Spec) -> Model:
    """The (cached) model of a spec's mesh, muscles, material and identity."""
    return _model(spec.mesh_path.resolve(), spec.muscles_path.resolve(), spec.material, _identity_key(spec.head_identity))


#: Figures kept per process (a dataset of many identities keeps only the latest).
FIGURE_CACHE = 4
_figures: "OrderedDict[int, tuple]" = OrderedDict()


def figure_for(model: Model):
    """What the renderer draws for a model: a head's figure (built once per model), or
    None for a face mask."""
    from .figure import head_figure
    from .head import HeadMesh

    if not isinstance(model.mesh, HeadMesh):
        return None
    if id(model) not in _figures:
        _figures[id(model)] = (model, head_figure(model.mesh.head, model))  # the model kept alive with its key
        while len(_figures) > FIGURE_CACHE:
            _figures.popitem(last=False)
    _figures.move_to_end(id(model))
    return _figures[id(model)][1]


def run(
    model: Model,
    activations: np.ndarray,
    dt: float,
    stop_on_inversion: bool = True,
    source: str = "simulation",
    threads: int | None = None,
    out: solver.Diagnostics | None = None,
    progress: Progress | None = None,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Simulate ``activations`` (frames, M) from rest. Returns positions, kinetic energy,
    inverted-triangle counts and smallest relative areas per frame: ``out``'s arrays if
    given (``diagnostics``). The kernels' parallel loops run on ``threads`` threads: by
    default every core Numba has for a mesh of at least ``PARALLEL_FROM`` vertices, else
    one (facesim.config). With ``progress``, ``STREAMED_FRAMES`` frames a call, each
    reported done as soon as it is in ``out``, and the run stops early when cancelled."""
    frames = len(activations)
    if activations.ndim != 2 or activations.shape[1] != len(model.muscles.names):
        raise ValueError(f"activations must be (frames, {len(model.muscles.names)}), one column per muscle and control")
    n = model.vertex_count
    state = kernels.State(np.array(model.arrays.rest_position), np.zeros((n, 3)))  # the kernels' vertex order (Model)
    out = diagnostics(frames, n) if out is None else out
    kernel_out = out if model.vertex_order is None else out._replace(positions=np.empty_like(out.positions))
    frame_speed = RUNAWAY_FRACTION * model.scale / dt
    energy_limit = 0.5 * model.material.mass * n * frame_speed**2
    table = np.ascontiguousarray(activations, dtype=np.float64)
    control = kernels.control(model.arrays, np.zeros(table.shape[1]))
    work, forces = kernels.workspace(model.arrays), kernels.forces(model.arrays)
    factor = model.preconditioner(float(dt) / model.material.substeps)
    piece = STREAMED_FRAMES if progress else max(1, int(STEPS_PER_CALL / (model.material.substeps * n)))
    status, frame, element = kernels.OK, -1, -1
    started = time.perf_counter()
    if threads is None:
        threads = numba.config.NUMBA_NUM_THREADS if n >= PARALLEL_FROM else 1
    previous = numba.get_num_threads()
    numba.set_num_threads(min(threads, numba.config.NUMBA_NUM_THREADS))
    try:
        for start in range(0, frames, piece):  # Python between pieces: Ctrl-C and SIGTERM act within about 0.2 s
            stop = min(frames, start + piece)
            status, frame, element = solver._simulate(
                model.arrays, table, start, stop, float(dt), int(model.material.substeps),
                energy_limit, stop_on_inversion, state, control, work, forces, factor, kernel_out,
            )
            done = stop if status == kernels.OK else frame
            if kernel_out is not out:  # into the mesh's vertex order
                out.positions[start:done] = model.in_mesh_order(kernel_out.positions[start:done], axis=1)
            if progress:
                progress.advance(done, time.perf_counter() - started)
            if status != kernels.OK or (progress and progress.cancelled):
                break
    finally:
        numba.set_num_threads(previous)
    positions, energy, inverted, smallest = out
    if status == kernels.NOT_FINITE:
        raise SimulationError(f"{source}: simulation diverged at frame {frame}: vertex {model.mesh_vertex(element)} is not "
                              "finite", frame)
    if status == kernels.INVERTED:
        raise SimulationError(f"{source}: simulation failed at frame {frame}: triangle {model.mesh_triangle(element)} inverted",
                              frame)
    if status == kernels.RUNAWAY:
        raise SimulationError(f"{source}: simulation diverged at frame {frame}: runaway kinetic energy {energy[frame]:.3g}", frame)
    return positions, energy, inverted, smallest


def concurrent_kernels() -> bool:
    """Whether two threads may run facesim's parallel kernels at once: the simulation in the
    background and the renderer's. Numba's OpenMP and TBB layers allow it; its own
    workqueue, the fallback on a machine without libgomp or TBB, stops the process when a
    second thread starts a parallel loop, so there the simulation runs first. Known once a
    parallel kernel has run in the process (building a model runs one)."""
    try:
        return numba.threading_layer() in ("omp", "tbb")
    except ValueError:  # no parallel kernel run yet
        return False


def diagnostics(frames: int, n: int) -> solver.Diagnostics:
    """Room for a run's output (``run``): positions, kinetic energy, inverted triangles and
    smallest relative area per frame."""
    return solver.Diagnostics(np.empty((frames, n, 3)), np.zeros(frames), np.zeros(frames, dtype=np.int64), np.zeros(frames))


def simulate(spec: Spec, stop_on_inversion: bool = True, notice=None, background: bool = False) -> Animation:
    """Simulate an expression spec from the neutral face. ``notice`` receives a one-line
    estimate before a run expected to take minutes. ``background``: return at once and
    simulate on a thread of its own (module docstring), where Numba allows it
    (``concurrent_kernels``) and the mesh is simulated on one thread (fewer than
    ``PARALLEL_FROM`` vertices); the spec, mesh and muscles are checked before it starts
    either way.

    A larger mesh is simulated first: its simulation wants every core, and the renderer
    (llvmpipe's rasteriser threads, the frames' preparation, the encoder) already keeps
    two busy. Happy on the Hopper face subdivided twice (6,990 vertices) to MP4 at 512²,
    side by side in one process on two cores (2026-12-03): 891 ms simulated first, 1,271
    overlapped with the simulation on two threads (whose loops wait at their ends for
    the thread the renderer holds off its core), 1,103 against 1,268 on one thread. The
    head's 468 vertices: 1,035 -> 988 ms and 1,048 -> 1,013."""
    model = model_for(spec)
    table = activation_table(spec, model.muscles)
    expected = len(table) * model.material.substeps * model.vertex_count / STEP_RATE
    if notice and expected > LONG_RUN:
        notice(f"{spec.source}: {len(table)} frames x {model.material.substeps} sub-steps x {model.vertex_count:,} "
               f"vertices: about {expected / 60:.0f} minutes of simulation (Ctrl-C stops it)")
    out = diagnostics(len(table), model.vertex_count)
    progress = Progress() if background and concurrent_kernels() and model.vertex_count < PARALLEL_FROM else None

    def simulated():
        run(model, table, spec.dt, stop_on_inversion, spec.source, out=out, progress=progress)

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
        pose=pose_table(spec) if spec.pose else None,
        face=spec.face_directory,
        progress=progress,
    )


def muscle_forces(model: Model, positions: np.ndarray, activation: np.ndarray) -> np.ndarray:
    """The muscle forces (eq. 3.1-3.25) acting on a face at ``positions`` (n, 3) under
    ``activation`` (one row of the activation table: muscles, then jaw and eyelids), with
    the muscles' ends where the jaw and lids hold them, as in the step: what
    ``--show-muscles`` draws, as the thesis's figure 3.10."""
    x = np.ascontiguousarray(model.in_kernel_order(positions), dtype=np.float64)
    forces = kernels.forces(model.arrays)
    control = kernels.control(model.arrays, activation)
    kernels._muscle_forces(model.arrays, x, control, kernels.workspace(model.arrays), forces)
    return model.in_mesh_order(forces.force)
