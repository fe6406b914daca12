"""Facial muscles on a face mesh (thesis section 3.1.2): the muscle file, its checks,
and the resolved :class:`MuscleSet` of arrays the model is built from.

A linear muscle (Waters; Zhang et al.) runs from its attachment O, on bone, to its
insertion I, in the skin. Its region of influence is the sector of angle ``zone`` around
O->I (eq. 3.2), with radial falloff out to ``r`` and ``r_max`` (eq. 3.3), both given as
multiples of the muscle length |OI| so that one file fits faces of any size. Points are
landmark indices or 3D points (cm) snapped to the nearest vertex, so a mesh of another
topology can carry the same muscles.

Attachments are pinned (the single-layer face has no skull to hold them), and so is the
outer rim of the mask: without it the mask drifts as a whole under the muscle pull.
"""

from __future__ import annotations

import re
from dataclasses import dataclass
from pathlib import Path
from typing import Literal

import numpy as np
from pydantic import Field, field_validator, model_validator

from .config import MIDLINE_FRACTION, SNAP_FRACTION
from .errors import InputError
from .mesh import FaceMesh
from .schema import Strict, load_model

Point = int | tuple[float, float, float]
NAME = re.compile(r"^[a-z][a-z0-9_]*$")


class MuscleDefaults(Strict):
    zone: float = Field(40.0, gt=0, le=180, description="angular zone α of eq. 3.2, degrees")
    falloff: tuple[float, float] = Field((1.0, 1.5), description="r and r_max of eq. 3.3, in muscle lengths")
    force: float = Field(30.0, gt=0, description="peak force f of eq. 3.1 at full activation")


class MuscleEntry(Strict):
    name: str
    kind: Literal["linear"]
    attachment: Point
    insertion: Point
    zone: float | None = Field(None, gt=0, le=180)
    falloff: tuple[float, float] | None = None
    force: float | None = Field(None, gt=0)

    @field_validator("name")
    @classmethod
    def _snake_case(cls, name: str) -> str:
        if not NAME.match(name):
            raise ValueError("must be snake_case (lower-case letters, digits, underscores)")
        return name

    @field_validator("falloff")
    @classmethod
    def _ordered(cls, falloff):
        if falloff is not None and not 0 < falloff[0] <= falloff[1]:
            raise ValueError("must be [r, r_max] with 0 < r <= r_max")
        return falloff


class Pinned(Strict):
    boundary: Literal["outer", "none"] = "outer"
    vertices: list[int] = []


class MuscleFile(Strict):
    units: Literal["cm"] = "cm"
    defaults: MuscleDefaults = MuscleDefaults()
    pinned: Pinned = Pinned()
    muscles: list[MuscleEntry]

    @model_validator(mode="after")
    def _unique_names(self):
        seen = set()
        for m in self.muscles:
            if m.name in seen:
                raise ValueError(f"duplicate muscle name {m.name!r}")
            seen.add(m.name)
        return self

    @field_validator("defaults")
    @classmethod
    def _defaults_ordered(cls, d: MuscleDefaults) -> MuscleDefaults:
        MuscleEntry._ordered(d.falloff)
        return d


@dataclass(frozen=True)
class MuscleSet:
    """Muscles resolved onto a mesh. Arrays are indexed by muscle.

    attachment, insertion : (M,) int64 vertex indices; zone : (M,) radians;
    falloff : (M, 2) r and r_max in muscle lengths; force : (M,); pinned : (p,) int64.
    """

    names: tuple[str, ...]
    attachment: np.ndarray
    insertion: np.ndarray
    zone: np.ndarray
    falloff: np.ndarray
    force: np.ndarray
    pinned: np.ndarray
    source: str = ""

    @property
    def count(self) -> int:
        return len(self.names)

    def index(self, name: str) -> int:
        return self.names.index(name)


def _snap(point: Point, mesh: FaceMesh, where: str) -> int:
    if isinstance(point, int):
        if not 0 <= point < mesh.vertex_count:
            raise InputError(f"{where}: vertex {point} does not exist (mesh has {mesh.vertex_count})")
        return point
    distance = np.linalg.norm(mesh.vertices - np.asarray(point), axis=1)
    nearest = int(np.argmin(distance))
    if distance[nearest] > SNAP_FRACTION * mesh.scale:
        raise InputError(f"{where}: point {list(point)} is {distance[nearest]:.2f} cm from the surface")
    return nearest


def _check_side(name: str, x: tuple[float, float], width: float, where: str) -> None:
    tolerance = MIDLINE_FRACTION * width
    side = "left" if name.endswith("_l") else "right" if name.endswith("_r") else "midline"
    ok = {
        "left": all(v > tolerance for v in x),
        "right": all(v < -tolerance for v in x),
        "midline": all(abs(v) <= tolerance for v in x),
    }[side]
    if not ok:
        hint = "+x" if side == "left" else "-x" if side == "right" else "x = 0"
        raise InputError(
            f"{where}: named for the {side} side but its points lie at x = {x[0]:.2f}, {x[1]:.2f} "
            f"(the subject's {side} is {hint})"
        )


def resolve_muscles(spec: MuscleFile, mesh: FaceMesh, source: str = "muscles") -> MuscleSet:
    """Check a muscle file against a mesh and resolve it to arrays."""
    width = float(np.ptp(mesh.vertices[:, 0]))
    attachment, insertion, zone, falloff, force = [], [], [], [], []
    for m in spec.muscles:
        where = f"{source}: muscle {m.name}"
        o = _snap(m.attachment, mesh, f"{where}: attachment")
        i = _snap(m.insertion, mesh, f"{where}: insertion")
        if np.linalg.norm(mesh.vertices[o] - mesh.vertices[i]) <= 0:
            raise InputError(f"{where}: zero length (attachment and insertion are the same point)")
        _check_side(m.name, (mesh.vertices[o, 0], mesh.vertices[i, 0]), width, where)
        attachment.append(o)
        insertion.append(i)
        zone.append(np.radians(m.zone or spec.defaults.zone))
        falloff.append(m.falloff or spec.defaults.falloff)
        force.append(m.force or spec.defaults.force)
    for v in spec.pinned.vertices:
        _snap(v, mesh, f"{source}: pinned")
    pinned = set(attachment) | set(spec.pinned.vertices)
    if spec.pinned.boundary == "outer":
        if not mesh.boundary_loops:
            raise InputError(f"{source}: pinned: the mesh has no boundary to pin (a closed head?)")
        pinned |= set(mesh.boundary_loops[0].tolist())
    return MuscleSet(
        names=tuple(m.name for m in spec.muscles),
        attachment=np.array(attachment, dtype=np.int64),
        insertion=np.array(insertion, dtype=np.int64),
        zone=np.array(zone, dtype=np.float64),
        falloff=np.array(falloff, dtype=np.float64).reshape(-1, 2),
        force=np.array(force, dtype=np.float64),
        pinned=np.array(sorted(pinned), dtype=np.int64),
        source=source,
    )


def load_muscles(path: str | Path, mesh: FaceMesh) -> MuscleSet:
    path = Path(path)
    return resolve_muscles(load_model(path, MuscleFile), mesh, source=str(path))


def muscles_as_points(spec: MuscleFile, mesh: FaceMesh) -> MuscleFile:
    """The same muscle file with every landmark index replaced by that vertex's position
    on ``mesh``: muscles carried by position to a mesh of another topology (a subdivided
    face, a scan), where they snap to the nearest vertex."""
    def point(p: Point) -> Point:
        return tuple(float(c) for c in mesh.vertices[p]) if isinstance(p, int) else p

    muscles = [m.model_copy(update={"attachment": point(m.attachment), "insertion": point(m.insertion)}) for m in spec.muscles]
    return spec.model_copy(update={"muscles": muscles, "pinned": spec.pinned.model_copy(update={"vertices": []})})
