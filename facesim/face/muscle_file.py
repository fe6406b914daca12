"""The muscle file: its schema and checks, and its muscles placed on a face mesh as a
facesim.physics.muscles.MuscleSet (``resolve_muscles``).

The file also names the bone-driven parts of the face (facesim.physics.rig): the jaw's
hinge and the lips that do and do not follow it, and each eye's upper and lower lid
contours. They are driven like muscles, by activations named ``jaw`` and ``eyelid_r`` /
``eyelid_l``.

Points are landmark indices or 3D points (cm) snapped to the nearest vertex, so a mesh of
another topology can carry the same file. Attachments are pinned (the single-layer face has
no skull to hold them; a head whose skin the hypodermis holds may unpin them, ``Pinned``),
and so is the outer rim of the mask: without it the mask drifts as a whole under the
muscle pull.
"""

from __future__ import annotations

import re
from pathlib import Path
from typing import Annotated, Any, Literal, Union

import numpy as np
from pydantic import Field, StrictInt, field_validator, model_validator

from ..config import MIDLINE_FRACTION, SNAP_FRACTION
from ..errors import InputError
from ..physics.mesh import FaceMesh
from ..physics.muscles import (
    GAZE,
    JAW_CONTROLS,
    LINEAR,
    PUFF_PRESSURE,
    PUPIL,
    SPHINCTER,
    TONGUE,
    EyelidRig,
    JawRig,
    MuscleSet,
)
from ..physics.rig import jaw_forward
from ..schema import Strict, load_model
from .head import HeadMesh

#: A landmark: a vertex index (an integer: YAML's ``true`` is not vertex 1) or a 3D point.
Point = Annotated[StrictInt, Field(ge=0)] | tuple[float, float, float]


NAME = re.compile(r"^[a-z][a-z0-9_]*$")


class MuscleDefaults(Strict):
    zone: float = Field(40.0, gt=0, le=180, description="angular zone α of eq. 3.2, degrees")
    falloff: tuple[float, float] = Field((1.0, 1.5), description="r and r_max of eq. 3.3, in muscle lengths")
    force: float = Field(30.0, gt=0, description="peak force f of eq. 3.1 at full activation")


def _snake_case(name: str) -> str:
    if not NAME.match(name):
        raise ValueError("must be snake_case (lower-case letters, digits, underscores)")
    return name


def _ordered(falloff):
    if falloff is not None and not 0 < falloff[0] <= falloff[1]:
        raise ValueError("must be [r, r_max] with 0 < r <= r_max")
    return falloff


class _Muscle(Strict):
    name: str
    falloff: tuple[float, float] | None = None
    force: float | None = Field(None, gt=0)
    protrusion: float = Field(0.0, ge=-20, le=20, description="the push of its contraction along the skin's rest normal, "
                              "per unit of its pull: outward (a pout) or, negative, inward (a cheek pressed to the teeth)")

    _names = field_validator("name")(_snake_case)
    _falloff = field_validator("falloff")(_ordered)


class MuscleEntry(_Muscle):
    kind: Literal["linear"]
    attachment: Point
    insertion: Point
    zone: float | None = Field(None, gt=0, le=180)


class SphincterEntry(_Muscle):
    """A ring muscle: ``centre`` is the mean of its points, ``ring`` the points the
    ellipse is fitted to (``falloff`` in ring radii; default [1, 1.5])."""

    kind: Literal["sphincter"]
    centre: list[Point] = Field(..., min_length=1)
    ring: list[Point] = Field(..., min_length=4)


class _Contours(Strict):
    """Upper and lower points paired in order, upper over lower: a part's contacts."""

    upper: list[Point] = Field(..., min_length=1)
    lower: list[Point] = Field(..., min_length=1)

    @model_validator(mode="after")
    def _paired(self):
        if len(self.upper) != len(self.lower):
            raise ValueError(f"upper ({len(self.upper)} points) and lower ({len(self.lower)}) must pair up")
        return self


class Jaw(_Contours):
    """The mandible: a rotation about the hinge axis through two points (the
    temporomandibular joints), ``max_angle`` degrees at activation 1, and a glide of its
    condyles along the articular eminence: forward by ``protrusion`` cm (FACS AU29, jaw
    thrust, driven by the control ``jaw_thrust``) and sideways by ``excursion`` cm (AU30,
    ``jaw_sideways_l`` toward the subject's left, ``jaw_sideways_r`` the right). ``lower`` points
    follow it fully, ``upper`` points stay with the skull; the rest of the face follows
    with a weight interpolated smoothly between them (facesim.physics.rig). The two lists pair
    up, upper over lower: the lips' contacts, which meet across a plane turned
    ``contact_tilt`` degrees from the horizontal, its normal leaning back (facesim.physics.rig):
    the lower lip pushed up slides forward over the upper one. The joints lie
    ``hinge_depth`` behind the two hinge points (a fraction of the distance between them,
    straight back in the horizontal plane): named by landmark, the points are on the
    skin, where a face's contour passes the joints' height, and the condyles sit deeper,
    in front of the ears."""

    hinge: tuple[Point, Point]
    hinge_depth: float = Field(0.0, ge=0, le=0.5, description="how far behind the hinge points the temporomandibular "
                               "joints lie, as a fraction of the distance between the points (0: at them)")
    max_angle: float = Field(20.0, gt=0, le=45)
    # a grown mandible protrudes 7-10 mm and moves 8-12 mm to either side (clinical
    # norms); ICT's jawForward carries the lower incisors 9 mm, its jawLeft 7.4 mm
    protrusion: float = Field(0.9, ge=0, le=2, description="cm the jaw glides forward at jaw_thrust 1 (AU29)")
    excursion: float = Field(0.75, ge=0, le=2, description="cm the jaw glides sideways at jaw_sideways_l/_r 1 (AU30)")
    puff_pressure: float = Field(PUFF_PRESSURE, ge=0, description="the air pressure in the closed mouth (force per cm²) "
                                 "at cheek_puff_l/_r 1 (AU34), pushing the cheeks out (facesim.physics.pressure)")
    contact_tilt: float = Field(0.0, ge=0, lt=90, description="degrees the plane the closed lips meet across "
                                "turns from the horizontal, its front edge up (0: the upper lip only ever above the "
                                "lower); 50 matches ICT's chin raiser and lip press on the default head (REALISM.md)")


class Eyelid(_Contours):
    """One eye's lids: the upper and lower contour points, paired from one eye corner to
    the other. ``reach`` is how far around the opening the skin follows the lids, in eye
    widths."""

    name: str
    reach: float = Field(0.45, gt=0, le=2)
    levator: str | None = Field(None, description="name of the control raising the upper lid (the levator "
                                   "palpebrae superioris, AU5), if the face has one")
    levator_angle: float = Field(12.5, gt=0, le=30, description="degrees the upper lid's middle turns up over the "
                                 "eyeball at the levator's full activation (its ends at the eye corners stay); 12.5 "
                                 "matches ICT's eyeWide on the default head (REALISM.md, AU5)")

    _names = field_validator("name")(_snake_case)

    @field_validator("levator")
    @classmethod
    def _levator_name(cls, value):
        return None if value is None else _snake_case(value)


class Pinned(Strict):
    """Vertices held where the bones put them: the mask's outer rim, listed vertices, and
    (``attachments``, the thesis's face) each linear muscle's attachment. A head's skin is
    tied to the skull everywhere by the hypodermis (facesim.physics.material.Material.tissue), so
    its attachments need no pin, and unpinned they let the skin over the cheekbone and
    the brow move under other muscles (a cheek raiser lifts the zygomaticus's origin).

    ``boundary``: the outer rim pinned (``outer``, the thesis's face), free (``none``), or
    ``tied``: held where the bones put it by springs of stiffness ``tie`` (the units of
    Material.tissue) on top of the hypodermis, standing for the skin beyond the cut (the
    scalp over the galea, the neck), which gives a little: ICT's brow raiser and lowerer
    move the forehead's top edge 3 mm, which a pinned rim cannot (a crease), while a free
    one lets the inner brow raiser drag the whole forehead."""

    boundary: Literal["outer", "tied", "none"] = "outer"
    tie: float = Field(0.0, ge=0, description="stiffness tying a tied rim's vertices to the bones")
    vertices: list[int] = []
    attachments: bool = True

    @model_validator(mode="after")
    def _tie_with_a_tied_rim(self):
        if (self.boundary == "tied") != (self.tie > 0):
            raise ValueError(f"tie: expected a positive stiffness with boundary: tied and none otherwise, "
                             f"got tie {self.tie:g} with boundary {self.boundary}")
        return self


class MuscleFile(Strict):
    units: Literal["cm"] = "cm"
    material: dict[str, Any] = Field({}, description="the material (facesim.physics.material.Material's fields) the forces were "
                                     "set on; a spec's material and its preset win over it")
    defaults: MuscleDefaults = MuscleDefaults()
    pinned: Pinned = Pinned()
    muscles: list[Annotated[Union[MuscleEntry, SphincterEntry], Field(discriminator="kind")]]
    jaw: Jaw | None = None
    eyelids: list[Eyelid] = []

    @model_validator(mode="after")
    def _unique_names(self):
        seen = set(JAW_CONTROLS + TONGUE) if self.jaw else set()
        levators = [e.levator for e in self.eyelids if e.levator]
        for name in [m.name for m in self.muscles] + [e.name for e in self.eyelids] + levators:
            if name in seen:
                raise ValueError(f"duplicate name {name!r}")
            seen.add(name)
        return self

    @field_validator("defaults")
    @classmethod
    def _defaults_ordered(cls, d: MuscleDefaults) -> MuscleDefaults:
        _ordered(d.falloff)
        return d


def _snap(point: Point, mesh: FaceMesh, where: str, below: int | None = None) -> int:
    """A landmark index checked, or the vertex nearest a 3D point; with ``below``, the
    nearest of the vertices lower than that one (a lower lip or lid under its partner,
    which on a mesh of another topology may be the nearer vertex to both points)."""
    if isinstance(point, int):
        if not 0 <= point < mesh.vertex_count:
            raise InputError(f"{where}: vertex {point} does not exist (mesh has {mesh.vertex_count})")
        return point
    distance = np.linalg.norm(mesh.vertices - np.asarray(point), axis=1)
    if below is not None:
        distance[mesh.vertices[:, 1] >= mesh.vertices[below, 1]] = np.inf
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


def _upper_over_lower(mesh: FaceMesh, upper: np.ndarray, lower: np.ndarray, where: str) -> None:
    below = np.flatnonzero(mesh.vertices[upper, 1] <= mesh.vertices[lower, 1])
    if len(below):
        k = below[0]
        raise InputError(f"{where}: upper point {k} (vertex {upper[k]}) does not lie above its lower partner (vertex {lower[k]})")


def resolve_muscles(spec: MuscleFile, mesh: FaceMesh, source: str = "muscles") -> MuscleSet:
    """Check a muscle file against a mesh and resolve it to arrays."""
    width = float(np.ptp(mesh.vertices[:, 0]))
    kind, attachment, insertion, centres, rings, zone, falloff, force, protrusion = [], [], [], [], [], [], [], [], []
    for m in spec.muscles:
        where = f"{source}: muscle {m.name}"
        if m.kind == "linear":
            o = _snap(m.attachment, mesh, f"{where}: attachment")
            i = _snap(m.insertion, mesh, f"{where}: insertion")
            if np.linalg.norm(mesh.vertices[o] - mesh.vertices[i]) <= 0:
                raise InputError(f"{where}: zero length (attachment and insertion are the same point)")
            _check_side(m.name, (mesh.vertices[o, 0], mesh.vertices[i, 0]), width, where)
            kind.append(LINEAR)
            attachment.append(o)
            insertion.append(i)
            centres.append([o])
            rings.append(np.zeros(0, dtype=np.int64))
            zone.append(np.radians(m.zone or spec.defaults.zone))
            falloff.append(m.falloff or spec.defaults.falloff)
        else:
            centre = [_snap(p, mesh, f"{where}: centre") for p in m.centre]
            ring = np.array([_snap(p, mesh, f"{where}: ring") for p in m.ring], dtype=np.int64)
            if len(set(ring.tolist())) < 4:
                raise InputError(f"{where}: ring: needs at least 4 distinct vertices")
            middle = mesh.vertices[centre].mean(axis=0)
            _check_side(m.name, (middle[0], middle[0]), width, where)
            kind.append(SPHINCTER)
            attachment.append(-1)
            insertion.append(int(ring[0]))
            centres.append(centre)
            rings.append(ring)
            zone.append(np.pi)
            falloff.append(m.falloff or (1.0, 1.5))
        protrusion.append(m.protrusion)
        force.append(m.force or spec.defaults.force)
    for v in spec.pinned.vertices:
        _snap(v, mesh, f"{source}: pinned")
    pinned = {a for a in attachment if a >= 0 and spec.pinned.attachments} | set(spec.pinned.vertices)
    tied = np.zeros(0, dtype=np.int64)
    if spec.pinned.boundary != "none":
        if not mesh.boundary_loops:
            raise InputError(f"{source}: pinned: the mesh has no boundary to {'pin' if spec.pinned.boundary == 'outer' else 'tie'} (a closed head?)")
        if spec.pinned.boundary == "outer":
            pinned |= set(mesh.boundary_loops[0].tolist())
        else:
            tied = np.setdiff1d(mesh.boundary_loops[0], sorted(pinned)).astype(np.int64)
    for m, k, i in zip(spec.muscles, kind, insertion):
        if k == LINEAR and i in pinned:
            raise InputError(f"{source}: muscle {m.name}: insertion: vertex {i} is pinned (the rim, or an attachment) "
                             "and would never move; expected a vertex of free skin")
    jaw, controls = None, []
    if spec.jaw is not None:
        where = f"{source}: jaw"
        hinge = np.array([mesh.vertices[_snap(p, mesh, f"{where}: hinge")] if isinstance(p, int) else p
                          for p in spec.jaw.hinge], dtype=np.float64)  # a point may lie inside the head
        span = float(np.linalg.norm(hinge[1] - hinge[0]))
        if span < 0.1 * width:
            raise InputError(f"{where}: hinge: its two points must lie on either side of the face")
        hinge = hinge - spec.jaw.hinge_depth * span * jaw_forward((hinge[1] - hinge[0]) / span)
        upper = np.array([_snap(p, mesh, f"{where}: upper") for p in spec.jaw.upper], dtype=np.int64)
        lower = np.array([_snap(p, mesh, f"{where}: lower", below=u) for p, u in zip(spec.jaw.lower, upper)], dtype=np.int64)
        _upper_over_lower(mesh, upper, lower, where)
        jaw = JawRig(hinge, lower, upper, float(np.radians(spec.jaw.max_angle)), float(np.radians(spec.jaw.contact_tilt)),
                     spec.jaw.protrusion, spec.jaw.excursion, spec.jaw.puff_pressure)
        controls += JAW_CONTROLS + (TONGUE if isinstance(mesh, HeadMesh) else ())  # a head's tongue rides the mandible
    eyelids = []
    for lid in spec.eyelids:
        where = f"{source}: eyelid {lid.name}"
        upper = np.array([_snap(p, mesh, f"{where}: upper") for p in lid.upper], dtype=np.int64)
        lower = np.array([_snap(p, mesh, f"{where}: lower", below=u) for p, u in zip(lid.lower, upper)], dtype=np.int64)
        middle = mesh.vertices[np.concatenate([upper, lower])].mean(axis=0)
        _check_side(lid.name, (middle[0], middle[0]), width, where)
        _upper_over_lower(mesh, upper, lower, where)
        gaze = tuple(f"{g}_{lid.name[-1]}" for g in GAZE)  # the name's side: _check_side held it to it
        if any(g in controls for g in gaze):
            raise InputError(f"{where}: a second eyelid on the subject's {'left' if lid.name[-1] == 'l' else 'right'}")
        eyelids.append(EyelidRig(lid.name, upper, lower, lid.reach, lid.levator, float(np.radians(lid.levator_angle)), gaze))
        controls += [lid.name] + ([lid.levator] if lid.levator else []) + list(gaze) + [f"{PUPIL}_{lid.name[-1]}"]
    centre_start = np.cumsum([0] + [len(c) for c in centres]).astype(np.int64)
    return MuscleSet(
        names=tuple(m.name for m in spec.muscles) + tuple(controls),
        kind=np.array(kind, dtype=np.int64),
        attachment=np.array(attachment, dtype=np.int64),
        insertion=np.array(insertion, dtype=np.int64),
        centre_start=centre_start,
        centre_index=np.array([v for c in centres for v in c], dtype=np.int64),
        ring=tuple(rings),
        zone=np.array(zone, dtype=np.float64),
        falloff=np.array(falloff, dtype=np.float64).reshape(-1, 2),
        force=np.array(force, dtype=np.float64),
        protrusion=np.array(protrusion, dtype=np.float64),
        pinned=np.array(sorted(pinned), dtype=np.int64),
        tied=tied,
        tie=float(spec.pinned.tie) if len(tied) else 0.0,
        jaw=jaw,
        eyelids=tuple(eyelids),
        source=source,
        material=_material_fields(spec.material, source),
    )


def _material_fields(fields: dict, source: str) -> tuple:
    """A muscle file's material, checked as a spec's (facesim.face.material.MaterialSpec)."""
    from pydantic import ValidationError

    from .material import MaterialSpec

    try:
        MaterialSpec.model_validate(fields)
    except ValidationError as error:
        first = error.errors()[0]
        raise InputError(f"{source}: material -> {' -> '.join(map(str, first['loc']))}: {first['msg']}") from None
    return tuple(sorted(fields.items()))


def load_muscles(path: str | Path, mesh: FaceMesh, source: str | None = None) -> MuscleSet:
    """Read a muscle file and resolve it on ``mesh``; errors name ``source`` (the path)."""
    path = Path(path)
    return resolve_muscles(load_model(path, MuscleFile), mesh, source=source or str(path))


def muscles_as_points(spec: MuscleFile, mesh: FaceMesh) -> MuscleFile:
    """The same muscle file with every landmark index replaced by that vertex's position
    on ``mesh``: muscles, jaw and eyelids carried by position to a mesh of another
    topology (a subdivided face, a scan), where they snap to the nearest vertex."""
    def point(p: Point) -> Point:
        return tuple(float(c) for c in mesh.vertices[p]) if isinstance(p, int) else p

    def carried(entry, *fields):
        return entry.model_copy(update={f: [point(p) for p in getattr(entry, f)] for f in fields})

    muscles = [m.model_copy(update={"attachment": point(m.attachment), "insertion": point(m.insertion)})
               if m.kind == "linear" else carried(m, "centre", "ring") for m in spec.muscles]
    jaw = spec.jaw and carried(spec.jaw, "lower", "upper").model_copy(update={"hinge": tuple(point(p) for p in spec.jaw.hinge)})
    return spec.model_copy(update={
        "muscles": muscles, "jaw": jaw, "eyelids": [carried(e, "upper", "lower") for e in spec.eyelids],
        "pinned": spec.pinned.model_copy(update={"vertices": []}),
    })


def carried_text(source: str | Path, mesh: FaceMesh) -> str:
    """The muscle file at ``source`` with its muscles as points on ``mesh`` (the face
    its indices name; ``muscles_as_points``), as YAML: what `facesim mesh align` writes
    beside an aligned mesh, and a subdivided face's file in the tests and the benchmark."""
    import yaml

    carried = muscles_as_points(load_model(Path(source), MuscleFile), mesh)
    return yaml.safe_dump(carried.model_dump(mode="json"), sort_keys=False)
