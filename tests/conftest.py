"""Shared fixtures: the default face, its muscles, models and expression specs."""

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
