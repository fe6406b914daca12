"""Lips and lids kept apart: a position projection after each step, so the two lips (and
the two lids) meet at their contact gap and never pass through each other; and sealed
lips kept together: the orbicularis oris holding them shut (the jaw rig's ``lip_seal``)
stops them parting further than the rig puts them, against the air of a puffed mouth.
"""


import math

from numba import njit

from ..config import NUMBA_OPTIONS

#: How far apart (cm) lips sealed with s < 1 may part beyond where the rig puts them:
#: (1 - s) of this. Sealed fully, not at all.
SEAL_SLACK = 1.0
#: How far (cm) a lip rolled in fully (AU28) may pass the other along their contact
#: normal: ICT's mouthRollLower takes the lower lip's edge 1.2 cm back behind the upper's.
ROLL_PASS = 2.0


@njit(**NUMBA_OPTIONS)
def _contacts(model, state, control):
    """Lips and lids do not pass through each other: each pair (upper, lower) is kept at
    least its gap apart along its contact normal n (straight up for the lids, turned back
    for the lips: facesim.physics.rig), by moving both half the overlap along n and giving them
    their mean velocity along n (an inelastic contact; a single-layer mesh has no
    collisions). Across n they slide freely. A lip pair sealed with s > 0 is also kept
    within its gap plus (1 - s) ``SEAL_SLACK`` of where the rig's targets put it relative
    to each other: e = (X_u - X_l) - (T_u - T_l), |e| at most that, both moved half the
    excess toward each other along e (``_held_together``). A lip rolled in (either roll's
    activation r) lets the lips' pairs pass ``ROLL_PASS`` r along n."""
    x, v, pinned = state.x, state.v, model.pinned
    sealed = control.activation[model.jaw_seal_column] if model.jaw_seal_column >= 0 else 0.0
    rolled = 0.0  # a lip rolled in tucks behind the other: the lips' contact lets it pass
    if model.lip_roll_column[0] >= 0:
        rolled = max(control.activation[model.lip_roll_column[0]], control.activation[model.lip_roll_column[1]])
    for k in range(model.contact_upper.shape[0]):
        u = model.contact_upper[k]
        l = model.contact_lower[k]
        n = model.contact_normal[k]
        if sealed > 0.0 and model.contact_lips[k]:
            # within the gap (none where a pair starts within it: the lips' middle crosses the
            # tilted plane at rest) and the seal's slack
            _held_together(x, v, pinned, control.target, u, l, max(model.contact_gap[k], 0.0) + (1.0 - sealed) * SEAL_SLACK)
        overlap = model.contact_gap[k] - (ROLL_PASS * rolled if model.contact_lips[k] else 0.0)
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


@njit(**NUMBA_OPTIONS)
def _held_together(x, v, pinned, target, u, l, reach):
    """Pair (u, l) kept within ``reach`` of where the targets put one relative to the
    other: e = (X_u - X_l) - (T_u - T_l) shortened to ``reach`` when longer, each moving
    half the excess along e (a pinned one keeps still), and their velocities along e
    averaged: held, they move together along it."""
    ex = (x[u, 0] - x[l, 0]) - (target[u, 0] - target[l, 0])
    ey = (x[u, 1] - x[l, 1]) - (target[u, 1] - target[l, 1])
    ez = (x[u, 2] - x[l, 2]) - (target[u, 2] - target[l, 2])
    length = math.sqrt(ex * ex + ey * ey + ez * ez)
    if length <= reach:
        return
    e = (ex / length, ey / length, ez / length)
    excess = length - reach
    share_u = 0.0 if pinned[u] else (1.0 if pinned[l] else 0.5)
    share_l = 0.0 if pinned[l] else 1.0 - share_u
    vn_u = 0.0
    vn_l = 0.0
    for d in range(3):
        x[u, d] -= share_u * excess * e[d]
        x[l, d] += share_l * excess * e[d]
        vn_u += e[d] * v[u, d]
        vn_l += e[d] * v[l, d]
    mean = 0.5 * (vn_u + vn_l)  # held, they move together along e
    for d in range(3):
        v[u, d] += ((0.0 if pinned[u] else mean) - vn_u) * e[d]
        v[l, d] += ((0.0 if pinned[l] else mean) - vn_l) * e[d]
