"""Shared fixtures: the default face, its muscles, models and expression specs; waiting
on a condition (never a fixed sleep) for the tests that signal a running process."""

import os
import time
from pathlib import Path

import numpy as np
import pytest

import facesim
from facesim.config import DEFAULT_MESH, DEFAULT_MUSCLES
from facesim.mesh import load_mesh
from facesim.muscles import load_muscles
from facesim.simulate import model_for

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
    s = spec(name)
    return s.material.model_copy(update=changes)


@pytest.fixture(scope="session")
def model():
    return model_for(spec("happy"))


@pytest.fixture()
def rng():
    return np.random.default_rng(20261122)
