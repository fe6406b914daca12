"""The helpers every force term shares: finiteness under ``fastmath``, the non-linear
coefficient of eq. 3.6 and 3.7, the links of the whole stiffness K that an implicit solver
needs (facesim.physics.arrays.Forces), the fixed slices a parallel term scatters by, and a
branch-free arctangent for the muscles' projection (eq. 3.21).

The springs, the edge repulsion, the bending, the hypodermis, the muscles' frame, their
flood fills and each muscle's region run on every core for a large mesh (``prange``,
facesim.config.PARALLEL_FROM): a link term scatters by ``CHUNKS`` fixed slices of its
links into buffers of their own, summed per vertex in slice order (``_gather_parts``), and
the fills split the muscles by fixed slices (``_find_regions``), so the bits do not
depend on the thread count. Inside a parallel loop every array is written through a local
name: Numba 0.68 drops writes made there through a tuple's field (``forces.force[i] =
...``; measured), and takes no tuple nested in another (so ``Forces`` is flat). Nor does
a parallel loop read the model: Numba hands a loop every tuple its body names, whole,
and the model's 67 fields cost each loop about 3 s of compiling (a one-line loop: 3.9 s
against 1.0 with its one array taken out first) and 0.6 µs at each start. A term takes
out what it reads before its loop, as locals or as a small tuple of its own
(``_spring_fields``, ``_repulsion_fields``, ``_muscle_fields``, ``_ring_fields``,
``_links``): compiling every kernel went 143 -> 79 s (2026-12-03, AMD EPYC). Those are
plain tuples, read by position as each one's docstring lists: named tuples built inside
a parallel kernel and handed to its loop crash Numba 0.68's array analysis (IndexError
in _gen_shape_call; tried).

Numba's cache does not see a change in a callee's file (facesim.config keys it by a hash
of facesim's code).
"""

import math

import numpy as np
from numba import njit, prange

from ..config import CHUNKS, LENGTH_EPS, NUMBA_OPTIONS, PARALLEL_OPTIONS

#: The exponent bits of a float64: all set for inf and NaN.
EXPONENT = np.int64(0x7FF0000000000000)


@njit(**NUMBA_OPTIONS)
def _not_finite(a):
    """The first row of ``a`` (rows, 3), C-contiguous float64, holding an inf or a NaN, or
    -1. Reads the exponent bits: ``fastmath`` lets the compiler assume every float is
    finite and drop ``math.isfinite``, but not an integer test."""
    bits = a.reshape(-1).view(np.int64)
    for k in range(bits.shape[0]):
        if bits[k] & EXPONENT == EXPONENT:
            return k // a.shape[1]
    return -1


@njit(**NUMBA_OPTIONS)
def _copy_rows(source, out):
    """out[:] = source for two (rows, 3) arrays, as a loop: Numba's slice assignment
    checks the shapes with an error message it formats, and compiling that message
    (its strings' kernels) cost a render compiling from nothing about 3 s (2.65 s
    inclusive by Numba's compile events, 2026-12-08)."""
    for i in range(source.shape[0]):
        for d in range(3):
            out[i, d] = source[i, d]


@njit(**NUMBA_OPTIONS)
def _squarable(exponent):
    """Whether ``_power`` raises to ``exponent`` by squaring: a whole number, 0 to 127."""
    return exponent == math.floor(exponent) and 0.0 <= exponent <= 127.0


@njit(**NUMBA_OPTIONS)
def _power(base, exponent, squarable):
    """base ** exponent, by repeated squaring when ``squarable`` (``_squarable``: the
    thesis's γ = ζ = 5), several times faster than the general pow in the inner loops.
    The squarings are a fixed count of steps without a branch, and ``squarable`` is the
    same for a whole loop, so the compiler can take the test out of the loop (measured
    on 2026-12-02, the springs' loop alone at 27,614 vertices: 8 ns a vertex)."""
    if squarable:
        result = 1.0
        e = int(exponent)
        for _ in range(7):
            result *= base if e & 1 else 1.0
            base *= base
            e >>= 1
        return result
    return base**exponent


@njit(**NUMBA_OPTIONS)
def _nonlinear_coefficient(length, rest, k0, exponent, unit, squarable):
    """The g of eq. 3.17 (h with ζ), -(1 + ((|X| - d) / u)²)^γ k0 (|X| - d) / |X|, and the
    derivative of the tension φ = -g |X| = k0 (1 + s²)^γ (|X| - d), s = (|X| - d) / u:
    dφ/d|X| = k0 (1 + s²)^(γ-1) (1 + (2γ + 1) s²), the stiffness along the link. The
    thesis's stretch is in cm (u = 1); on a finer mesh of the same face u is its edge
    length relative to the default face's, so the same strain stiffens the same way.
    ``squarable``: ``_squarable(exponent - 1)``, found once per loop."""
    stretch = length - rest
    relative = stretch / unit
    square = relative * relative
    factor = _power(1.0 + square, exponent - 1.0, squarable)
    g = -factor * (1.0 + square) * k0 * stretch / max(length, LENGTH_EPS)
    return g, k0 * factor * (1.0 + (2.0 * exponent + 1.0) * square)


@njit(**dict(NUMBA_OPTIONS, inline="always"))
def _links(forces):
    """The arrays of K's links (``Forces``), as the link terms' loops are handed them
    (module docstring)."""
    return forces.node, forces.weight, forces.axis, forces.along, forces.across


@njit(**NUMBA_OPTIONS)
def _set_link(links, l, i, j, k, wi, wj, wk, dx, dy, dz, length, g, along):
    """Link l of K (``_links``): nodes i, j, k with weights (the fourth node unused),
    axis (dx, dy, dz) / length, the tension's derivative ``along`` and -g (the tension
    over the length, eq. 3.17's g with its sign turned) across, clamped at 0."""
    node, weight, axis, along_of, across_of = links
    node[l, 0] = i
    node[l, 1] = j
    node[l, 2] = k
    node[l, 3] = k
    weight[l, 0] = wi
    weight[l, 1] = wj
    weight[l, 2] = wk
    weight[l, 3] = 0.0
    inverse = 1.0 / max(length, LENGTH_EPS)
    axis[l, 0] = dx * inverse
    axis[l, 1] = dy * inverse
    axis[l, 2] = dz * inverse
    along_of[l] = along
    across_of[l] = max(-g, 0.0)


@njit(**NUMBA_OPTIONS)
def _link_extension(node, weight, l, p):
    """Σ_k w_k p_node[l, k], link l's extension (``Forces``) in the vectors ``p`` (n, 3)."""
    ux = 0.0
    uy = 0.0
    uz = 0.0
    for k in range(4):
        w = weight[l, k]
        n = node[l, k]
        ux += w * p[n, 0]
        uy += w * p[n, 1]
        uz += w * p[n, 2]
    return ux, uy, uz


@njit(**NUMBA_OPTIONS)
def _link_spread(node, weight, l, scale, bx, by, bz, out):
    """out[node[l, k]] += scale w_k b for link l's nodes: a vector b acting on its
    extension, carried back to the vertices (the transpose of ``_link_extension``)."""
    for k in range(4):
        w = scale * weight[l, k]
        n = node[l, k]
        out[n, 0] += w * bx
        out[n, 1] += w * by
        out[n, 2] += w * bz


@njit(**NUMBA_OPTIONS)
def _chunk(c, count):
    """Slice c of ``CHUNKS`` of range(count): its first and its end."""
    return c * count // CHUNKS, (c + 1) * count // CHUNKS


@njit(**PARALLEL_OPTIONS)
def _gather_parts(forces):
    """Add the link terms' slices into ``force`` and ``stiffness`` in slice order, and
    zero them: the same sums on any number of threads."""
    force, stiffness, part = forces.force, forces.stiffness, forces.part
    for i in prange(force.shape[0]):
        for c in range(CHUNKS):
            for d in range(3):
                force[i, d] += part[c, i, d]
            stiffness[i] += part[c, i, 3]
            for d in range(4):
                part[c, i, d] = 0.0


def _arctangent_series(degree=10):
    """Coefficients c of atan(r) = r Σ c_k r^2k on |r| ≤ tan(π/8), interpolated at
    Chebyshev points in r² (numpy.polynomial): within 2e-15 of numpy's arctan there."""
    from numpy.polynomial import Chebyshev, Polynomial

    def over_r(s):
        r = np.sqrt(s)
        return np.where(r > 0.0, np.arctan(r) / np.where(r > 0.0, r, 1.0), 1.0)

    bound = math.tan(math.pi / 8.0) ** 2
    return tuple(float(c) for c in Chebyshev.interpolate(over_r, degree, domain=[0.0, bound]).convert(kind=Polynomial).coef)


ARCTANGENT_SERIES = _arctangent_series()


TAN_PI_8 = math.tan(math.pi / 8.0)


@njit(**NUMBA_OPTIONS)
def _atan2(y, x):
    """atan2(y, x) without a branch or a call (math.atan2 is a call to libm, and Numba's
    vector maths library is not in its wheels), written for vector lanes, although LLVM
    compiles the muscles' frame loop to scalar arithmetic (read from its code on
    2026-12-03): the gain is the call and the branches saved:
    the ratio of the smaller to the larger magnitude, reduced to |r| ≤ tan(π/8) by
    atan r = π/4 + atan((r - 1) / (r + 1)), ``ARCTANGENT_SERIES``, then the octant.
    Within 4e-15 (relative) of numpy's arctan2, signed zeros aside."""
    ax, ay = abs(x), abs(y)
    low, high = min(ax, ay), max(ax, ay)
    r = low / high if high > 0.0 else 0.0
    reduced = r > TAN_PI_8
    r = (r - 1.0) / (r + 1.0) if reduced else r
    s = r * r
    series = 0.0
    for k in range(len(ARCTANGENT_SERIES) - 1, -1, -1):
        series = series * s + ARCTANGENT_SERIES[k]
    angle = r * series + (0.25 * math.pi if reduced else 0.0)
    angle = 0.5 * math.pi - angle if ay > ax else angle
    angle = math.pi - angle if x < 0.0 else angle
    return math.copysign(angle, y)


@njit(**NUMBA_OPTIONS)
def _frame_point(x, i, axis_x, axis_z, radius, uv_projection, out, row):
    """Vertex i in the muscles' frame, into ``out[row]``: (R atan2(x - cx, z - cz), y, 0)
    of eq. 3.21, or 3D. With ``_atan2`` instead of libm's (the muscles' frame, one core
    at 27,614 vertices: 11 -> 4.5 ns a vertex, 2026-12-02)."""
    if uv_projection:
        out[row, 0] = radius * _atan2(x[i, 0] - axis_x, x[i, 2] - axis_z)
        out[row, 1] = x[i, 1]
        out[row, 2] = 0.0
    else:
        for d in range(3):
            out[row, d] = x[i, d]
