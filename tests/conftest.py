"""Shared fixtures: the default face, its muscles, models and expression specs; waiting
on a condition (never a fixed sleep) for the tests that signal a running process."""

import os
import resource
import sys
import time
from collections import defaultdict
from pathlib import Path

import numpy as np
import pytest

import facesim
from facesim.animation.simulate import model_for
from facesim.animation.spec import activation_table
from facesim.config import DEFAULT_MESH, DEFAULT_MUSCLES
from facesim.face.loading import load_mesh
from facesim.face.muscle_file import load_muscles
from facesim.physics.run import run

ROOT = Path(__file__).resolve().parent.parent
EXPRESSIONS = ROOT / "expressions"


def wait_for(condition, timeout=120.0, what="the condition"):
    """The first truthy value of ``condition()``, polled every 50 ms; fails after ``timeout`` s."""
    end = time.monotonic() + timeout
    while time.monotonic() < end:
        found = condition()
        if found:
            return found
        time.sleep(0.05)
    raise AssertionError(f"timed out waiting for {what}")


def cpu_seconds(pid: int) -> float:
    """CPU time (user + system, s) process ``pid`` has used: past imports and cached
    kernels, a render is simulating."""
    fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
    return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")


THESIS_EXPRESSIONS = ["happy", "sad", "angry", "fear", "disgust", "surprise", "disgusted_anger", "happy_surprise"]


@pytest.fixture(scope="session")
def mesh():
    return load_mesh(DEFAULT_MESH)


@pytest.fixture(scope="session")
def muscles(mesh):
    return load_muscles(DEFAULT_MUSCLES, mesh)


def spec(name: str, **changes):
    s = facesim.load_spec(EXPRESSIONS / f"{name}.yaml")
    return s.with_overrides(**changes) if changes else s


def material(name: str = "happy", **changes):
    """A spec's material with fields replaced."""
    from facesim.face.material import MaterialSpec

    return MaterialSpec.model_validate({**spec(name).material.model_dump(exclude_unset=True), **changes})


def held_apex(s, hold: int = 200):
    """A spec's face at its apex (its strongest frame), held ``hold`` frames: the model,
    the mean positions of the last 50 frames (disgust's lips keep a 0.15 mm tremor at
    their contact) and the most inverted triangles in any frame. Used by tests/test_solver.py
    and by scripts/bench.py to compare the solvers."""
    model = model_for(s)
    table = activation_table(s, model.muscles)
    apex = int(np.argmax(np.abs(table).sum(axis=1)))
    held = np.vstack([table[:apex + 1], np.repeat(table[apex:apex + 1], hold, axis=0)])
    positions, _, inverted, _ = run(model, held, s.dt, stop_on_inversion=False)
    return model, positions[-50:].mean(axis=0), int(inverted.max())


@pytest.fixture(scope="session")
def model():
    return model_for(spec("happy"))


@pytest.fixture()
def rng():
    return np.random.default_rng(20261122)


def pytest_configure(config):
    # the workers share the cores: a large mesh's parallel kernels on every core in each of
    # two workers on two cores waited on each other (the own-face and fold tests, side by
    # side: 95 s wall and 175 s of CPU against 77 s and 132 s with one thread each); a test
    # that asks for threads (run(threads=2)) still gets them
    workers = int(os.environ.get("PYTEST_XDIST_WORKER_COUNT", "1"))
    if workers > 1:
        from facesim.workers import share_the_cores

        share_the_cores(workers)
    config.addinivalue_line("markers", "heavy(seconds): a test that takes about this long alone (a copy of the package "
                            "compiled, the benchmark, a wheel built): run first, so two workers finish together")


def pytest_collection_modifyitems(items):
    """The heavy tests first, longest first, each with the rest of its module after it:
    `make test` hands whole modules to its two workers in this order (xdist's loadscope,
    so a module's fixtures are made on one worker, once), and the two share the long ones
    from the start instead of one of them starting a two-minute test at the end while the
    other idles."""
    def weight(item):
        mark = item.get_closest_marker("heavy")
        return mark.args[0] if mark else 0.0

    module_weight: dict = {}
    for item in items:
        module_weight[item.module] = max(module_weight.get(item.module, 0.0), weight(item))
    order = {module: k for k, module in enumerate(dict.fromkeys(item.module for item in items))}
    position = {id(item): k for k, item in enumerate(items)}
    items.sort(key=lambda item: (-module_weight[item.module], order[item.module], -weight(item), position[id(item)]))


#: Where the suite's time goes, by module: wall seconds, CPU seconds in the test's own
#: process and in the subprocesses it ran and waited for (a command run as users run it,
#: a copy of the package compiled, the benchmark). Printed at the end of every run: the
#: suite's target (issue 45) is met by cutting CPU, not by spreading it.
_CPU: dict = defaultdict(lambda: [0.0, 0.0, 0.0])


def _spent() -> tuple[float, float, float]:
    children = resource.getrusage(resource.RUSAGE_CHILDREN)
    forked = sys.modules.get("forked")  # commands forked by tests/forked.py's server, not this process's children
    return (time.perf_counter(), time.process_time(),
            children.ru_utime + children.ru_stime + (forked.cpu if forked else 0.0))


def _measured(item, when):
    before = _spent()
    yield
    after = _spent()
    item.user_properties.append(("cpu", (when, *(b - a for a, b in zip(before, after)))))


@pytest.hookimpl(hookwrapper=True)
def pytest_runtest_setup(item):
    yield from _measured(item, "setup")


@pytest.hookimpl(hookwrapper=True)
def pytest_runtest_call(item):
    yield from _measured(item, "call")


@pytest.hookimpl(hookwrapper=True)
def pytest_runtest_teardown(item):
    yield from _measured(item, "teardown")


def pytest_runtest_logreport(report):
    for name, value in report.user_properties:
        if name == "cpu" and value[0] == report.when:  # a phase's report carries the phases before it too
            totals = _CPU[report.nodeid.split("::")[0]]
            for k, seconds in enumerate(value[1:]):
                totals[k] += seconds


def pytest_terminal_summary(terminalreporter):
    if not _CPU:
        return
    rows = sorted(_CPU.items(), key=lambda row: -(row[1][1] + row[1][2]))
    write = terminalreporter.write_line
    terminalreporter.section("where the time went, by module (seconds)")
    write(f"{'module':32s} {'wall':>7s} {'CPU':>7s} {'in subprocesses':>16s}")
    for module, (wall, own, children) in rows[:15]:
        write(f"{module:32s} {wall:7.0f} {own + children:7.0f} {children:16.0f}")
    wall, own, children = (sum(row[1][k] for row in rows) for k in range(3))
    write(f"{'all ' + str(len(rows)) + ' modules':32s} {wall:7.0f} {own + children:7.0f} {children:16.0f}")
