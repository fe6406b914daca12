"""The skin's material: the mass-spring-damper parameters of thesis section 3.1.3, given
per vertex of the default face, and the same parameters per vertex of a mesh of another
resolution (``resolved_material``; why each scales as it does: facesim.physics.model).

Plain numbers: what a file may say and how it is checked is facesim.face.material's
``MaterialSpec``, which makes one of these.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace
from typing import Literal

import numpy as np

#: Steps per frame by default, per solver: the implicit step is stable at one (issue 15's
#: apex test against the quasi-implicit); the thesis's update needs four on the default face.
SUBSTEPS = {"implicit": 1, "quasi-implicit": 4}


@dataclass(frozen=True)
class Material:
    """Mass-spring-damper parameters (thesis section 3.1.3).

    mass : point mass m of every vertex; stiffness : spring stiffness k0, eq. 3.6 and 3.7;
    nonlinearity : spring non-linearity γ, eq. 3.6; repulsion_nonlinearity : edge-repulsion
    non-linearity ζ, eq. 3.7; damping : viscous damping c, eq. 3.10; tissue : hypodermis
    springs tying skin to bone (not in the thesis, where it is 0); drive : stiffness
    driving the lips and lid contours to the jaw's and eyelids' targets (facesim.physics.rig);
    solver : implicit (the linearised backward-Euler step, facesim.physics.solver) or
    quasi-implicit (the thesis's per-vertex update, eq. 3.14-3.20); substeps : steps per
    frame (None: ``SUBSTEPS`` of the solver); iterations, tolerance : the implicit step's
    conjugate gradients; bending : bending stiffness k_b of the skin's displacement
    (facesim.physics.bending; not in the thesis); edge_repulsion : eq. 3.7 on or off;
    uv_projection : muscle forces in the 2D projection of eq. 3.21-3.25, or in 3D;
    regions : where the muscles' falloff and regions are evaluated, attached (where the
    bones hold the skin) or moving (at the moving skin, as the thesis).
    """

    mass: float = 1.0
    stiffness: float = 1000.0
    nonlinearity: float = 5.0
    repulsion_nonlinearity: float = 5.0
    damping: float = 40.0
    tissue: float = 300.0
    drive: float = 20000.0
    solver: Literal["implicit", "quasi-implicit"] = "implicit"
    substeps: int | None = None
    iterations: int = 60
    tolerance: float = 1e-3
    bending: float = 100.0
    edge_repulsion: bool = True
    uv_projection: bool = True
    regions: Literal["attached", "moving"] = "attached"


#: The longest integration step (s) the material is calibrated for: the thesis's Δt
#: (its Table 3.1). A longer frame (a spec in real time at 25 fps: 40 ms) is split into as
#: many more steps: at 40 ms a step, happy's zygomatics with the inner brows raised, held,
#: kept a limit cycle of 0.7 mm that never came to rest (at 10 ms it settles).
LONGEST_STEP = 0.01


def steps_per_frame(material: Material, dt: float) -> int:
    """Integration steps per frame of ``dt`` seconds: the material's substeps, times as
    many as it takes to keep each step within LONGEST_STEP."""
    return material.substeps * max(1, math.ceil(dt / LONGEST_STEP - 1e-9))


def resolved_material(material: Material, resolution: float) -> Material:
    """The material per vertex on a mesh of resolution scale s (facesim.physics.model)."""
    s = resolution
    substeps = material.substeps or SUBSTEPS[material.solver]
    if material.solver == "quasi-implicit":  # an explicit update: stable only as its fastest spring allows
        substeps = max(substeps, round(substeps / np.sqrt(s)))
    return replace(material, mass=material.mass * s, damping=material.damping * np.sqrt(s), tissue=material.tissue * s,
                   drive=material.drive * s, substeps=substeps)
