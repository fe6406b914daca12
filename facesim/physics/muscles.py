"""Facial muscles resolved onto a face mesh (thesis section 3.1.2): the arrays of
:class:`MuscleSet` the model is built from, and the bone-driven parts (the jaw, the
eyelids) as :class:`JawRig` and :class:`EyelidRig`.

A linear muscle (Waters; Zhang et al.) runs from its attachment O, on bone, to its
insertion I, in the skin. Its region of influence is the sector of angle ``zone`` around
O->I (eq. 3.2), with radial falloff out to ``r`` and ``r_max`` (eq. 3.3), both in
multiples of the muscle length |OI| so that one set fits faces of any size.

A sphincter muscle (Waters' elliptical model; not in the thesis) is a ring that contracts
toward its centre: the orbicularis oris around the mouth, the orbicularis oculi around
each eye. Its ellipse is fitted to the ring's points; a vertex at elliptical radius ρ
(1 on the ring) is pulled toward the centre with the radial falloff of eq. 3.3 in ρ,
rising from the centre to ``r`` and falling to zero at ``r_max`` (ring radii).

The muscle file these come from, and how its points find their vertices:
facesim.face.muscle_file.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np

LINEAR, SPHINCTER = 0, 1


@dataclass(frozen=True)
class JawRig:
    """The jaw resolved onto a mesh: hinge (2, 3) points in cm, lower/upper vertex indices,
    max_angle and the lips' contact_tilt in radians, and how far (cm) its condyles glide
    forward (protrusion) and sideways (excursion) at activation 1, and the pressure in the
    mouth when the cheeks are puffed (puff_pressure, force per cm²)."""

    hinge: np.ndarray
    lower: np.ndarray
    upper: np.ndarray
    max_angle: float
    contact_tilt: float = 0.0
    protrusion: float = 0.0
    excursion: float = 0.0
    puff_pressure: float = 0.0


#: The air pressure in a puffed mouth (force per cm², facesim's units): on the default
#: head, ICT's cheekPuff_L's amplitude (REALISM.md; 2000 gave 1.23 of it, and the
#: cheeks' motion is linear in it).
PUFF_PRESSURE = 1600.0
#: The jaw's controls, activation columns after the muscles: its opening about the hinge
#: (MPEG-4 open_jaw, AU26/27), its glide forward (thrust_jaw, AU29) and to either side
#: (AU30 left and right: one column each, as activations are 0-1), the lips sealed
#: over it as it opens (ARKit's mouthClose: facesim.physics.rig), and the air pressure
#: in the mouth it closes, on each cheek (AU34, cheek puff: facesim.physics.pressure),
#: the lips drawn as a whole to the subject's left or right (ARKit's mouthLeft and
#: mouthRight, which FACS has no unit for: facesim.physics.rig), and each lip rolled in
#: over the teeth (AU28, lip suck; ARKit's mouthRollUpper and mouthRollLower).
JAW_CONTROLS = ("jaw", "jaw_thrust", "jaw_sideways_l", "jaw_sideways_r", "lip_seal", "cheek_puff_l", "cheek_puff_r",
                "mouth_left", "mouth_right", "lip_roll_upper", "lip_roll_lower")


@dataclass(frozen=True)
class EyelidRig:
    """One eye's lid contours resolved onto a mesh, paired corner to corner; ``gaze``
    names the controls turning that eye up, down, to the subject's left and right
    (``GAZE``), which its lids follow (facesim.physics.rig)."""

    name: str
    upper: np.ndarray
    lower: np.ndarray
    reach: float
    levator: str | None = None
    levator_angle: float = 0.0  # radians
    gaze: tuple[str, ...] = ()


#: An eye's gaze controls, each 0-1 (FACS AU63 eyes up, AU64 down, AU61 turned to the
#: subject's left, AU62 to the right; per eye, ``_l`` or ``_r`` added: ARKit's
#: eyeLookUpLeft is gaze_up_l, eyeLookOutLeft gaze_left_l, eyeLookInLeft gaze_right_l).
GAZE = ("gaze_up", "gaze_down", "gaze_left", "gaze_right")
#: How far (degrees) an eye turns at each gaze control's 1: about the rotations of ARKit's
#: eyeLook shapes at full weight; the eyes' range is larger (up 45-50, down 60, to
#: either side 50 degrees), but gazes beyond 30 degrees come with the head.
GAZE_ANGLE = (25.0, 30.0, 30.0, 30.0)
#: The tongue's controls, each 0-1, carried by the mandible and drawn by the renderer
#: (facesim.face.tongue.Tongue): ``tongue_out`` protrudes it (the genioglossus: FACS's
#: AU19, ARKit's tongueOut), ``tongue_up`` raises its tip toward the alveolar ridge (the
#: superior longitudinal muscle: the /l/ and /t/ of speech).
TONGUE = ("tongue_out", "tongue_up")
#: An eye's pupil dilation control, 0-1, per eye with ``_l`` or ``_r`` (ICT's
#: PupilDilate_L/_R; ARKit has none): drawn by the renderer (facesim.face.figure.Pupil).
PUPIL = "pupil_dilate"


@dataclass(frozen=True)
class MuscleSet:
    """Muscles resolved onto a mesh. Per-muscle arrays are indexed by muscle (M of them).

    names : the activation columns, the M muscles then the controls (``jaw``, the eyelids);
    kind : (M,) LINEAR or SPHINCTER; attachment : (M,) vertex of O, -1 for a sphincter;
    insertion : (M,) vertex of I, for a sphincter the ring vertex its flood fill starts at;
    centre_start, centre_index : the vertices whose mean is O (a linear muscle's
    attachment, a sphincter's centre points), in compressed rows; ring : a sphincter's ring
    vertices (empty for a linear muscle); zone : (M,) radians; falloff : (M, 2) r and r_max
    in muscle lengths or ring radii; force : (M,); protrusion : (M,) the push along the
    skin's rest normal per unit of its pull (the pucker's pout, the buccinator's press
    inward); pinned : (p,) int64; tied : the rim's vertices tied to the bones with
    stiffness ``tie`` (Pinned), (q,) int64.
    """

    names: tuple[str, ...]
    kind: np.ndarray
    attachment: np.ndarray
    insertion: np.ndarray
    centre_start: np.ndarray
    centre_index: np.ndarray
    ring: tuple[np.ndarray, ...]
    zone: np.ndarray
    falloff: np.ndarray
    force: np.ndarray
    pinned: np.ndarray
    protrusion: np.ndarray
    tied: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=np.int64))
    tie: float = 0.0
    jaw: JawRig | None = None
    eyelids: tuple[EyelidRig, ...] = ()
    source: str = ""
    material: tuple[tuple[str, Any], ...] = ()  # the file's material fields (MuscleFile.material)

    @property
    def count(self) -> int:
        """How many muscles (the controls are not counted)."""
        return len(self.force)

    @property
    def controls(self) -> tuple[str, ...]:
        return self.names[self.count:]

    def index(self, name: str) -> int:
        return self.names.index(name)
