"""What is done to a frame's arrays on the CPU, in Numba: the vertex buffer interleaved
(positions and normals, ``_interleave``), and antialiasing, by averaging a supersampled
frame's blocks (``_downsample``) or by blending across the edges of the frame as drawn
(``_smooth_edges``, an FXAA-style filter on a luma plane).
"""

from __future__ import annotations

import numpy as np
from numba import njit, prange

from ..config import NUMBA_OPTIONS, PARALLEL_OPTIONS
from .settings import EDGE_CONTRAST, EDGE_FLOOR


@njit(**NUMBA_OPTIONS)
def _interleave(x, normals, rows, attribute, out):
    """pyrender's interleaved vertex of the vertices ``rows`` of a part, in float32 into
    ``out``: position, normal, then its uv or colour (``attribute``, one row a vertex)."""
    for k in range(rows.shape[0]):
        i = rows[k]
        for d in range(3):
            out[k, d] = x[i, d]
            out[k, 3 + d] = normals[i, d]
        for d in range(attribute.shape[1]):
            out[k, 6 + d] = attribute[k, d]


@njit(**NUMBA_OPTIONS)
def _downsample(image, factor, out):
    """The mean of each ``factor`` x ``factor`` block of ``image`` (H, W, C) uint8 into
    ``out`` (H / factor, W / factor, C): a box filter, 4 samples per pixel at factor 2."""
    count = factor * factor
    for y in range(out.shape[0]):
        for x in range(out.shape[1]):
            for c in range(out.shape[2]):
                total = count // 2
                for dy in range(factor):
                    for dx in range(factor):
                        total += image[factor * y + dy, factor * x + dx, c]
                out[y, x, c] = total // count


@njit(**NUMBA_OPTIONS)
def _luma(image, y, x):
    """Rec. 601 luma of pixel (y, x) of an RGB(A) uint8 image."""
    return 0.299 * image[y, x, 0] + 0.587 * image[y, x, 1] + 0.114 * image[y, x, 2]


@njit(**NUMBA_OPTIONS)
def _near(plane, y, x):
    """plane[y, x], its coordinates clamped to the plane."""
    return plane[min(max(y, 0), plane.shape[0] - 1), min(max(x, 0), plane.shape[1] - 1)]


@njit(**dict(PARALLEL_OPTIONS, fastmath=False))
def _smooth_edges(image, out):
    """Antialiasing after drawing: the sub-pixel pass of FXAA (T. Lottes, "FXAA", NVIDIA
    white paper, 2009) on ``image`` (H, W, C) uint8 into ``out``. Where a pixel's 3x3
    luma spans enough (``EDGE_CONTRAST``, ``EDGE_FLOOR``), the edge runs across the
    steeper of its two second differences; the pixel is blended toward its neighbour
    on the side of the larger step, by s² for s = smoothstep(|mean of the 3x3 - M| / span):
    a pixel lying as a step between its neighbours moves most, one on a smooth ramp not
    at all. Every channel, alpha too (``--onto``), by the same weight. Measured on the
    head's smile at 512², against 4 samples per pixel: 41.5 dB unfiltered, 44.3 dB
    filtered; its cost is a few milliseconds against the 30 ms more that supersampling
    draws. Compiled without ``fastmath``: with it, a dataset sample's bytes differed
    between a process that compiled the kernel and one that loaded it from Numba's cache
    (measured on a cold cache; the lumas tie often, at whole levels, and a reordered sum
    breaks a tie either way); without it they agree. Each pixel's luma is taken once, into
    a plane of its own, where the filter reads nine (the head at 512², side by side in one
    process: 1.51 -> 0.95 ms a frame, the same bytes over 56 frames of four expressions)."""
    height, width = image.shape[0], image.shape[1]
    luma = np.empty((height, width))
    for row in prange(height):
        for x in range(width):
            luma[row, x] = _luma(image, row, x)
    for row in prange(height):
        y = np.int64(row)  # a parallel loop's index may be unsigned, and y - 1 must not wrap
        for x in range(width):
            m = luma[y, x]
            n, s, w, e = _near(luma, y - 1, x), _near(luma, y + 1, x), _near(luma, y, x - 1), _near(luma, y, x + 1)
            brightest = max(m, n, s, w, e)
            span = brightest - min(m, n, s, w, e)
            for c in range(image.shape[2]):
                out[y, x, c] = image[y, x, c]
            if span < max(EDGE_FLOOR, EDGE_CONTRAST * brightest):
                continue
            nw, ne = _near(luma, y - 1, x - 1), _near(luma, y - 1, x + 1)
            sw, se = _near(luma, y + 1, x - 1), _near(luma, y + 1, x + 1)
            across_rows = 2.0 * abs(n + s - 2.0 * m) + abs(ne + se - 2.0 * e) + abs(nw + sw - 2.0 * w)
            across_columns = 2.0 * abs(e + w - 2.0 * m) + abs(ne + nw - 2.0 * n) + abs(se + sw - 2.0 * s)
            if across_rows >= across_columns:  # a horizontal edge: blend with the pixel above or below
                dy, dx = (-1 if abs(n - m) >= abs(s - m) else 1), 0
            else:
                dy, dx = 0, (-1 if abs(w - m) >= abs(e - m) else 1)
            ny, nx = min(max(y + dy, 0), height - 1), min(max(x + dx, 0), width - 1)
            mean = (2.0 * (n + s + w + e) + nw + ne + sw + se) / 12.0
            t = min(abs(mean - m) / span, 1.0)
            t = (3.0 - 2.0 * t) * t * t
            blend = t * t
            for c in range(image.shape[2]):
                out[y, x, c] = np.uint8(min(255.0, (1.0 - blend) * image[y, x, c] + blend * image[ny, nx, c] + 0.5))
