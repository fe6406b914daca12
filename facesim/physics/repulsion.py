"""Edge repulsion, eq. 3.7 (its h, eq. 3.17, as stiffness): each triangle's vertices kept
from the opposite edges, the term that keeps elements from overlapping (thesis fig. 3.16).
Two passes like the springs (facesim.physics.springs): each triangle's corner forces into
rows of their own, then added to the vertices.
"""

import math

from numba import njit, prange

from ..config import CHUNKS, LENGTH_EPS, NUMBA_OPTIONS, PARALLEL_OPTIONS
from .numerics import _chunk, _gather_parts, _links, _nonlinear_coefficient, _set_link, _squarable


@njit(**dict(NUMBA_OPTIONS, inline="always"))
def _repulsion_fields(model):
    """What the edge repulsion reads of the model (module docstring): k0, exponent and
    length unit, in this order (the rest distances, ``corner_rest_distance``, reach the
    loops as an array of their own: an array inside a tuple costs a loop its vector
    lanes, LLVM then checking it against every other for overlap)."""
    return model.stiffness, model.repulsion_nonlinearity, model.length_unit


@njit(**dict(NUMBA_OPTIONS, inline="always"))
def _repulsion_pair(pairs, rest_distance, k, triangle, squarable, ix, iy, iz, ax, ay, az, bx, by, bz):
    """Eq. 3.7 for pair k of a triangle: the vertex at (ix, iy, iz) against the line through
    the edge from (ax, ay, az) to (bx, by, bz), its foot P_k = a + t (b - a). Returns h
    (eq. 3.17) and the stiffness along, t, X_i - P_k and its length. Inlined: passing the
    model's tuple to a call per pair costs more than the pair (measured: 18 times slower)."""
    k0, exponent, unit = pairs
    ex = bx - ax
    ey = by - ay
    ez = bz - az
    t = ((ix - ax) * ex + (iy - ay) * ey + (iz - az) * ez) / max(ex * ex + ey * ey + ez * ez, LENGTH_EPS)
    dx = ix - ax - t * ex
    dy = iy - ay - t * ey
    dz = iz - az - t * ez
    distance = math.sqrt(dx * dx + dy * dy + dz * dz)
    h, along = _nonlinear_coefficient(distance, rest_distance[k, triangle], k0, exponent, unit, squarable)
    return h, along, t, dx, dy, dz, distance


@njit(**dict(NUMBA_OPTIONS, inline="always"))
def _repulsion_triangle(pairs, rest_distance, t, ax, ay, az, bx, by, bz, cx, cy, cz, squarable, out, stiffness, links,
                        first_link, a, b, c, write_links):
    """Triangle t's three pairs of eq. 3.7 (``_edge_repulsion_forces``), its corners a, b,
    c at (ax, ay, az), (bx, by, bz) and (cx, cy, cz): each corner's own R and its shares of
    the reactions on the two edges it ends, into ``out`` (9, t) and its h into
    ``stiffness`` (3, t); with ``write_links``, the pairs as links of K too (``_links``),
    from link ``first_link`` + 3t."""
    ha, la, ta, rax, ray, raz, da = _repulsion_pair(pairs, rest_distance, 0, t, squarable, ax, ay, az, bx, by, bz, cx, cy, cz)
    hb, lb, tb, rbx, rby, rbz, db = _repulsion_pair(pairs, rest_distance, 1, t, squarable, bx, by, bz, cx, cy, cz, ax, ay, az)
    hc, lc, tc, rcx, rcy, rcz, dc = _repulsion_pair(pairs, rest_distance, 2, t, squarable, cx, cy, cz, ax, ay, az, bx, by, bz)
    if write_links:  # pair r as link s + r of K, u = X_i - (1 - t) X_a - t X_b with the foot's t held
        l = first_link + 3 * t
        _set_link(links, l, a, b, c, 1.0, ta - 1.0, -ta, rax, ray, raz, da, ha, la)
        _set_link(links, l + 1, b, c, a, 1.0, tb - 1.0, -tb, rbx, rby, rbz, db, hb, lb)
        _set_link(links, l + 2, c, a, b, 1.0, tc - 1.0, -tc, rcx, rcy, rcz, dc, hc, lc)
    stiffness[0, t] = ha
    stiffness[1, t] = hb
    stiffness[2, t] = hc
    # a: its R, and its shares of b's reaction on (c, a) and of c's on (a, b); b and c alike
    out[0, t] = ha * rax - tb * hb * rbx - (1.0 - tc) * hc * rcx
    out[1, t] = ha * ray - tb * hb * rby - (1.0 - tc) * hc * rcy
    out[2, t] = ha * raz - tb * hb * rbz - (1.0 - tc) * hc * rcz
    out[3, t] = hb * rbx - tc * hc * rcx - (1.0 - ta) * ha * rax
    out[4, t] = hb * rby - tc * hc * rcy - (1.0 - ta) * ha * ray
    out[5, t] = hb * rbz - tc * hc * rcz - (1.0 - ta) * ha * raz
    out[6, t] = hc * rcx - ta * ha * rax - (1.0 - tb) * hb * rbx
    out[7, t] = hc * rcy - ta * ha * ray - (1.0 - tb) * hb * rby
    out[8, t] = hc * rcz - ta * ha * raz - (1.0 - tb) * hb * rbz


@njit(**PARALLEL_OPTIONS)
def _edge_repulsion_forces(model, xp, forces):
    """Edge repulsion, eq. 3.7: each vertex is held at its rest altitude above the
    opposite edge of each of its triangles.

    R_ik acts on the vertex (with h as its stiffness, eq. 3.17) and its reaction -R_ik on
    the edge's ends, split (1 - t) : t by where the foot P_k lies. The thesis leaves the
    reaction out, but without it the term is not conservative and a perturbed face at
    rest never settles (measured: kinetic energy grows); with it the term derives from a
    potential in the point-to-line distance. Pair r is link s + r of K (s springs).

    Two passes, as the springs': triangle t's three pairs (3t, 3t + 1, 3t + 2: its
    corners a, b, c against (b, c), (c, a), (a, b), facesim.physics.model) give each corner its
    own R and its shares of the reactions on the two edges it ends, into
    ``corner_force`` (9, t) and ``corner_stiffness`` (3, t); then the corners' sums are
    added to the vertices (``_scatter_corners``). As the springs' (``_spring_forces``),
    the thesis's update gathers the corners into the rows of ``corner_position`` first,
    and its loop over the triangles, reading and writing rows alone, runs on vector lanes
    (``_repulsion_corners``: 168 -> 97 ns a vertex at 27,614 vertices, one thread,
    2026-12-03); the implicit step's loop, which also writes the links, reads the corners
    where they are.
    """
    if not model.edge_repulsion:
        return
    corner, out, stiffness = model.corner, forces.corner_force, forces.corner_stiffness
    rest_distance = model.corner_rest_distance
    pairs, links, first_link = _repulsion_fields(model), _links(forces), model.spring_end.shape[1]
    squarable = _squarable(model.repulsion_nonlinearity - 1.0)
    if model.implicit:  # a loop that also writes the links
        for t in prange(corner.shape[1]):
            a = corner[0, t]
            b = corner[1, t]
            c = corner[2, t]
            _repulsion_triangle(pairs, rest_distance, t, xp[a, 0], xp[a, 1], xp[a, 2], xp[b, 0], xp[b, 1], xp[b, 2],
                                xp[c, 0], xp[c, 1], xp[c, 2], squarable, out, stiffness, links, first_link, a, b, c, True)
    else:
        position = forces.corner_position
        for t in prange(corner.shape[1]):  # the corners gathered, so that the next loop reads rows
            for k in range(3):
                v = corner[k, t]
                for d in range(3):
                    position[3 * k + d, t] = xp[v, d]
        _repulsion_corners(pairs, rest_distance, position, squarable, out, stiffness)
    _scatter_corners(model, forces)


@njit(**PARALLEL_OPTIONS)
def _repulsion_corners(pairs, rest_distance, position, squarable, out, stiffness):
    """Every triangle's corner forces and h (``_repulsion_triangle``) from the rows of
    ``position`` (9, t), for the thesis's update: a loop that reads and writes rows
    alone, one per kind of exponent (``_spring_tensions``)."""
    if squarable:
        for t in prange(position.shape[1]):
            _repulsion_row(pairs, rest_distance, position, t, True, out, stiffness)
    else:
        for t in prange(position.shape[1]):
            _repulsion_row(pairs, rest_distance, position, t, False, out, stiffness)


@njit(**dict(NUMBA_OPTIONS, inline="always"))
def _repulsion_row(pairs, rest_distance, position, t, squarable, out, stiffness):
    """``_repulsion_triangle`` for triangle t, its corners read from the rows of
    ``position`` (9, t), without links (the thesis's update: no link is written, so the
    links' arguments are placeholders)."""
    _repulsion_triangle(pairs, rest_distance, t, position[0, t], position[1, t], position[2, t], position[3, t],
                        position[4, t], position[5, t], position[6, t], position[7, t], position[8, t], squarable, out,
                        stiffness, pairs, 0, 0, 0, 0, False)


@njit(**PARALLEL_OPTIONS)
def _scatter_corners(model, forces):
    """Each triangle's corner forces and stiffness (``_edge_repulsion_forces``) added to
    its vertices, by ``CHUNKS`` fixed slices of the triangles (``_gather_parts``)."""
    corner, out, corner_stiffness, parts = model.corner, forces.corner_force, forces.corner_stiffness, forces.part
    for c in prange(CHUNKS):
        part = parts[c]
        first, stop = _chunk(c, corner.shape[1])
        for t in range(first, stop):
            for k in range(3):
                v = corner[k, t]
                for d in range(3):
                    part[v, d] += out[3 * k + d, t]
                part[v, 3] += corner_stiffness[k, t]
    _gather_parts(forces)
