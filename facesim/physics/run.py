"""A model run from rest under a table of activations: the Numba simulation
(facesim.physics.solver) called in pieces, in the model's vertex order and back, with
its diagnostics and the error of a run that blew up (:class:`SimulationError` naming the
frame and the vertex or triangle), on this thread or frame by frame for a caller that
waits on it (:class:`Progress`); and the muscle forces on a face at given positions.
"""

from __future__ import annotations

import threading
import time

import numba
import numpy as np

from ..config import PARALLEL_FROM
from ..errors import SimulationError
from . import layout, rig_control, solver
from .model import Model
from .muscle_forces import _muscle_forces

#: Vertex-steps per call of the simulation kernel (about 0.2 s): a long run returns to
#: Python between calls, where Ctrl-C and SIGTERM are handled.
STEPS_PER_CALL = 1_000_000
#: Frames per call of the simulation kernel when it runs in the background: a frame is
#: handed to the renderer as soon as it is simulated.
STREAMED_FRAMES = 1
#: A run is "runaway" when its kinetic energy exceeds that of every vertex crossing a
#: tenth of the face in one frame: far beyond any expression, short of overflow.
RUNAWAY_FRACTION = 0.1



class Progress:
    """How far a simulation running in the background has come (``simulate``): the frames
    done, the seconds spent so far, the error that stopped it; ``cancelled`` asks it to
    stop after the frame it is on. With ``held``, no more than that many frames are
    reported done until ``release``: a check of the whole run (that its face moved) may
    still fail it before a caller has its last frame."""

    def __init__(self, held: int | None = None):
        self._condition = threading.Condition()
        self.held = held
        self.done = 0
        self.seconds = 0.0
        self.error: BaseException | None = None
        self.cancelled = False

    def advance(self, done: int, seconds: float) -> None:
        with self._condition:
            self.done, self.seconds = (done if self.held is None else min(done, self.held)), seconds
            self._condition.notify_all()

    def release(self, done: int) -> None:
        """Report ``done`` frames, past ``held``."""
        with self._condition:
            self.held, self.done = None, done
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


def compiled_here() -> bool:
    """Whether this process compiled the simulation's kernel rather than loading it from
    Numba's cache (what a slow first run is put down to)."""
    return sum(solver._simulate.stats.cache_misses.values()) > 0


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
    state = layout.State(np.array(model.arrays.rest_position), np.zeros((n, 3)))  # the kernels' vertex order (Model)
    out = diagnostics(frames, n) if out is None else out
    kernel_out = out if model.vertex_order is None else out._replace(positions=np.empty_like(out.positions))
    frame_speed = RUNAWAY_FRACTION * model.scale / dt
    energy_limit = 0.5 * model.material.mass * n * frame_speed**2
    table = np.ascontiguousarray(activations, dtype=np.float64)
    control = rig_control.control(model.arrays, np.zeros(table.shape[1]))
    work, forces = layout.workspace(model.arrays), layout.forces(model.arrays)
    factor = model.preconditioner(float(dt) / model.material.substeps)
    piece = STREAMED_FRAMES if progress else max(1, int(STEPS_PER_CALL / (model.material.substeps * n)))
    status, frame, element = layout.OK, -1, -1
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
            done = stop if status == layout.OK else frame
            if kernel_out is not out:  # into the mesh's vertex order
                out.positions[start:done] = model.in_mesh_order(kernel_out.positions[start:done], axis=1)
            if progress:
                progress.advance(done, time.perf_counter() - started)
            if status != layout.OK or (progress and progress.cancelled):
                break
    finally:
        numba.set_num_threads(previous)
    positions, energy, inverted, smallest = out
    if status == layout.NOT_FINITE:
        raise SimulationError(f"{source}: simulation diverged at frame {frame}: vertex {model.mesh_vertex(element)} is not "
                              "finite", frame)
    if status == layout.INVERTED:
        raise SimulationError(f"{source}: simulation failed at frame {frame}: triangle {model.mesh_triangle(element)} inverted",
                              frame)
    if status == layout.RUNAWAY:
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


def muscle_forces(model: Model, positions: np.ndarray, activation: np.ndarray) -> np.ndarray:
    """The muscle forces (eq. 3.1-3.25) acting on a face at ``positions`` (n, 3) under
    ``activation`` (one row of the activation table: muscles, then jaw and eyelids), with
    the muscles' ends where the jaw and lids hold them, as in the step: what
    ``--show-muscles`` draws, as the thesis's figure 3.10."""
    x = np.ascontiguousarray(model.in_kernel_order(positions), dtype=np.float64)
    forces = layout.forces(model.arrays)
    control = rig_control.control(model.arrays, activation)
    _muscle_forces(model.arrays, x, control, layout.workspace(model.arrays), forces)
    return model.in_mesh_order(forces.force)
