"""The skin's material as files give it: ``material:`` in a spec or a muscle file, its
presets, and the muscle file's material under the spec's (``over_muscle_file``). Checked
here (pydantic, one-line errors); the physics takes the plain numbers
(facesim.physics.material.Material).
"""

from __future__ import annotations

from typing import Literal

from pydantic import Field, model_validator

from ..physics.material import Material
from ..physics.mesh import FaceMesh
from ..physics.model import Model, build_model
from ..physics.muscles import MuscleSet
from ..schema import Strict

_DEFAULT = Material()

#: Material presets: the fields a preset sets where a spec leaves them out. ``thesis``
#: reproduces the thesis's model for its tables in BENCHMARKS.md: its update, eq.
#: 3.14-3.20, at four steps per frame, and no bending. The hypodermis stays: without it
#: the thesis's update folds happy at Table 3.3's longest step (Δt = 0.015 s; measured).
#: ``facesim`` is the defaults below.
PRESETS = {
    "facesim": {},
    "thesis": dict(solver="quasi-implicit", bending=0.0, regions="moving"),
}


class MaterialSpec(Strict):
    """The material as a spec or a muscle file gives it (``material:``), each field
    facesim.physics.material.Material's, checked. ``preset`` fills the fields a spec does
    not give (``PRESETS``); fields given win."""

    preset: Literal["facesim", "thesis"] = Field("facesim", description="facesim: the defaults below; thesis: the "
                                                 "thesis's model (quasi-implicit update, no bending, regions at the moving skin)")
    mass: float = Field(_DEFAULT.mass, gt=0, description="point mass m of every vertex")
    stiffness: float = Field(_DEFAULT.stiffness, gt=0, description="spring stiffness k0, eq. 3.6 and 3.7")
    nonlinearity: float = Field(_DEFAULT.nonlinearity, ge=0, description="spring non-linearity γ, eq. 3.6")
    repulsion_nonlinearity: float = Field(_DEFAULT.repulsion_nonlinearity, ge=0, description="edge-repulsion non-linearity ζ, eq. 3.7")
    damping: float = Field(_DEFAULT.damping, ge=0, description="viscous damping c, eq. 3.10")
    tissue: float = Field(_DEFAULT.tissue, ge=0, description="hypodermis springs tying skin to bone (not in the thesis, where it is 0)")
    drive: float = Field(_DEFAULT.drive, ge=0, description="stiffness driving the lips and lid contours to the targets of the jaw and eyelids (facesim.physics.rig)")
    solver: Literal["implicit", "quasi-implicit"] = Field(
        _DEFAULT.solver, description="implicit: the linearised backward-Euler step with the whole stiffness, solved by "
        "conjugate gradients (facesim.physics.solver); quasi-implicit: the thesis's per-vertex update, eq. 3.14-3.20")
    substeps: int | None = Field(None, ge=1, le=1000, description="integration steps per frame (each Δt / substeps); "
                                 "default 1 for the implicit solver, 4 for the quasi-implicit")
    iterations: int = Field(_DEFAULT.iterations, ge=1, le=10000, description="most conjugate-gradient iterations per implicit step")
    tolerance: float = Field(_DEFAULT.tolerance, gt=0, lt=1, description="the implicit step's conjugate gradients stop when the "
                             "residual has fallen by this factor")
    bending: float = Field(_DEFAULT.bending, ge=0, description="bending stiffness k_b of the skin's displacement (facesim.physics.bending; "
                           "not in the thesis, where it is 0)")
    edge_repulsion: bool = Field(_DEFAULT.edge_repulsion, description="edge repulsion (eq. 3.7); off reproduces the thesis's fig. 3.16")
    uv_projection: bool = Field(_DEFAULT.uv_projection, description="muscle forces in the 2D projection (eq. 3.21-3.25); off: in 3D")
    regions: Literal["attached", "moving"] = Field(
        _DEFAULT.regions, description="where the muscles' falloff (eq. 3.2-3.4) and regions (section 3.3) are evaluated: "
        "attached: where the bones hold the skin (facesim.physics.muscle_forces); moving: at the moving skin, as the thesis")

    @model_validator(mode="before")
    @classmethod
    def _preset(cls, data):
        if isinstance(data, dict) and data.get("preset") in PRESETS:
            return {**PRESETS[data["preset"]], **data}
        return data

    @model_validator(mode="after")
    def _bending_needs_the_whole_stiffness(self):
        if self.solver == "quasi-implicit" and self.bending > 0:
            raise ValueError("bending needs solver: implicit (the quasi-implicit update of eq. 3.19 keeps one stiffness "
                             "per vertex, and a hinge's couples four: measured, happy runs away at bending 60 with 16 "
                             "steps per frame); give bending: 0 with it, or preset: thesis")
        return self

    def physical(self) -> Material:
        """The material's numbers, for facesim.physics.model.build_model."""
        return Material(**self.model_dump(exclude={"preset"}))


def over_muscle_file(material: MaterialSpec, muscles: MuscleSet) -> Material:
    """``material`` over the one the muscle file says its forces were set on
    (``material:`` in the file), as the physics takes it: the fields ``material`` was
    given, and its preset's, win. The Hopper face's file keeps the thesis's skin its
    forces were chosen on."""
    if muscles.material:
        given = material.model_dump(exclude_unset=True)
        material = MaterialSpec.model_validate({**dict(muscles.material), **PRESETS[material.preset], **given})
    return material.physical()


def face_model(mesh: FaceMesh, muscles: MuscleSet, material: MaterialSpec = MaterialSpec(), reorder: bool | None = None) -> Model:
    """facesim.physics.model.build_model with a material as files give it, over the muscle
    file's (``over_muscle_file``): the model a spec runs."""
    return build_model(mesh, muscles, over_muscle_file(material, muscles), reorder)
