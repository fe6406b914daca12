"""Expression specs: which muscles contract, how strongly, over how many frames, at what
time step. A spec is a YAML file validated by pydantic (unknown fields are errors):

    name: happy                 # optional; the file name by default
    frames: 35                  # frames of animation, one per Δt (thesis Table 3.1)
    dt: 0.01                    # Δt per frame, seconds
    onset: 10                   # frames over which activations ease in (Parke's cosine)
    activations:                # muscle: activation in [0, 1]
      zygomaticus_major_l: 1.0
    material: {damping: 20}     # optional overrides of facesim.model.Material
    mesh: my_face.obj           # optional, relative to the spec (default: meshes/face.obj)
    muscles: my_face.muscles.yaml

``load_spec`` checks the file alone; ``activation_table`` checks the muscle names against
the muscle file and turns the spec into a (frames, muscles) table once, before simulation.
"""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import numpy as np
from pydantic import Field, PrivateAttr

from .config import DEFAULT_MESH, DEFAULT_MUSCLES
from .errors import InputError
from .model import Material
from .muscles import MuscleSet
from .schema import Strict, load_model

Activation = Annotated[float, Field(ge=0.0, le=1.0)]
#: More frames than this is taken for a typo: 100k frames is over an hour at 25 fps.
MAX_FRAMES = 100_000


class Spec(Strict):
    name: str | None = Field(None, min_length=1)
    description: str = ""
    frames: int = Field(35, ge=1, le=MAX_FRAMES)
    dt: float = Field(0.01, gt=0, le=1.0)
    onset: int = Field(10, ge=0, description="frames to ease activations in; 0 for a step")
    fps: float = Field(25.0, gt=0, le=240, description="playback rate of the rendered video")
    activations: dict[str, Activation] = Field(default_factory=dict)
    material: Material = Material()
    mesh: Path | None = None
    muscles: Path | None = None
    _source: Path | None = PrivateAttr(None)

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
        return self._relative(self.muscles, DEFAULT_MUSCLES)

    def with_overrides(self, **changes) -> "Spec":
        """A copy with fields replaced (used by the CLI's --mesh, --muscles)."""
        spec = self.model_copy(update={k: v for k, v in changes.items() if v is not None})
        spec._source = self._source
        return spec


def load_spec(path: str | Path) -> Spec:
    """Read and validate an expression spec (one-line InputError on any problem)."""
    path = Path(path)
    spec = load_model(path, Spec)
    spec._source = path
    return spec


def activation_table(spec: Spec, muscles: MuscleSet) -> np.ndarray:
    """(frames, muscles) activations: each muscle eases in over ``onset`` frames with
    Parke's cosine and holds. Unknown muscle names are an error."""
    table = np.zeros((spec.frames, muscles.count))
    frame = np.arange(1, spec.frames + 1)
    ease = np.ones(spec.frames) if spec.onset == 0 else 0.5 - 0.5 * np.cos(np.pi * np.minimum(frame / spec.onset, 1.0))
    for name, value in spec.activations.items():
        if name not in muscles.names:
            raise InputError(f"{spec.source}: activations -> {name}: unknown muscle (see `facesim muscles`)")
        table[:, muscles.index(name)] = value * ease
    return table
