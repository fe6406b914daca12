"""Where a command's time goes, phase by phase: ``facesim render --timings``.

A phase adds up the wall time of the blocks named for it (``with phase("model"):``), on
whichever thread runs them; ``imports`` is the time from the process's start to the
command's (Python, facesim and what it imports); ``kernels`` is Numba's: the time its
dispatchers spent loading compiled kernels from the cache, or compiling them, counted
from its ``numba:compile`` events (the outermost of each thread), and it lies within the
phases that first called them. Phases overlap where the work does: a small face is
simulated on a thread of its own while the frames are drawn and encoded
(facesim.animation.simulate), so they add up to more than the wall time.
"""

from __future__ import annotations

import os
import threading
import time
from contextlib import contextmanager

#: The phases of a render, in the order they are reported.
PHASES = ("imports", "kernels", "model", "figure", "GL context", "simulation", "drawing", "encoding")

_seconds: dict[str, float] = {}
_lock = threading.Lock()
_listening = False


def add(name: str, seconds: float) -> None:
    with _lock:
        _seconds[name] = _seconds.get(name, 0.0) + seconds


@contextmanager
def phase(name: str):
    """Count the block's wall time to ``name``."""
    started = time.perf_counter()
    try:
        yield
    finally:
        add(name, time.perf_counter() - started)


def process_age() -> float | None:
    """Seconds since this process started (Linux's /proc; None elsewhere)."""
    try:
        with open("/proc/self/stat") as stat:
            started = int(stat.read().rpartition(")")[2].split()[19]) / os.sysconf("SC_CLK_TCK")
        return time.clock_gettime(time.CLOCK_BOOTTIME) - started
    except (OSError, ValueError, IndexError, AttributeError):
        return None


def start() -> None:
    """Begin counting: the imports up to now, and Numba's kernels from now on."""
    global _listening
    age = process_age()
    if age is not None:
        add("imports", age)
    if not _listening:
        from numba.core import event

        class KernelListener(event.Listener):
            """The outermost compile event of each thread, timed (``kernels``)."""

            def __init__(self):
                self._local = threading.local()

            def on_start(self, _):
                local = self._local
                local.depth = getattr(local, "depth", 0) + 1
                if local.depth == 1:
                    local.started = time.perf_counter()

            def on_end(self, _):
                local = self._local
                local.depth -= 1
                if local.depth == 0:
                    add("kernels", time.perf_counter() - local.started)

        event.register("numba:compile", KernelListener())
        _listening = True


def seconds() -> dict[str, float]:
    with _lock:
        return dict(_seconds)


def summary(total: float | None = None) -> str:
    """One line: each phase counted, in ``PHASES``' order, then the others."""
    counted = seconds()
    names = [name for name in PHASES if name in counted] + sorted(set(counted) - set(PHASES))
    parts = [f"{name} {counted[name]:.2f} s" for name in names]
    return "timings: " + ", ".join(parts) + ("" if total is None else f"; wall {total:.2f} s")
