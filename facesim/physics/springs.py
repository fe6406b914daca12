"""The skin's non-linear springs, eq. 3.6 (their g, eq. 3.17, as stiffness): one spring per
mesh edge, its force and, for the implicit step, its link of K.

The springs and the edge repulsion take two passes: a loop over their springs or
triangles that computes each one's force into arrays of its own, then a loop adding
those forces to the vertices. On one core at 27,614 vertices that made the springs
35 -> 31 ns a vertex and the edge repulsion 103 -> 51 (2026-12-02, an Intel Xeon). That
first loop, reading the ends' positions through an index, stayed scalar (no packed
square root or division in the code LLVM makes; its remark: "cannot identify array
bounds"). For the thesis's update it now runs on vector lanes (2026-12-03, AMD EPYC,
8 doubles a lane): the ends or corners are gathered into rows first (``spring_delta``,
``corner_position``), and the loop then reads and writes rows alone, every array handed
to it as an argument of its own. LLVM checks every pair of arrays it cannot prove apart
before it vectorises a loop, and gives up past a few ("too many memory checks needed");
an array reached through a tuple is one it cannot prove apart, a separate argument of a
parallel loop is one it can (``_spring_tensions``, ``_repulsion_corners``). Springs 56 ->
41 ns a vertex, edge repulsion 168 -> 97, at 27,614 vertices on one thread; 60 -> 45 and
129 -> 51 on the Hopper face. The implicit step's loops write the links of K as well
(``_spring_links``, ``_repulsion_triangle`` with its links), stay scalar and read the
positions where they are: a gathering pass made them slower. On the Hopper face the
implicit step's force terms took 112 µs a step so, 129 with the g-only loop and a
second loop for the links, and 106 as one scalar loop per term that also scattered
(measured on 2026-12-02).
Numba's cache does not see a change in a callee's file (facesim.config keys it by a hash
of facesim's code).
"""

import math

from numba import njit, prange

from ..config import CHUNKS, NUMBA_OPTIONS, PARALLEL_OPTIONS
from .numerics import _chunk, _gather_parts, _links, _nonlinear_coefficient, _set_link, _squarable


@njit(**dict(NUMBA_OPTIONS, inline="always"))
def _spring_fields(model):
    """What the springs read of the model (module docstring): k0, exponent and length
    unit, in this order (the rest lengths reach the loops as an array of their own, as
    the edge repulsion's: ``_repulsion_fields``)."""
    return model.stiffness, model.nonlinearity, model.length_unit


@njit(**dict(NUMBA_OPTIONS, inline="always"))
def _spring(springs, rest_length, s, dx, dy, dz, squarable):
    """Spring s of eq. 3.6 at the predicted positions, X_i* - X_j* = (dx, dy, dz): its
    length, its g (eq. 3.17) and its stiffness along (``_nonlinear_coefficient``)."""
    k0, exponent, unit = springs
    length = math.sqrt(dx * dx + dy * dy + dz * dz)
    g, along = _nonlinear_coefficient(length, rest_length[s], k0, exponent, unit, squarable)
    return length, g, along


@njit(**PARALLEL_OPTIONS)
def _spring_forces(model, xp, forces):
    """Springs on the mesh edges, eq. 3.6, at the predicted positions: F_i = g (X_i* - X_j*),
    its g into both ends' stiffness (eq. 3.17), and, for the implicit step, spring s as
    link s of K. Every spring's g into ``tension``, then each spring's force added to its
    ends (``_scatter_springs``).

    The thesis's update gathers the ends first and then takes every g in a loop over
    rows alone (``_spring_tensions``), which LLVM puts on vector lanes; the implicit step
    gathers them in the loop that also writes the links (``_spring_links``), which stays
    scalar: a pass of its own for the gathering made that loop slower, not faster
    (measured on 2026-12-03: 56 -> 41 ns a vertex for the thesis's update, 68 -> 84 for
    the implicit step, at 27,614 vertices on one thread)."""
    end, tension, delta, springs = model.spring_end, forces.tension, forces.spring_delta, _spring_fields(model)
    rest_length = model.spring_rest_length
    squarable = _squarable(model.nonlinearity - 1.0)
    if model.implicit:
        _spring_links(springs, rest_length, end, xp, squarable, forces)
    else:
        for s in prange(tension.shape[0]):  # the ends gathered, so that the next loop reads rows
            i = end[0, s]
            j = end[1, s]
            for d in range(3):
                delta[d, s] = xp[i, d] - xp[j, d]
        _spring_tensions(springs, rest_length, delta, squarable, tension)
    _scatter_springs(model, xp, forces)


@njit(**PARALLEL_OPTIONS)
def _spring_tensions(springs, rest_length, delta, squarable, tension):
    """Every spring's g into ``tension`` from the rows of ``delta``, for the thesis's
    update: one loop per kind of exponent, so that no call to pow is left in it, and
    every array handed to it alone (an array inside a tuple costs the loop its vector
    lanes: ``_repulsion_fields``)."""
    if squarable:
        for s in prange(tension.shape[0]):
            tension[s] = _spring(springs, rest_length, s, delta[0, s], delta[1, s], delta[2, s], True)[1]
    else:
        for s in prange(tension.shape[0]):
            tension[s] = _spring(springs, rest_length, s, delta[0, s], delta[1, s], delta[2, s], False)[1]


@njit(**PARALLEL_OPTIONS)
def _spring_links(springs, rest_length, end, xp, squarable, forces):
    """Every spring's g into ``tension`` and spring s as link s of K (``Forces``), for the
    implicit step: a loop of its own, so that the thesis's update, which needs only the
    g, does not write the links."""
    tension, links = forces.tension, _links(forces)
    for s in prange(tension.shape[0]):
        i = end[0, s]
        j = end[1, s]
        dx = xp[i, 0] - xp[j, 0]
        dy = xp[i, 1] - xp[j, 1]
        dz = xp[i, 2] - xp[j, 2]
        length, g, along = _spring(springs, rest_length, s, dx, dy, dz, squarable)
        tension[s] = g
        _set_link(links, s, i, j, j, 1.0, -1.0, 0.0, dx, dy, dz, length, g, along)


@njit(**PARALLEL_OPTIONS)
def _scatter_springs(model, xp, forces):
    """Each spring's force g (X_i* - X_j*) added to its ends and g to their stiffness, by
    ``CHUNKS`` fixed slices of the springs (``_gather_parts``). X_i* - X_j* is taken again
    here rather than read from ``spring_delta``, which the implicit step does not write
    (writing it there made that step's springs slower)."""
    end, tension, parts = model.spring_end, forces.tension, forces.part
    for c in prange(CHUNKS):
        part = parts[c]
        first, stop = _chunk(c, end.shape[1])
        for s in range(first, stop):
            i = end[0, s]
            j = end[1, s]
            g = tension[s]
            for d in range(3):
                pull = g * (xp[i, d] - xp[j, d])
                part[i, d] += pull
                part[j, d] -= pull
            part[i, 3] += g
            part[j, 3] += g
    _gather_parts(forces)
