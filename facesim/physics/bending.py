"""Bending of the skin's displacement: not in the thesis, the quadratic bending energy of
Bergou et al. 2006 over each hinge (two triangles sharing an edge), taken on the
displacement from rest so the rest shape bends nothing.
"""


from numba import njit, prange

from ..config import CHUNKS, PARALLEL_OPTIONS
from .numerics import _chunk, _gather_parts, _link_spread, _links


@njit(**PARALLEL_OPTIONS)
def _bending_forces(model, xp, control, forces):
    """Bending: each interior edge's hinge (its two triangles' four vertices) resists a
    change of the skin's curvature, with the quadratic energy of Bergou, Wardetzky, Harmon,
    Zorin and Grinspun, "A quadratic bending model for inextensible surfaces" (2006),

        E = ½ k_b Σ_e (Σ_k w_ek U_k)²,  U = X - target (each coordinate),

    where w_e is the hinge's cotangent stencil scaled by √(3 / (A_0 + A_1)) at rest
    (facesim.physics.model), so Σ_k w_ek X_k measures the hinge's bend and vanishes on a flat one.
    Bergou et al. apply it to the positions of a flat sheet; a face is curved at rest, so
    here it acts on the displacement from where the bones hold the skin (the rest shape
    moved by the jaw and lids): zero at rest and under the rig, and for the small turns
    of skin under muscles the change of the hinge's bend. Not in the thesis (k_b = 0 is
    its model): a spring lattice has no bending stiffness, so where muscles compress the
    skin it buckles into lumps and its sliver triangles turn over (issue 16). The energy
    is quadratic, so its stiffness k_b w wᵀ (link s + r + e of K) is constant and exact.
    """
    if model.bending == 0.0:
        return
    offset = model.spring_indices.shape[0] + model.repulsion_vertex.shape[0]
    kb, hinge, hinge_weight, target = model.bending, model.hinge, model.hinge_weight, control.target
    node_of, weight_of, axis, along, across = _links(forces)
    parts = forces.part
    for c in prange(CHUNKS):
        part = parts[c]
        first, end = _chunk(c, hinge.shape[0])
        for e in range(first, end):
            l = offset + e
            # the bend w · U summed over the differences U = X - target, not as w · X - w · target
            # (``_link_extension`` twice): the weights reach 100 and the positions 10 cm, and the
            # two sums would cancel to 1e-9
            bx = 0.0
            by = 0.0
            bz = 0.0
            for k in range(4):
                node = hinge[e, k]
                w = hinge_weight[e, k]
                part[node, 3] -= kb * w * w
                node_of[l, k] = node
                weight_of[l, k] = w
                bx += w * (xp[node, 0] - target[node, 0])
                by += w * (xp[node, 1] - target[node, 1])
                bz += w * (xp[node, 2] - target[node, 2])
            axis[l, 0] = 1.0
            axis[l, 1] = 0.0
            axis[l, 2] = 0.0
            along[l] = kb
            across[l] = kb
            _link_spread(node_of, weight_of, l, -kb, bx, by, bz, part)  # F = -k_b w (w · U)
    _gather_parts(forces)
