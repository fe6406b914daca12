"""Lips and lids kept apart: a position projection after each step, so the two lips (and
the two lids) meet at their contact gap and never pass through each other.
"""


from numba import njit

from ..config import NUMBA_OPTIONS


@njit(**NUMBA_OPTIONS)
def _contacts(model, state):
    """Lips and lids do not pass through each other: each pair (upper, lower) is kept at
    least its gap apart along its contact normal n (straight up for the lids, turned back
    for the lips: facesim.physics.rig), by moving both half the overlap along n and giving them
    their mean velocity along n (an inelastic contact; a single-layer mesh has no
    collisions). Across n they slide freely."""
    x, v, pinned = state.x, state.v, model.pinned
    for k in range(model.contact_upper.shape[0]):
        u = model.contact_upper[k]
        l = model.contact_lower[k]
        n = model.contact_normal[k]
        overlap = model.contact_gap[k]
        for d in range(3):
            overlap -= n[d] * (x[u, d] - x[l, d])
        if overlap <= 0.0:
            continue
        share_u = 0.0 if pinned[u] else (1.0 if pinned[l] else 0.5)
        share_l = 0.0 if pinned[l] else 1.0 - share_u
        vn_u = 0.0
        vn_l = 0.0
        for d in range(3):
            x[u, d] += share_u * overlap * n[d]
            x[l, d] -= share_l * overlap * n[d]
            vn_u += n[d] * v[u, d]
            vn_l += n[d] * v[l, d]
        if vn_u < vn_l:
            mean = 0.5 * (vn_u + vn_l)
            for d in range(3):
                v[u, d] += ((0.0 if pinned[u] else mean) - vn_u) * n[d]
                v[l, d] += ((0.0 if pinned[l] else mean) - vn_l) * n[d]
