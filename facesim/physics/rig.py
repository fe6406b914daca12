"""The bone-driven parts of the face, beyond the thesis: the jaw and the eyelids.

Neither is a muscle pulling skin: each moves a set of *targets*, the positions the skin
would take if it followed the bone, and the simulation ties the skin to them. The
hypodermis springs of the model (``Material.tissue``) already tie every vertex to its rest
position; here the rest position becomes a target that moves. Pinned vertices are set on
their targets (the rim along the mandible turns with it), the lips and the lid contours
are driven toward theirs by stiff springs (``Material.drive``) while the jaw opens or the
lids close, and everything else follows through the springs, with the muscles still
acting on top.

- **Jaw** (MPEG-4 ``open_jaw``, FACS AU26/AU27): a rotation by ``w θ`` about the hinge
  axis through the two temporomandibular points, θ = activation × ``max_angle``, then a
  translation by ``w g``: the condyles glide along the articular eminence, forward (AU29,
  jaw thrust, ``protrusion`` cm at activation 1, perpendicular to the hinge axis in the
  horizontal plane) and sideways (AU30, ``excursion`` cm along the hinge axis, toward the
  subject's left or right), so the mandible is a rigid body with translation, not a
  hinge alone. The lips sealed over the open jaw (``lip_seal``, ARKit's mouthClose: the
  orbicularis oris holding the lips together while the jaw drops, as for /p b m/ spoken
  open) turn with the weight w' = w + s Δw (their glide keeps w), Δw = -w on the lips and
  the skin around their corners, harmonic out to zero at the rim and above the hinge: the
  lower lip stays with the upper one and the skin over the chin stretches between it and
  the jaw (ICT's mouthClose on top of jawOpen: the lower lip back up 3.6 cm, the chin's
  skin less the further down). The lips
  drawn as a whole to one side (``mouth_left``/``mouth_right``, ARKit's mouthLeft and
  mouthRight: the modiolus of that side pulling the lips' ring along the teeth) turn
  about the vertical axis of the cylinder the face wraps around (the muscles' projection,
  facesim.physics.muscles) by ``lip_shift`` / R, ``LIP_SHIFT`` times a weight 1
  on the lips and corners and harmonic out to 0 at the rim and ``LIP_SHIFT_REACH`` mouth
  half-widths: the middle slides across the teeth and back, the trailing corner comes
  forward, the leading one goes back (as ICT's mouthLeft moves them). The weight
  w is 1 on the lower lip and the rim below the hinge, 0 on the upper lip and above the
  hinge, and harmonic in between (the graph Laplacian's Dirichlet problem), so the opening
  spreads smoothly through the cheeks and the lips part without tearing the corners.
- **Eyelids** (AU43 eyes closed, AU45 blink; AU5 upper lid raiser): each contour vertex
  slides over the eyeball about the horizontal axis through its centre, in cylindrical
  coordinates (x, φ, r) about that axis, to a meeting line a tenth of the way up from the
  lower lid, above each lower point (the upper lid does most of a blink) while the lower
  lid slides a millimetre toward the nose, at a radius outside the eyeball. The upper
  target always stays above its lower partner, ``LID_GAP`` apart when closed, so the
  lids never pass through each other. The skin around the opening, out to ``reach`` eye widths, follows with a
  harmonic share of the contour's motion. The levator palpebrae superioris (an eyelid's
  ``levator`` control) turns the upper contour up over the eyeball instead, by
  ``levator_angle`` at its middle and less toward the corners (sin π s along it, s from
  corner to corner); the lower lid stays, and the skin follows the same way. Closure c
  and raise a add in (Δx, Δφ, Δr) as c Δ_close + a (1 - c) Δ_raise: the levator lets go
  as the lid closes, so a blink closes a raised lid.

The jaw's lip lists and the lid contours are paired in order; each pair is also a contact
(``contacts._contacts``): the upper vertex never drops below its lower partner, so a
sphincter pressing the lips together, or a closing lid, stops where they meet. "Below"
is along the pair's contact normal: straight up for the lids; for the lips, turned back
by the jaw's ``contact_tilt``, since closed lips meet across an inclined plane and a
lower lip pushed up (the chin raiser, AU17; the lip press, AU24) slides forward over the
upper one rather than lifting it. ICT's scans measure that plane: over its action units
the lower lip's travel against the upper one keeps to one side of a plane turned about
50 degrees (every unit but the dimpler, AU14, by 1.5 mm), where a horizontal one is
crossed by 6.6 mm under AU17 and 2.5 mm under AU24.

The eyeball (centre and radius from the eye opening) is the same one the renderer draws.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .mesh import FaceMesh, smooth_interpolation
from .muscles import JAW_CONTROLS, MuscleSet

#: The wall of the oral cavity (AU34's pressure): an ellipse about the mouth's centre,
#: (across, up and down) in mouth half-widths, at full weight inside CAVITY_CORE of it:
#: the cheeks over the buccinators, out to the masseters, and the lips. Measured against
#: ICT's cheekPuff_L on the default head (cosine): reaching (2.0, 1.6) 0.65, (3.0, 1.2)
#: 0.76, (3.0, 1.0) 0.77; its centre raised or lowered a third of a half-width, 0.67 and
#: 0.75. The rest of the gap is direction: the scan's cheeks move forward and a little
#: up, where a pressure along the skin's normal pushes their sides out sideways.
CAVITY_REACH = (3.0, 1.0)
CAVITY_CORE = 0.5
#: How far (cm, along the face) the lips slide at mouth_left or mouth_right 1 (from the
#: trailing corner to the middle; the leading corner LIP_LEADING of it), and how far
#: around the mouth the skin follows (mouth half-widths). Against ICT's mouthLeft on the
#: default head: cosine 0.88, amplitude 0.98 (1.5 cm: 0.87, 0.74; LIP_LEADING 1, the lips
#: sliding as one, folded the leading corner's slivers).
LIP_SHIFT = 2.0
LIP_SHIFT_REACH = 3.0
LIP_LEADING = 0.45
#: The lips rolled in over the teeth (``lip_roll_upper``/``lip_roll_lower``: FACS AU28,
#: lip suck; ARKit's mouthRollUpper and mouthRollLower): the orbicularis oris's marginal
#: part turns each lip about a horizontal axis through a pivot inside it, the upper lip's
#: edge back and its vermilion down, the lower's back and up. A rigid turn fits ICT's
#: shapes at the lips' middle (within 0.6 mm for the upper, 2.5 mm for the lower) by 45
#: and -45.5 degrees about pivots LIP_ROLL_PIVOT (up, forward) mouth half-widths from the
#: mouth opening's centre; the upper lip turns 57 (the skin holds it back: at 45 it
#: reached 0.66 of ICT's amplitude). Against ICT's on the default head: upper cosine
#: 0.82, amplitude 0.78; lower 0.83, 0.96.
LIP_ROLL_ANGLE = (57.0, -45.5)
LIP_ROLL_PIVOT = ((0.51, -0.01), (-0.78, -0.27))
#: How much of each lip (upper, lower) turns: all of it within LIP_ROLL_BAND mouth
#: half-widths of its edge and nearer it than the other lip's, easing to the corners,
#: which turn LIP_ROLL_CORNER of the middle (ICT's: 0.45 for the upper lip, 0.1 for the
#: lower; the upper's at 0.45 folded 2 triangles there), harmonic out to nothing at the
#: other lip and LIP_ROLL_REACH half-widths from the mouth's centre (a band of 0.25 and
#: reach of 1.6, as first tried: cosine 0.77 and 0.63).
LIP_ROLL_BAND = (0.4, 0.4)
LIP_ROLL_CORNER = (0.35, 0.1)
LIP_ROLL_REACH = (1.2, 1.2)
#: Each roll (upper, lower) holds the other lip still at its edge and, out to this many
#: mouth half-widths from the middle, over its band: the lower roll holds the whole
#: upper lip (not holding it, the upper lip turned too and folded); the upper roll lets
#: the lower lip follow a little (held, its cosine fell to 0.77).
LIP_ROLL_APART = (0.0, 1.0)
#: The lips part as a wedge over this fraction of the mouth's width from each corner.
JAW_WEDGE = 0.3
#: The mouth corners follow the jaw by this much of the lower lip's travel (a little less
#: than half: they stay nearer the upper lip), driven with the full ``Material.drive``:
#: the corner's sliver triangles fold over under any other pull (measured on the default
#: face: 0.5, or a softer drive, inverts one at 20 degrees). A corner is the mouth
#: opening's leftmost or rightmost vertex and any vertex within JAW_CORNER_SIZE mouth widths.
JAW_CORNER = 0.42
JAW_CORNER_SIZE = 0.025
#: Sealed over the open jaw (mouthClose), the lips turn back with the skin within this
#: many mouth widths of each corner: the seal's change Δw is fixed there, not left to the
#: harmonic fill, which let the corner's sliver triangles (61-76-184 on the default face)
#: fold over under the upper lip's roll and the seal together (0.06 still folds one; 0.09
#: folds the next ring's).
JAW_SEAL_CORNER = 0.075
#: The skin over the mandible is held to it with this share of ``Material.drive`` times
#: its jaw weight while the jaw is open: bone under the chin, soft tissue in the cheeks.
JAW_DRIVE = 0.5
#: The least vertical gap (cm) between paired lip and lid vertices (less where they are
#: closer at rest): contact, which a single-layer mesh does not otherwise have.
CONTACT_GAP = 0.01
#: Where closed lids meet, as a fraction of the way from the lower lid to the upper one:
#: the upper lid does most of a blink's travel. Each pair meets above its lower point, so
#: the upper lid comes down onto the lower one, and the lower lid slides LID_NASAL (cm)
#: toward the nose, as the lower lid does in a blink (ICT's eyeBlink moves the skin under
#: it 2 mm nasally). Measured on the default head against ICT's blink (AU45): met at
#: the pair's mean, a fifth of the way up and with no nasal slide, cosine 0.73; met above
#: the lower point 0.77, a tenth of the way up 0.78, the lids' reach 0.25 0.79, the slide
#: 1 mm 0.81 (2 mm inverts two triangles).
LID_MEETING = 0.1
LID_NASAL = 0.1
#: Within this distance (cm) of an eye's corner a lid's closing eases off to nothing: the
#: default faces' lids have no vertex so close (the nearest, 1.15 mm).
CANTHUS_ROOM = 0.1
#: Gap left between the closed lid contours (cm): they touch but never cross.
LID_GAP = 0.02
#: How far outside the eyeball the closed lid slides (cm): the lid's own thickness.
LID_THICKNESS = 0.06
#: How far (cm, at the contour's middle, less toward the corners as sin πs) the upper and
#: lower lids follow the eye at gaze_up and gaze_down 1: the upper lid rides the cornea's
#: top, the lower lid its bottom, less. ICT's eyeLook shapes move the lids' middles up 3.4
#: and 1.6 mm, down 7.4 and 2.0 mm, to the side 2.2 and 2.0 mm, with eyeballs that do not
#: turn; over facesim's eyeball turned 30 degrees down, 7.4 mm all but closed the lids
#: (the picture read as eyes shut), 4 mm leaves the iris under the lid as a downward gaze
#: shows it.
LOOK_LIDS = ((0.34, 0.16), (-0.40, -0.12))
#: To either side (gaze_left/right 1) the lids and the skin of the lids turn with the
#: globe about its vertical axis, by LOOK_SIDE (cm) over the eyeball's radius (a slide of
#: LOOK_SIDE in front of the globe), easing off to nothing LOOK_REACH eye widths beyond
#: the opening and within LOOK_TIE eye widths of its corners, which the canthal tendons
#: tie to the orbit. ICT's eyeLookIn_L and eyeLookOut_L do the same: the side the lids
#: move toward goes back round the globe (1.5 mm at the outer end) and the side they
#: leave comes forward, and the lid's skin moves with them, 2.4 mm, not only its edge.
#: Against them (cosine, amplitude): a slide of the contour alone, spread harmonically,
#: 0.70, 0.95; turned round the globe, 0.75-0.77; with the lids' skin turned too, 0.86-0.88,
#: 0.95-0.96.
LOOK_SIDE, LOOK_TIE = 0.20, 0.5
#: The skin follows the lids' gaze out to this many eye widths around the opening (their
#: closing reaches further: an eyelid's ``reach``). Against ICT's eyeLookUp_L at the
#: landmarks: cosine 0.89, amplitude 1.05 (0.05-0.2 alike).
LOOK_REACH = 0.2


@dataclass(frozen=True)
class Rig:
    """Per-vertex arrays of the jaw and eyelids, in the kernels' layout (n vertices).

    jaw_column : activation column of the jaw, -1 without one; jaw_weight : (n,) w;
    jaw_hinge : (3,) a point on the hinge axis; jaw_axis : (3,) its unit direction (+x);
    jaw_max : θ at activation 1 (radians); lip_shift_column : (2,) activation columns of
    the lips drawn to the subject's left and right (-1 without a jaw); lip_shift :
    (n, 2) how far (cm, along the face) each vertex slides with them at 1, to either side;
    lip_roll_column : (2,) activation columns of the upper and the lower lip rolled in (-1
    without a jaw); lip_roll : (n, 2) each vertex's share of either roll; lip_roll_pivot :
    (2, 3) a point on each roll's axis (+x); lip_roll_angle : (2,) each roll at 1 (radians);
    pressure_column : (2,) activation columns of
    the pressure in the mouth on the subject's left and right cheek (-1 without a jaw);
    pressure_weight : (n, 2) each vertex's share of the cavity's wall on either side;
    pressure : the pressure at activation 1, its sign the winding's (outward); jaw_seal_column : activation column of the lips'
    seal (-1 without a jaw); jaw_seal : (n,) Δw, each vertex's change of jaw weight when
    sealed; jaw_glide_column : (3,) activation columns of
    the glide forward, to the left and to the right (-1 without a jaw); jaw_glide : (3, 3)
    the glide (cm) of each at activation 1; lid_column : (n,) activation column of the
    eyelid moving each vertex, -1 for none; lid_centre : (n, 3) its eyeball centre;
    lid_delta : (n, 3) (Δx, Δφ, Δr) at full closure; lid_raise_column : (n,) activation
    column of the levator raising the vertex's upper lid, -1 for none; lid_raise_delta :
    (n, 3) (Δx, Δφ, Δr) at the levator's full activation; lid_look_column : (n, 4) the
    activation columns of the gaze controls of the eye moving each vertex (up, down, left,
    right: facesim.physics.muscles.GAZE), -1 for none; lid_look_delta : (n, 4, 3) the
    (Δx, Δφ, Δr) at each one's 1; gaze_column : (2, 4) the gaze controls' columns of the
    subject's left eye and right eye, -1 without that eye; drive_column : (n,) the control
    whose activation drives the vertex to its target (the lips: the jaw; the lid contours:
    their eyelid), -1 for none; drive_weight : (n,) its share of ``Material.drive``;
    contact_upper, contact_lower : (k,) the lip and lid pairs that may not pass through
    each other; contact_lips : (k,) whether a pair is the lips' (a seal holds those); contact_normal : (k, 3) the direction the upper one keeps above the lower
    (the lids: straight up; the lips: turned back by the jaw's ``contact_tilt``);
    contact_gap : (k,) the least gap each keeps along it.
    """

    jaw_column: int
    jaw_weight: np.ndarray
    jaw_hinge: np.ndarray
    jaw_axis: np.ndarray
    jaw_max: float
    lip_shift_column: np.ndarray
    lip_shift: np.ndarray
    lip_roll_column: np.ndarray
    lip_roll: np.ndarray
    lip_roll_pivot: np.ndarray
    lip_roll_angle: np.ndarray
    pressure_column: np.ndarray
    pressure_weight: np.ndarray
    pressure: float
    jaw_seal_column: int
    jaw_seal: np.ndarray
    jaw_glide_column: np.ndarray
    jaw_glide: np.ndarray
    lid_column: np.ndarray
    lid_centre: np.ndarray
    lid_delta: np.ndarray
    lid_raise_column: np.ndarray
    lid_raise_delta: np.ndarray
    lid_look_column: np.ndarray
    lid_look_delta: np.ndarray
    gaze_column: np.ndarray
    drive_column: np.ndarray
    drive_weight: np.ndarray
    contact_upper: np.ndarray
    contact_lower: np.ndarray
    contact_lips: np.ndarray
    contact_normal: np.ndarray
    contact_gap: np.ndarray


def eyeball(opening: np.ndarray) -> tuple[np.ndarray, float]:
    """Centre and radius of the eyeball behind an eye opening (its points, (k, 3)):
    radius 0.42 of the opening's width, centre 0.8 radius behind its mean."""
    radius = 0.42 * float(np.ptp(opening[:, 0]))
    return opening.mean(axis=0) - np.array([0.0, 0.0, 0.8 * radius]), radius


def harmonic(mesh: FaceMesh, fixed: np.ndarray, values: np.ndarray) -> np.ndarray:
    """Values (n, d) that equal ``values`` on the ``fixed`` vertices and are harmonic (the
    mean of their neighbours) everywhere else: the Dirichlet problem of the graph Laplacian."""
    return smooth_interpolation(mesh.edges, mesh.vertex_count, fixed, values)


def _opening(mesh: FaceMesh, vertices: np.ndarray) -> np.ndarray | None:
    """The inner boundary loop (mouth or eye opening) that holds any of ``vertices``."""
    return next((loop for loop in mesh.boundary_loops[1:] if np.isin(vertices, loop).any()), None)


def _rim(mesh: FaceMesh) -> np.ndarray:
    """The mesh's outer boundary loop (held still by every rig field), if it has one."""
    return mesh.boundary_loops[0] if mesh.boundary_loops else np.zeros(0, dtype=np.int64)


def _arcs(loop: np.ndarray, a: int, b: int) -> tuple[np.ndarray, np.ndarray]:
    """The two arcs of a closed ``loop`` between its positions ``a`` and ``b`` (neither
    included), each running from ``a`` to ``b``: one way round, and the other."""
    one = np.roll(loop, -a)[1:(b - a) % len(loop)]
    other = np.roll(loop, -b)[1:(a - b) % len(loop)][::-1]
    return one, other


def _lip_edges(mesh: FaceMesh, jaw, loop: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The upper and the lower lip's edge and the two mouth corners on the mouth opening's
    ``loop``: its two arcs between the corners (its leftmost and rightmost vertices) are
    the lower lip, which holds the listed lower points, and the upper lip; a finer mesh
    has more vertices on them than the muscle file lists."""
    x = mesh.vertices
    ends = sorted([int(np.argmin(x[loop, 0])), int(np.argmax(x[loop, 0]))])
    arcs = _arcs(loop, *ends)
    lower_first = np.isin(jaw.lower, arcs[0]).sum() >= np.isin(jaw.lower, arcs[1]).sum()
    upper = np.union1d(jaw.upper, arcs[1 if lower_first else 0])
    lower = np.union1d(jaw.lower, arcs[0 if lower_first else 1])
    return upper, lower, loop[ends]


def _jaw(mesh: FaceMesh, muscles: MuscleSet):
    """The jaw's column, per-vertex weight, hinge point and axis, angle at activation 1,
    the mouth-corner vertices (driven firmly), and the weight's change when the lips are
    sealed (Δw: module docstring)."""
    jaw = muscles.jaw
    x = mesh.vertices
    hinge = jaw.hinge
    axis = hinge[1] - hinge[0]
    axis = axis / np.linalg.norm(axis) * np.sign(axis[0] or 1.0)
    below = x[:, 1] < hinge[:, 1].mean()
    rim = _rim(mesh)
    lower, upper, corners = jaw.lower, jaw.upper, np.zeros(0, dtype=np.int64)
    loop = _opening(mesh, jaw.lower)
    if loop is not None:
        upper, lower, corners = _lip_edges(mesh, jaw, loop)
    # The lips part as a wedge: toward each corner (with any vertex all but touching it)
    # their weights meet half way, or the tissue at the corner folds over.
    lips = np.concatenate([lower, upper])
    lip_weight = np.isin(lips, lower).astype(float)
    if len(corners):
        width = np.ptp(x[loop, 0])
        near = np.linalg.norm(x[:, None] - x[None, corners], axis=2).min(axis=1) < JAW_CORNER_SIZE * width
        corners = np.union1d(corners, np.setdiff1d(np.flatnonzero(near), lips))
        distance = np.linalg.norm(x[lips, None, :2] - x[None, corners, :2], axis=2).min(axis=1)
        lip_weight += (0.5 - lip_weight) * _smoothstep(1 - distance / (JAW_WEDGE * width))
    fixed = np.concatenate([lips, corners, rim, np.flatnonzero(~below)])
    value = np.concatenate([lip_weight, np.full(len(corners), JAW_CORNER), below[rim].astype(float),
                            np.zeros(int((~below).sum()))])
    fixed, first = np.unique(fixed, return_index=True)  # the lips win over the rules after them
    weight = np.clip(harmonic(mesh, fixed, value[first, None])[:, 0], 0.0, 1.0)
    lips_and_corners = np.union1d(lips, corners)
    if len(corners):  # sealed, the skin around each corner stays with the lips (JAW_SEAL_CORNER)
        around = np.linalg.norm(x[:, None] - x[None, corners], axis=2).min(axis=1) < JAW_SEAL_CORNER * width
        lips_and_corners = np.union1d(lips_and_corners, np.flatnonzero(around))
    still = np.setdiff1d(fixed, lips_and_corners)  # the rim and the skin above the hinge
    seal = harmonic(mesh, np.concatenate([lips_and_corners, still]),
                    np.concatenate([-weight[lips_and_corners], np.zeros(len(still))])[:, None])[:, 0]
    return muscles.index("jaw"), weight, hinge[0], axis, jaw.max_angle, corners, np.clip(seal, -weight, 0.0)


def _lips_around(mesh: FaceMesh, jaw, corners: np.ndarray) -> np.ndarray:
    """(n, 2) the lips' share of their turn to the subject's left and to the right: on the
    mouth opening's loop, its corners and the listed lip points, 1 from the trailing
    corner to the middle, easing to ``LIP_LEADING`` at the leading corner (the lips bunch
    there as they slide: ICT's mouthLeft moves its leading corner 0.7 cm, the trailing one
    1.6), harmonic out to 0 at the rim and beyond ``LIP_SHIFT_REACH`` mouth half-widths
    from the mouth's centre."""
    loop = _opening(mesh, jaw.lower)
    if loop is None:
        return np.zeros((mesh.vertex_count, 2))
    x = mesh.vertices
    lips = np.unique(np.concatenate([loop, corners, jaw.upper, jaw.lower]))
    centre, half = x[loop].mean(axis=0), np.ptp(x[loop, 0]) / 2
    far = np.flatnonzero(np.linalg.norm((x - centre)[:, :2], axis=1) > LIP_SHIFT_REACH * half)
    rim = _rim(mesh)
    still = np.setdiff1d(np.union1d(far, rim), lips)
    out = np.zeros((mesh.vertex_count, 2))
    for k, toward in enumerate((1.0, -1.0)):  # to the left (+x), to the right
        ahead = toward * (x[lips, 0] - centre[0]) / half  # -1 at the trailing corner, 1 at the leading one
        share = 1.0 - (1.0 - LIP_LEADING) * _smoothstep(ahead)
        values = np.concatenate([share, np.zeros(len(still))])
        out[:, k] = np.clip(harmonic(mesh, np.concatenate([lips, still]), values[:, None])[:, 0], 0.0, 1.0)
    return out


def _lips_rolled(mesh: FaceMesh, jaw, corners: np.ndarray, jaw_weight: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(n, 2) each vertex's share of the upper and the lower lip's roll (LIP_ROLL_ANGLE)
    and (2, 3) the two pivots: module docstring and LIP_ROLL_BAND. Which lip a vertex is
    on is the jaw's weight's (under a half: the upper), not its nearer edge: closed, the
    lips' skin lies a millimetre apart, and by distance the upper lip's middle fell to
    the lower, and folded when it rolled."""
    n = mesh.vertex_count
    loop = _opening(mesh, jaw.lower)
    if loop is None:
        return np.zeros((n, 2)), np.zeros((2, 3))
    x = mesh.vertices
    centre, half = x[loop].mean(axis=0), np.ptp(x[loop, 0]) / 2
    edges = _lip_edges(mesh, jaw, loop)[:2]
    rim = _rim(mesh)
    out = np.zeros((n, 2))
    distance = [np.linalg.norm(x[:, None, :2] - x[None, edge, :2], axis=2).min(axis=1) for edge in edges]
    bands = []
    for k, edge in enumerate(edges):  # each lip: within the band of its edge, and nearer it than the other lip's
        near = (distance[k] < LIP_ROLL_BAND[k] * half) & ((jaw_weight < 0.5) if k == 0 else (jaw_weight >= 0.5))
        bands.append(np.union1d(np.setdiff1d(np.flatnonzero(near), np.concatenate([edges[1 - k], corners])), edge))
    for k, band in enumerate(bands):
        far = np.flatnonzero(np.linalg.norm((x - centre)[:, :2], axis=1) > LIP_ROLL_REACH[k] * half)
        across = np.abs(x[band, 0] - centre[0]) / half
        share = 1.0 - (1.0 - LIP_ROLL_CORNER[k]) * _smoothstep(across)
        # the other lip does not turn, but toward the corners, where the lips share their skin
        other = np.union1d(edges[1 - k], bands[1 - k][np.abs(x[bands[1 - k], 0] - centre[0]) < LIP_ROLL_APART[k] * half])
        still = np.setdiff1d(np.union1d(np.union1d(far, rim), other), band)
        fixed = np.concatenate([band, corners, still])
        values = np.concatenate([share, np.full(len(corners), LIP_ROLL_CORNER[k]), np.zeros(len(still))])
        out[:, k] = np.clip(harmonic(mesh, fixed, values[:, None])[:, 0], 0.0, 1.0)
    pivots = np.array([[0.0, centre[1] + up * half, centre[2] + forward * half] for up, forward in LIP_ROLL_PIVOT])
    return out, pivots


def _cavity_wall(mesh: FaceMesh, jaw) -> tuple[np.ndarray, float]:
    """The skin over the oral cavity, where the air in a puffed mouth pushes (AU34), as
    (n, 2) weights on the subject's left and right, and the sign that turns the mesh's
    winding outward. The wall is the ellipse about the mouth's centre reaching
    ``CAVITY_REACH`` mouth half-widths across and up and down, weight 1 inside
    ``CAVITY_CORE`` of it and easing to 0 at its edge; a vertex's side eases from one
    cheek to the other across the middle quarter of the mouth, the lips shared."""
    n = mesh.vertex_count
    loop = _opening(mesh, jaw.lower)
    if loop is None:
        return np.zeros((n, 2)), 1.0
    x = mesh.vertices
    centre, half = x[loop].mean(axis=0), np.ptp(x[loop, 0]) / 2
    u, v = (x[:, 0] - centre[0]) / half, (x[:, 1] - centre[1]) / half
    r = np.hypot(u / CAVITY_REACH[0], v / CAVITY_REACH[1])
    wall = 1.0 - _smoothstep((r - CAVITY_CORE) / (1.0 - CAVITY_CORE))
    left = _smoothstep((u + 0.25) / 0.5)
    f = mesh.faces
    area = np.cross(x[f[:, 1]] - x[f[:, 0]], x[f[:, 2]] - x[f[:, 0]])
    outward = float(np.sign((wall[f].mean(axis=1) * area[:, 2]).sum()) or 1.0)  # the face looks along +z
    return np.column_stack([wall * left, wall * (1.0 - left)]), outward


def jaw_forward(axis: np.ndarray) -> np.ndarray:
    """The mandible's forward, a unit vector: perpendicular to the hinge ``axis`` (a unit
    vector) in the horizontal plane. The condyles glide along it (AU29), and the muscle
    file's joints lie ``hinge_depth`` behind their hinge points against it
    (facesim.face.muscle_file)."""
    forward = np.array([0.0, 0.0, 1.0]) - axis[2] * axis
    return forward / np.linalg.norm(forward)


def _smoothstep(t: np.ndarray) -> np.ndarray:
    t = np.clip(t, 0.0, 1.0)
    return t * t * (3 - 2 * t)


def _cylindrical(points: np.ndarray, centre: np.ndarray) -> np.ndarray:
    """(x, φ, r) about the horizontal axis through ``centre``: φ = atan2(y, z) upward."""
    d = points - centre
    return np.column_stack([d[:, 0], np.arctan2(d[:, 1], d[:, 2]), np.hypot(d[:, 1], d[:, 2])])


def _lid_arcs(mesh: FaceMesh, opening: np.ndarray | None, lid) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The upper and lower lid's whole edges, each from the outer corner to the inner
    (the points the muscle file lists and, on a finer mesh, the opening's vertices between
    them), and the opening's two corners (the canthi): on each stretch of the loop between
    an upper and a lower point, its vertex farthest across the eye. Held still as corners,
    the vertices between a lid's points turned over the triangles between them and their
    closing neighbours."""
    if opening is None:
        return lid.upper, lid.lower, np.zeros(0, dtype=np.int64)
    side = np.where(np.isin(opening, lid.upper), 1, np.where(np.isin(opening, lid.lower), -1, 0))
    marked = np.flatnonzero(side)
    k = np.arange(len(opening))
    before = marked[np.searchsorted(marked, k, side="right") - 1]  # wraps to the last marked at the start
    after = marked[np.searchsorted(marked, k) % len(marked)]
    across = np.abs(mesh.vertices[opening, 0] - mesh.vertices[opening, 0].mean())
    at = []
    for start in np.unique(before[(side == 0) & (side[before] != side[after])]):
        stretch = np.flatnonzero((side == 0) & (before == start))
        at.append(int(stretch[np.argmax(across[stretch])]))
    if len(at) != 2:
        return lid.upper, lid.lower, opening[at]
    # the loop's vertex at the lid's first point (nearest it: on a mesh so fine that the
    # points snap off the opening, the Hopper face Loop-subdivided four times, it was none)
    first = int(np.argmin(np.linalg.norm(mesh.vertices[opening] - mesh.vertices[lid.upper[0]], axis=1)))
    # the corner nearer the lid's first point along the loop is the outer one
    at.sort(key=lambda c: min((c - first) % len(opening), (first - c) % len(opening)))
    one, other = _arcs(opening, *at)
    upper, lower = (one if np.isin(points, one).sum() > np.isin(points, other).sum() else other
                    for points in (lid.upper, lid.lower))
    return upper, lower, opening[at]


def _along(n: int) -> np.ndarray:
    """Fractions along a lid's edge of n vertices, corner (0) to corner (1)."""
    return np.arange(1, n + 1) / (n + 1)


def _eyelid(mesh: FaceMesh, lid, opening: np.ndarray | None, centre: np.ndarray, radius: float, width: float):
    """The lids' edges' (Δx, Δφ, Δr) at full closure (each vertex meets the other lid at
    the same fraction along it), and at the levator's full raise, spread harmonically over
    the skin within ``reach`` eye widths of the opening. Returns the region, its two
    deltas, its deltas at each gaze control's 1 (region, 4, 3) and the lids' edges."""
    x = mesh.vertices
    edge_upper, edge_lower, corners = _lid_arcs(mesh, opening, lid)
    s_upper, s_lower = _along(len(edge_upper)), _along(len(edge_lower))
    upper, lower = _cylindrical(x[edge_upper], centre), _cylindrical(x[edge_lower], centre)
    lower_at = np.column_stack([np.interp(s_upper, s_lower, lower[:, j]) for j in range(3)])  # below each upper vertex
    upper_at = np.column_stack([np.interp(s_lower, s_upper, upper[:, j]) for j in range(3)])  # above each lower vertex
    nasal = -np.sign(centre[0]) * LID_NASAL  # toward the face's midline

    def meeting(up, low):
        phi = low[:, 1] + LID_MEETING * (up[:, 1] - low[:, 1])
        over_ball = np.sqrt(np.maximum(radius**2 - low[:, 0] ** 2, 0.0)) + LID_THICKNESS
        r = np.maximum((up[:, 2] + low[:, 2]) / 2, over_ball)
        return low[:, 0], phi, r, LID_GAP / 2 / r

    mx, mphi, mr, half_gap = meeting(upper, lower_at)
    delta_upper = np.column_stack([mx - upper[:, 0], mphi + half_gap - upper[:, 1], mr - upper[:, 2]])
    _, mphi, mr, half_gap = meeting(upper_at, lower)
    delta_lower = np.column_stack([np.full(len(lower), nasal), mphi - half_gap - lower[:, 1], mr - lower[:, 2]])
    # within CANTHUS_ROOM of a corner, where the canthal tendons hold the lids, the closing
    # eases off (a finer mesh has edge vertices there, which crossed the corner)
    if len(corners):
        for edge, d in ((edge_upper, delta_upper), (edge_lower, delta_lower)):
            near = np.linalg.norm(x[edge][:, None] - x[corners][None], axis=2).min(axis=1)
            d *= np.clip(near / CANTHUS_ROOM, 0.0, 1.0)[:, None]
    contour = np.concatenate([edge_upper, edge_lower])
    distance = np.linalg.norm((x - centre)[:, :2], axis=1)
    outside = np.flatnonzero(distance > (0.5 + lid.reach) * width)
    fixed = np.concatenate([contour, corners, np.setdiff1d(outside, contour)])
    still = np.zeros((len(fixed) - len(contour), 3))  # the eye corners and the skin beyond reach
    delta = harmonic(mesh, fixed, np.concatenate([delta_upper, delta_lower, still]))
    raised = np.zeros_like(delta)
    if lid.levator:
        raise_upper = np.column_stack([np.zeros_like(s_upper), lid.levator_angle * np.sin(np.pi * s_upper), np.zeros_like(s_upper)])
        raised = harmonic(mesh, fixed, np.concatenate([raise_upper, np.zeros_like(delta_lower), still]))
    region = np.setdiff1d(np.flatnonzero(distance <= (0.5 + lid.reach) * width), corners)
    sin_upper, sin_lower = np.sin(np.pi * s_upper), np.sin(np.pi * s_lower)
    # up and down, the skin follows the lids' edges less far than their closing, out to
    # LOOK_REACH eye widths; to a side, the lids and their skin turn with the globe
    beyond = np.setdiff1d(np.flatnonzero(distance > (0.5 + LOOK_REACH) * width), np.concatenate([contour, corners]))
    looks = []
    for up, low in LOOK_LIDS:
        on_upper = np.column_stack([np.zeros(len(sin_upper)), up * sin_upper / upper[:, 2], np.zeros(len(sin_upper))])
        on_lower = np.column_stack([np.zeros(len(sin_lower)), low * sin_lower / lower[:, 2], np.zeros(len(sin_lower))])
        looks.append(harmonic(mesh, np.concatenate([contour, corners, beyond]),
                              np.concatenate([on_upper, on_lower, np.zeros((len(corners) + len(beyond), 3))]))[region])
    tie = np.linalg.norm(x[region][:, None] - x[corners][None], axis=2).min(axis=1) if len(corners) else np.inf
    turn = (LOOK_SIDE / radius * (1.0 - _smoothstep((distance[region] - 0.5 * width) / (LOOK_REACH * width)))
            * _smoothstep(tie / (LOOK_TIE * width)))
    looks += [_turned_about_the_globe(x[region], centre, sign * turn) for sign in (1.0, -1.0)]
    return region, delta[region], raised[region], np.stack(looks, axis=1), contour


def _turned_about_the_globe(points: np.ndarray, centre: np.ndarray, angle: np.ndarray) -> np.ndarray:
    """(Δx, Δφ, Δr) (``_cylindrical``'s coordinates about the eyeball's horizontal axis) of
    ``points`` turned by ``angle`` (radians, each its own) about the vertical axis through
    the eyeball's ``centre``: the lids and their skin sliding sideways with the globe,
    round it, so the side they move toward goes back and the side they leave comes forward."""
    d = points - centre
    turned = centre + np.column_stack([d[:, 0] * np.cos(angle) + d[:, 2] * np.sin(angle), d[:, 1],
                                       -d[:, 0] * np.sin(angle) + d[:, 2] * np.cos(angle)])
    return _cylindrical(turned, centre) - _cylindrical(points, centre)


def build_rig(mesh: FaceMesh, muscles: MuscleSet) -> Rig:
    n = mesh.vertex_count
    drive_column = np.full(n, -1, dtype=np.int64)
    drive_weight = np.zeros(n)
    if muscles.jaw is not None:
        jaw_column, jaw_weight, hinge, axis, jaw_max, corners, seal = _jaw(mesh, muscles)
        seal_column = muscles.index("lip_seal")
        pressure_column = np.array([muscles.index("cheek_puff_l"), muscles.index("cheek_puff_r")], dtype=np.int64)
        pressure_weight, winding = _cavity_wall(mesh, muscles.jaw)
        pressure = winding * muscles.jaw.puff_pressure
        lip_shift_column = np.array([muscles.index("mouth_left"), muscles.index("mouth_right")], dtype=np.int64)
        lip_shift = LIP_SHIFT * _lips_around(mesh, muscles.jaw, corners)
        lip_roll_column = np.array([muscles.index("lip_roll_upper"), muscles.index("lip_roll_lower")], dtype=np.int64)
        lip_roll, lip_roll_pivot = _lips_rolled(mesh, muscles.jaw, corners, jaw_weight)
        drive_column[jaw_weight > 0] = jaw_column
        drive_weight[:] = JAW_DRIVE * jaw_weight
        drive_weight[corners] = 1.0
        glide_column = np.array([muscles.index(c) for c in JAW_CONTROLS[1:4]], dtype=np.int64)
        jaw = muscles.jaw
        glide = np.array([jaw.protrusion * jaw_forward(axis), jaw.excursion * axis, -jaw.excursion * axis])
    else:
        jaw_column, jaw_weight, hinge, axis, jaw_max = -1, np.zeros(n), np.zeros(3), np.array([1.0, 0, 0]), 0.0
        glide_column, glide = np.full(3, -1, dtype=np.int64), np.zeros((3, 3))
        seal_column, seal = -1, np.zeros(n)
        pressure_column, pressure_weight, pressure = np.full(2, -1, dtype=np.int64), np.zeros((n, 2)), 0.0
        lip_shift_column, lip_shift = np.full(2, -1, dtype=np.int64), np.zeros((n, 2))
        lip_roll_column, lip_roll, lip_roll_pivot = np.full(2, -1, dtype=np.int64), np.zeros((n, 2)), np.zeros((2, 3))
    lid_column = np.full(n, -1, dtype=np.int64)
    lid_centre = np.zeros((n, 3))
    lid_delta = np.zeros((n, 3))
    lid_raise_column = np.full(n, -1, dtype=np.int64)
    lid_raise_delta = np.zeros((n, 3))
    lid_look_column = np.full((n, 4), -1, dtype=np.int64)
    lid_look_delta = np.zeros((n, 4, 3))
    gaze_column = np.full((2, 4), -1, dtype=np.int64)
    for lid in muscles.eyelids:
        opening = _opening(mesh, lid.upper)
        points = mesh.vertices[opening if opening is not None else np.concatenate([lid.upper, lid.lower])]
        centre, radius = eyeball(points)
        region, delta, raised, looks, edge = _eyelid(mesh, lid, opening, centre, radius, float(np.ptp(points[:, 0])))
        region_free = region[lid_column[region] < 0]
        keep = np.isin(region, region_free)
        lid_column[region_free] = muscles.index(lid.name)
        lid_centre[region_free] = centre
        lid_delta[region_free] = delta[keep]
        if lid.levator:
            lid_raise_column[region_free] = muscles.index(lid.levator)
            lid_raise_delta[region_free] = raised[keep]
        if lid.gaze:
            columns = [muscles.index(g) for g in lid.gaze]
            lid_look_column[region_free] = columns
            lid_look_delta[region_free] = looks[keep]
            gaze_column[0 if centre[0] > 0 else 1] = columns
        drive_column[edge] = muscles.index(lid.name)
        drive_weight[edge] = 1.0
    # the contact pairs, upper over lower, and the tilt of the plane each part meets across
    parts = [(muscles.jaw.upper, muscles.jaw.lower, muscles.jaw.contact_tilt)] if muscles.jaw is not None else []
    parts += [(lid.upper, lid.lower, 0.0) for lid in muscles.eyelids]
    upper = np.concatenate([np.zeros(0, dtype=np.int64)] + [up for up, _, _ in parts])
    lower = np.concatenate([np.zeros(0, dtype=np.int64)] + [low for _, low, _ in parts])
    normal = np.concatenate([np.zeros((0, 3))] + [np.tile([0.0, np.cos(tilt), -np.sin(tilt)], (len(up), 1))
                                                 for up, _, tilt in parts])
    gap = np.minimum(CONTACT_GAP, np.einsum("kd,kd->k", mesh.vertices[upper] - mesh.vertices[lower], normal))
    lips = np.arange(len(upper)) < (len(muscles.jaw.upper) if muscles.jaw is not None else 0)  # the jaw's pairs first
    return Rig(jaw_column, jaw_weight, hinge, axis, jaw_max, lip_shift_column, lip_shift, lip_roll_column, lip_roll,
               lip_roll_pivot, np.radians(LIP_ROLL_ANGLE), pressure_column, pressure_weight, pressure, seal_column, seal,
               glide_column, glide, lid_column, lid_centre, lid_delta, lid_raise_column, lid_raise_delta, lid_look_column,
               lid_look_delta, gaze_column, drive_column, drive_weight, upper, lower, lips, normal, gap)
