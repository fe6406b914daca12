"""The hypodermis: springs tying each vertex to where the bones take it
(facesim.physics.rig), and the rig's drive holding the lips' and lids' contours to their
targets. Not in the thesis, where the skin hangs from its pinned rim alone.
"""


from numba import njit, prange

from ..config import PARALLEL_OPTIONS


@njit(**PARALLEL_OPTIONS)
def _tissue_forces(model, xp, control, forces):
    """Hypodermis springs: each vertex tied to its target (its rest position, moved by the
    jaw and eyelids) with stiffness k_t + tie_i + hold_i, the soft tissue that attaches
    skin to bone (tie_i: a tied rim's, the skin beyond the cut, muscles.Pinned). Not in
    the thesis (tissue = 0 is its model); a spring mesh has no bending stiffness, so under
    muscle pull it wrinkles and creeps without ever settling, and these springs give
    every mode a restoring force. ``hold`` holds the skin over the
    mandible and the lid contours to their targets while the jaw and lids move."""
    force, stiffness, diagonal = forces.force, forces.stiffness, forces.diagonal
    tissue, tie, hold, target = model.tissue, model.tie, control.hold, control.target
    for i in prange(xp.shape[0]):
        k = tissue + tie[i] + hold[i]
        stiffness[i] -= k
        diagonal[i] += k
        for d in range(3):
            force[i, d] -= k * (xp[i, d] - target[i, d])
