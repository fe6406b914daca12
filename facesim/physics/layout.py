"""What the simulation's kernels read and write, in the shape of warp.sim: an immutable
:data:`ModelArrays` (what ``facesim.physics.model.build_model`` makes), a :data:`State`
(positions x and velocities v, what a step reads and writes), a :data:`Control` per frame
(activations, and where the bones put the skin and the muscles' ends), a :data:`Forces`
accumulator every force term adds into, and a :data:`Workspace` for the muscles' regions.

A term adds, at the predicted positions X* (eq. 3.14), its force F_i and, where its force
depends on X_i, the scalar stiffness K_i = Σ ∂F_i/∂X_i along the spring (the Σ g + Σ h of
eq. 3.19; negative for a stretched spring), and damping terms their C_i = -∂F_i/∂V_i.
A solver turns these into new velocities.
"""

from collections import namedtuple

import numpy as np

from ..config import CHUNKS

#: The model's arrays and constants, as the kernels read them (facesim.physics.model.Model.arrays).
#: Shapes: n vertices, t triangles, s springs, r repulsion pairs, M muscles; the jaw and
#: eyelid fields are facesim.physics.rig.Rig's, the material's are facesim.physics.material.Material's. The
#: pairs' rest distances are Model.repulsion_rest_distance by corner (3, t), pair 3t + k
#: at (k, t), for the vector loop of ``_repulsion_corners``.
ModelArrays = namedtuple("ModelArrays", [
    "rest_position", "faces", "rest_normal", "rest_area", "rest_against", "pinned", "tie",
    "neighbour_start", "neighbour_index", "ring_start", "ring_a", "ring_b",
    "spring_indices", "spring_end", "corner", "spring_rest_length", "repulsion_vertex", "repulsion_edge",
    "corner_rest_distance",
    "hinge", "hinge_weight",
    "muscle_kind", "muscle_axes", "muscle_insertion", "muscle_centre_start", "muscle_centre_index",
    "muscle_cos_zone", "muscle_r", "muscle_r_max", "muscle_force", "muscle_protrusion", "rest_vertex_normal", "axis_x", "axis_z", "radius",
    "jaw_column", "jaw_weight", "jaw_hinge", "jaw_axis", "jaw_max", "lip_shift_column", "lip_shift", "lip_roll_column", "lip_roll", "lip_roll_pivot", "lip_roll_angle", "pressure_column", "pressure_weight", "pressure", "jaw_seal_column", "jaw_seal", "jaw_glide_column", "jaw_glide", "lid_column", "lid_centre", "lid_delta",
    "lid_raise_column", "lid_raise_delta", "lid_look_column", "lid_look_delta", "gaze_column", "drive_column", "drive_weight", "contact_upper", "contact_lower", "contact_lips", "contact_normal", "contact_gap",
    "mass", "damping", "stiffness", "nonlinearity", "repulsion_nonlinearity", "length_unit", "tissue", "drive",
    "bending", "edge_repulsion", "uv_projection", "attached_regions", "implicit", "iterations", "tolerance",
])


#: What a step reads and advances: positions x and velocities v, (n, 3) each.
State = namedtuple("State", ["x", "v"])


#: A frame's controls: ``activation`` (muscles then jaw and lids, one row of the
#: activation table); ``target`` (n, 3) where the bones take each vertex and ``hold`` (n,)
#: the drive holding it there; the muscles' ends ``origin`` and ``insertion_point`` (M, 3)
#: in the frame they act in, from the same bones (``_rig_control``).
Control = namedtuple("Control", ["activation", "target", "hold", "origin", "insertion_point"])


#: What the force terms add into: ``force`` (n, 3), ``stiffness`` (n,) the K_i and
#: ``damping`` (n,) the C_i of the module docstring; and the links of the whole stiffness
#: K = -∂F/∂X that an implicit solver needs, where the K_i keep one number per vertex:
#: link l joins the vertices ``node[l]`` (4) with weights ``weight[l]``, its extension
#: u = Σ_k w_k X_node[l, k] (a spring: X_i - X_j; edge repulsion: X_i - P_k; a bending
#: hinge: its four vertices' stencil), and adds w_p w_q B to the 3x3 block (p, q) of K,
#: with B = along a aᵀ + across (I - a aᵀ) for its unit ``axis`` a; ``diagonal`` (n,) adds
#: an isotropic stiffness per vertex (the hypodermis). B is positive semi-definite: along
#: is the derivative of the tension, across the tension over the length, and 0 when
#: compressed (the usual clamp: a compressed spring's sideways instability is left out);
#: a hinge's B is isotropic (along = across). The link terms scatter into ``part``
#: (CHUNKS, n, 4), one slice of the links each, a vertex's force and its stiffness side by
#: side (one cache line: the springs' and corners' scatter and the sums 36.0 -> 33.3 ns a
#: vertex at 27,614), summed per vertex and zeroed after each term (``_gather_parts``). A term's per-link values
#: wait there between its two passes (module docstring): each spring's g in ``tension``
#: (s,), each triangle's corner forces and h in ``corner_force`` (9, t) and
#: ``corner_stiffness`` (3, t); for the thesis's update, what those loops read, gathered
#: into rows first: each spring's X_i* - X_j* in ``spring_delta`` (3, s) and each
#: triangle's corners' positions in ``corner_position`` (9, t). One flat tuple: Numba's
#: parallel loops take no tuple nested in another.
Forces = namedtuple("Forces", ["force", "stiffness", "damping", "node", "weight", "axis", "along", "across", "diagonal",
                               "part", "tension", "corner_force", "corner_stiffness", "spring_delta", "corner_position"])


#: Scratch arrays of the muscle terms: the points in the muscles' frame (n, 3); the flood
#: fills' marks and stacks, one row per slice of the muscles (CHUNKS, n), and the mark of
#: each slice's latest fill (CHUNKS,); a region and its δ (n,) for a fill that finds no
#: room in the store. Each step's regions are found on every core (``_find_regions``)
#: into the store: muscle m's region the ``region_count[m]`` entries of ``kept_vertex``
#: and ``kept_delta`` from ``region_first[m]`` (a count of -1: not found), slice c
#: writing only its share of the store, ``kept[c]`` entries of it in use. Where the
#: regions are evaluated where the bones hold the skin (``attached_regions``), they change
#: only when the bones move, and are kept between steps: ``bones`` (n, 3) the targets
#: they were found at (``known`` (1,): 0 until the first). A workspace serves one model.
Workspace = namedtuple("Workspace", ["frame", "attached", "visited", "stack", "region", "delta", "stamp", "bones", "known",
                                     "region_first", "region_count", "kept_vertex", "kept_delta", "kept"])


#: Room for the regions, in vertices per mesh vertex: a region that does not fit in its
#: slice's share is found alone, on one core, at every step.
KEPT_REGIONS = 8


def workspace(model: ModelArrays) -> Workspace:
    n, muscles = model.rest_position.shape[0], model.muscle_kind.shape[0]
    room = KEPT_REGIONS * n
    return Workspace(np.empty((n, 3)), np.empty((n, 3)), np.zeros((CHUNKS, n), dtype=np.int64),
                     np.empty((CHUNKS, n), dtype=np.int64), np.empty(n, dtype=np.int64), np.empty(n),
                     np.zeros(CHUNKS, dtype=np.int64), np.empty((n, 3)), np.zeros(1, dtype=np.int64),
                     np.zeros(muscles, dtype=np.int64), np.full(muscles, -1, dtype=np.int64),
                     np.empty(room, dtype=np.int64), np.empty(room), np.zeros(CHUNKS, dtype=np.int64))


def forces(model: ModelArrays) -> Forces:
    """Zeroed accumulators for a model: one link per spring, then one per repulsion pair,
    then one per bending hinge."""
    n = model.rest_position.shape[0]
    count = model.spring_indices.shape[0] + model.repulsion_vertex.shape[0] + model.hinge.shape[0]
    triangles = model.faces.shape[0]
    return Forces(np.zeros((n, 3)), np.zeros(n), np.zeros(n), np.zeros((count, 4), dtype=np.int64), np.zeros((count, 4)),
                  np.zeros((count, 3)), np.zeros(count), np.zeros(count), np.zeros(n), np.zeros((CHUNKS, n, 4)),
                  np.zeros(model.spring_indices.shape[0]), np.zeros((9, triangles)),
                  np.zeros((3, triangles)), np.zeros((3, model.spring_indices.shape[0])), np.zeros((9, triangles)))


#: Status codes returned by ``facesim.physics.solver._simulate``.
OK, NOT_FINITE, INVERTED, RUNAWAY = 0, 1, 2, 3


