"""Worker processes that never outlive the run that started them, and never more of them
than the machine has cores.

Every process pool facesim starts (frames in parallel, batch, dataset) runs
:func:`die_with_parent` in each worker: Linux's ``PR_SET_PDEATHSIG`` sends it SIGKILL when
its parent dies however it dies (even by SIGKILL, which no handler sees), and a watchdog
thread, for platforms without it, exits when the worker finds itself re-parented. A
rendering worker holds about 400 MB; an orphan would hold it forever.
"""

from __future__ import annotations

import os
import signal
import sys
import threading
import time

#: How often (s) the watchdog looks at its parent.
WATCH_INTERVAL = 0.5
_PR_SET_PDEATHSIG = 1


def worker_pool(jobs: int):
    """A pool of ``jobs`` spawned worker processes that die with this one, sharing the
    cores: each runs a large mesh's parallel kernels on its share of them."""
    import multiprocessing
    from concurrent.futures import ProcessPoolExecutor

    return ProcessPoolExecutor(jobs, mp_context=multiprocessing.get_context("spawn"), initializer=_start_worker,
                               initargs=(os.getpid(), jobs))


def _start_worker(parent: int, jobs: int) -> None:
    """Initializer of every worker process of a pool of ``jobs``: ``die_with_parent``,
    and ``share_the_cores``."""
    die_with_parent(parent)
    share_the_cores(jobs)


def share_the_cores(processes: int) -> None:
    """Run this thread's parallel kernels on its share of the cores, ``processes`` processes
    sharing them (facesim.physics.run takes Numba's count for the calling thread). Every
    process on every core waited on the others: `batch --jobs 2` of four expressions on
    the Hopper face subdivided twice (6,990 vertices) took 24.0-26.0 s wall and 43-45 s
    of CPU on two cores, 9.9-10.4 s and 16-17 s with a thread each (2026-12-06)."""
    import numba

    from .config import prepare_numba

    prepare_numba()  # the threads this starts are OpenMP's, as a kernel's would be
    numba.set_num_threads(max(1, min(numba.config.NUMBA_NUM_THREADS, available_cores() // processes)))


def die_with_parent(parent: int) -> None:
    """Initializer of every worker process: end when ``parent`` (the pid of the process
    that started the pool, passed in: a worker that starts after its parent died finds
    itself re-parented, and its own getppid() would name the new parent) ends."""
    if sys.platform.startswith("linux"):
        import ctypes

        try:
            ctypes.CDLL(None, use_errno=True).prctl(_PR_SET_PDEATHSIG, signal.SIGKILL)
        except (OSError, AttributeError):
            pass
    if os.getppid() != parent:  # the parent died before prctl took effect
        os._exit(1)

    def watch():
        while os.getppid() == parent:
            time.sleep(WATCH_INTERVAL)
        os._exit(1)

    threading.Thread(target=watch, name="facesim-watchdog", daemon=True).start()


def available_cores() -> int:
    """The cores this process may run on (its affinity, else the machine's count)."""
    try:
        return len(os.sched_getaffinity(0))
    except AttributeError:
        return os.cpu_count() or 1


def capped_jobs(jobs: int, warn=None) -> int:
    """``jobs`` limited to the cores available: more rendering processes than cores only
    add memory (about 400 MB each) and contention. ``warn`` receives a one-line message."""
    cores = available_cores()
    if jobs > cores:
        if warn:
            warn(f"--jobs {jobs}: this machine has {cores} cores; using {cores}")
        return cores
    return jobs
