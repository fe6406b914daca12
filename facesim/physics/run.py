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

from ..errors import SimulationError
from . import layout, rig_control, solver, twins
from .material import steps_per_frame
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
    reported done until ``complete``: a check of the whole run (that its face moved) may
    still fail it before a caller has its last frame. With ``capacity``, the run's
    positions are a ring of that many frames (a streamed run): a frame is simulated only
    once the caller has ``release``d the frame ``capacity`` before it."""

    def __init__(self, held: int | None = None, capacity: int | None = None):
        self._condition = threading.Condition()
        self.held = held
        self.capacity = capacity
        self.released = 0
        self.done = 0
        self.seconds = 0.0
        self.error: BaseException | None = None
        self.cancelled = False

    def advance(self, done: int, seconds: float) -> None:
        with self._condition:
            self.done, self.seconds = (done if self.held is None else min(done, self.held)), seconds
            self._condition.notify_all()

    def complete(self, done: int) -> None:
        """Report ``done`` frames, past ``held``."""
        with self._condition:
            self.held, self.done = None, done
            self._condition.notify_all()

    def release(self, frame: int) -> None:
        """The caller is done with frames up to ``frame``: their slots may be reused."""
        with self._condition:
            self.released = max(self.released, frame + 1)
            self._condition.notify_all()

    def wait_for_room(self, stop: int) -> None:
        """Return once frames up to ``stop`` (exclusive) fit in the ring, or when cancelled."""
        if self.capacity is not None:
            with self._condition:
                self._condition.wait_for(lambda: stop - self.released <= self.capacity or self.cancelled)

    def cancel(self) -> None:
        with self._condition:
            self.cancelled = True
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
    return any(sum(kernel.stats.cache_misses.values()) > 0 for kernel in twins.variants(solver._simulate))


def run(
    model: Model,
    activations: np.ndarray,
    dt: float,
    stop_on_inversion: bool = True,
    source: str = "simulation",
    threads: int | None = None,
    out: solver.Diagnostics | None = None,
    progress: Progress | None = None,
    on_frames=None,
    shaping: np.ndarray | None = None,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Simulate ``activations`` (frames, M) from rest. Returns positions, kinetic energy,
    inverted-triangle counts and smallest relative areas per frame: ``out``'s arrays if
    given (``diagnostics``). The kernels' parallel loops run on ``threads`` threads: by
    default, for a mesh of at least ``PARALLEL_FROM`` vertices, as many as Numba gives
    the calling thread (every core, unless the caller chose fewer with
    ``numba.set_num_threads``: processes sharing the cores), else
    the serial twins of the kernels run (facesim.physics.twins); given ``threads``, the
    parallel kernels run on that many, on any mesh. With ``progress``, ``STREAMED_FRAMES`` frames a call, each
    reported done as soon as it is in ``out``, and the run stops early when cancelled;
    ``out.positions`` may then hold fewer frames than the run, a ring reused in turn as
    the caller releases frames (``Progress``). ``on_frames(positions)`` sees each piece's
    positions (k, n, 3), in the mesh's order, as they are written.

    ``shaping`` (frames, M): activations whose muscles shape the skin that the jaw then
    carries (``shaped_by_the_muscles``): an expression under words said."""
    frames = len(activations)
    if activations.ndim != 2 or activations.shape[1] != len(model.muscles.names):
        raise ValueError(f"activations must be (frames, {len(model.muscles.names)}), one column per muscle and control")
    n = model.vertex_count
    shaped = None if shaping is None else shaped_by_the_muscles(model, activations, shaping, dt, source, threads)
    if shaped is not None:  # the rest positions a frame's rig reads, the held rows rewritten each frame
        rest = np.array(model.arrays.rest_position)
        # handed to the kernels read-only, as the model's own arrays are: a writable array is
        # another type to Numba, and every kernel was compiled again for it (about 50 s, the
        # first time a spec spoke over an expression on a machine)
        frozen = rest.view()
        frozen.setflags(write=False)
        shaped = (*shaped, rest, frozen)
    state = layout.State(np.array(model.arrays.rest_position), np.zeros((n, 3)))  # the kernels' vertex order (Model)
    out = diagnostics(frames, n) if out is None else out
    ring = len(out.positions) < frames  # a streamed run: a few frames' room, reused in turn
    if ring and (progress is None or progress.capacity != len(out.positions)):
        raise ValueError("positions for fewer frames than the run need a Progress of that capacity")
    frame_speed = RUNAWAY_FRACTION * model.scale / dt
    energy_limit = 0.5 * model.material.mass * n * frame_speed**2
    table = np.ascontiguousarray(activations, dtype=np.float64)
    control = rig_control.control(model.arrays, np.zeros(table.shape[1]))
    work, forces = layout.workspace(model.arrays), layout.forces(model.arrays)
    substeps = steps_per_frame(model.material, float(dt))
    factor = model.preconditioner(float(dt) / substeps)
    piece = 1 if ring or shaped is not None else STREAMED_FRAMES if progress else max(1, int(STEPS_PER_CALL / (substeps * n)))
    scratch = None if model.vertex_order is None else np.empty((min(piece, frames), n, 3))  # the kernels' order
    status, frame, element = layout.OK, -1, -1
    started = time.perf_counter()
    simulate = twins.for_mesh(solver._simulate, n, threads)
    if threads is None:
        threads = numba.get_num_threads() if twins.on_threads(n) else 1
    previous = numba.get_num_threads()
    numba.set_num_threads(min(threads, numba.config.NUMBA_NUM_THREADS))
    try:
        for start in range(0, frames, piece):  # Python between pieces: Ctrl-C and SIGTERM act within about 0.2 s
            stop = min(frames, start + piece)
            if progress:
                progress.wait_for_room(stop)
                if progress.cancelled:
                    break
            first = start % len(out.positions) if ring else start
            rows = out.positions[first:first + stop - start]
            arrays = model.arrays
            if shaped is not None:  # where the jaw takes its skin: the rest shape the muscles made this frame
                held, offset, rest, frozen = shaped
                rest[held] = model.arrays.rest_position[held] + offset[start]
                arrays = arrays._replace(rest_position=frozen)
            status, frame, element = simulate(
                arrays, table, start, stop, float(dt), substeps, energy_limit,
                stop_on_inversion, state, control, work, forces, factor,
                out._replace(positions=rows if scratch is None else scratch[:stop - start]),
            )
            done = stop if status == layout.OK else frame
            if scratch is not None:  # into the mesh's vertex order
                rows[:done - start] = model.in_mesh_order(scratch[:done - start], axis=1)
            if on_frames is not None:
                on_frames(rows[:done - start])
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


def jaw_family(model: Model) -> list[int]:
    """The activation columns of the jaw's rig: its opening, the lips' seal, shift and
    rolls, and the condyles' glides (facesim.physics.rig)."""
    a = model.arrays
    columns = [a.jaw_column, a.jaw_seal_column, *a.lip_shift_column, *a.lip_roll_column, *a.jaw_glide_column]
    return [int(c) for c in columns if c >= 0]


def shaped_by_the_muscles(model: Model, activations: np.ndarray, shaping: np.ndarray, dt: float, source: str,
                          threads) -> tuple | None:
    """The skin the jaw holds (the lips, the mouth's corners, the skin over the mandible:
    ``Rig.drive_weight``), as the muscles of ``shaping`` alone shape it, frame by frame:
    (its rows in the kernels' order, (frames, rows, 3) their displacement from rest), from
    a run of ``shaping`` with the jaw's rig at rest; None where the jaw does not move in
    ``activations`` or no muscle acts in ``shaping``.

    The jaw's rig drives that skin to where the bone takes it, with a stiffness far above
    any muscle's (it keeps the corners' slivers from folding). Driven to where the bone
    takes its rest shape, a smile under words kept 7% of its lift; driven to where the
    bone takes the smile's shape, at least 70%, the bilabials still closing (0.43-0.85 mm
    at their middles). The words' own muscles stay out of ``shaping``: the visemes were made
    against the rig's hold, and their lip muscles alone, unheld, fold the mouth's corners."""
    a = model.arrays
    family = jaw_family(model)
    muscles = a.muscle_kind.shape[0]
    if not family or not activations[:, family].any() or not shaping[:, :muscles].any():
        return None
    rows = np.flatnonzero((a.drive_weight > 0) & (a.drive_column == a.jaw_column))
    if not len(rows):
        return None
    still = np.array(shaping, dtype=np.float64)
    still[:, family] = 0.0
    offset = np.empty((len(still), len(rows), 3), dtype=np.float32)  # 1.8 KB a frame on the head: the skin alone is not kept
    ring = Progress(capacity=1)
    done = [0]

    def keep(positions):
        for x in positions:
            offset[done[0]] = model.in_kernel_order(x)[rows] - a.rest_position[rows]
            ring.release(done[0])
            done[0] += 1

    run(model, still, dt, stop_on_inversion=False, source=source, threads=threads, out=diagnostics(len(still), model.vertex_count, 1),
        progress=ring, on_frames=keep)
    # the shape is carried as far as the rig holds the skin (min(1, 10 a), physics.rig_control):
    # as the jaw comes to rest the skin is let go where the muscles hold it, not snapped there
    offset *= np.minimum(1.0, 10.0 * activations[:, family].max(axis=1))[:, None, None]
    return rows, offset


def diagnostics(frames: int, n: int, capacity: int | None = None) -> solver.Diagnostics:
    """Room for a run's output (``run``): positions, kinetic energy, inverted triangles and
    smallest relative area per frame; positions for ``capacity`` frames alone, when
    given (a streamed run's ring)."""
    held = frames if capacity is None else min(capacity, frames)
    return solver.Diagnostics(np.empty((held, n, 3)), np.zeros(frames), np.zeros(frames, dtype=np.int64), np.zeros(frames))


def muscle_forces(model: Model, positions: np.ndarray, activation: np.ndarray) -> np.ndarray:
    """The muscle forces (eq. 3.1-3.25) acting on a face at ``positions`` (n, 3) under
    ``activation`` (one row of the activation table: muscles, then jaw and eyelids), with
    the muscles' ends where the jaw and lids hold them, as in the step: what
    ``--show-muscles`` draws, as the thesis's figure 3.10."""
    x = np.ascontiguousarray(model.in_kernel_order(positions), dtype=np.float64)
    forces = layout.forces(model.arrays)
    control = rig_control.control(model.arrays, activation)
    twins.for_mesh(_muscle_forces, model.vertex_count)(model.arrays, x, control, layout.workspace(model.arrays), forces)
    return model.in_mesh_order(forces.force)
