"""Baking a photo into the head's texture: each texel takes the photo's colour where its
point of the fitted head faces the camera and nothing hides it.

The texture is an atlas of six square tiles, three across and two down, one per part the
photo can show (``TILES``): the face, the back of the head, and each eye's sclera and
inner sphere (ICT's M_Iris, painted whole: pupil, iris and the white around them). ICT
lays its parts out in UV tiles of their own (the face in [0, 1]², the back of the head in
[1, 2] x [0, 1], ...) and the eyes' shells in the face's square, over one another;
:func:`atlas_uv` moves each part's triangles, as the figure draws them
(facesim.face.figure.drawn_rows: the sclera without its clear cornea), into its tile. Teeth, gums, tongue and lashes keep facesim's materials: a photo of a
closed mouth does not show them.

Steps (:func:`bake`):

1. the head's depth as the photo's camera sees it, and which surface is nearest (the skin
   or an eyeball), rasterised per pixel (``_depth_buffer``);
2. every texel of every tile's triangles: its point on the head and its normal by
   barycentric interpolation, its pixel in the photo and its depth; it takes the photo's
   colour (bilinear) when its depth is within ``DEPTH_TOLERANCE`` of the nearest surface
   there, with a weight that fades from 1 to 0 as the surface turns away from the camera
   (``GRAZING``: at a grazing angle one pixel smears over many texels);
3. what no pixel shows takes a tone: facesim's own colours scaled to the photo's skin
   (the median of the face's texels seen face-on) on the face and the back of the head
   (so the inside of the mouth stays dark and the inner lips lip-coloured), and
   facesim's own paint on the eyes (the white, and the pupil and iris of the inner
   sphere, which a gaze turns into view: the few pixels a photo gives an eye's white
   are mostly the lids' shadow). Seen texels keep the photo's colour exactly (so the
   neutral head through the photo's camera is the photo); unseen ones take the nearest
   seen colour, fading into the tone over ``FEATHER`` texels, so no seam shows where the
   photo ends.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from ..config import NUMBA_OPTIONS
from .colours import SKIN
from .figure import COLUMNS, TILE, TILES, atlas_uv

#: Which surface each tile belongs to, for what hides what: the skin (face and back of the
#: head), then each eye's sclera and inner sphere (which shows only through the cornea).
SURFACE = (0, 0, 1, 2, 3, 4)
#: A texel is seen when it lies within this depth of the nearest surface at its pixel:
#: this many cm, or this many of the photo's pixels (a pixel spans a range of depths on a
#: sloping surface), whichever is more.
DEPTH_TOLERANCE = (0.08, 1.5)
#: cos θ between the surface's normal and the direction to the camera: below the first
#: the photo's colour is not used, above the second fully. Kept near 0: through the
#: photo's own camera every visible texel should show its pixel (the neutral frame is
#: the photo), and only the silhouette's last pixels smear.
GRAZING = (0.02, 0.12)
#: Texels over which the photo's colour fades into the tone at the edge of what was seen.
FEATHER = 12


@njit(**NUMBA_OPTIONS)
def _barycentric(px, py, ax, ay, bx, by, cx, cy):
    det = (by - cy) * (ax - cx) + (cx - bx) * (ay - cy)
    if abs(det) < 1e-12:
        return -1.0, -1.0, -1.0
    l0 = ((by - cy) * (px - cx) + (cx - bx) * (py - cy)) / det
    l1 = ((cy - ay) * (px - cx) + (ax - cx) * (py - cy)) / det
    return l0, l1, 1.0 - l0 - l1


@njit(**NUMBA_OPTIONS)
def _span(a, b, c, size):
    """The pixels (first, last) whose centres a triangle with coordinates a, b, c along one
    axis may cover, within [0, size)."""
    return max(int(np.floor(min(a, b, c))), 0), min(int(np.ceil(max(a, b, c))), size - 1)


@njit(**NUMBA_OPTIONS)
def _depth_buffer(pixels, depth, triangles, group, out, owner):
    """out (h, w): the largest depth (nearest the camera) of the triangles over each pixel
    centre, -inf where none is; owner (h, w): that triangle's ``group``, -1 where none is."""
    h, w = out.shape
    out[:] = -np.inf
    owner[:] = -1
    for t in range(triangles.shape[0]):
        a, b, c = triangles[t, 0], triangles[t, 1], triangles[t, 2]
        x0, x1 = _span(pixels[a, 0], pixels[b, 0], pixels[c, 0], w)
        y0, y1 = _span(pixels[a, 1], pixels[b, 1], pixels[c, 1], h)
        for y in range(y0, y1 + 1):
            for x in range(x0, x1 + 1):
                l0, l1, l2 = _barycentric(x + 0.5, y + 0.5, pixels[a, 0], pixels[a, 1], pixels[b, 0], pixels[b, 1],
                                          pixels[c, 0], pixels[c, 1])
                if l0 < 0.0 or l1 < 0.0 or l2 < 0.0:
                    continue
                d = l0 * depth[a] + l1 * depth[b] + l2 * depth[c]
                if d > out[y, x]:
                    out[y, x] = d
                    owner[y, x] = group[t]


@njit(**NUMBA_OPTIONS)
def _sample(photo, x, y, out):
    """Bilinear sample of photo (h, w, 3) at pixel coordinates (x, y) (centres at +0.5)."""
    h, w = photo.shape[0], photo.shape[1]
    fx = min(max(x - 0.5, 0.0), w - 1.0)
    fy = min(max(y - 0.5, 0.0), h - 1.0)
    ix, iy = min(int(fx), w - 2), min(int(fy), h - 2)
    tx, ty = fx - ix, fy - iy
    for d in range(3):
        top = (1 - tx) * photo[iy, ix, d] + tx * photo[iy, ix + 1, d]
        bottom = (1 - tx) * photo[iy + 1, ix, d] + tx * photo[iy + 1, ix + 1, d]
        out[d] = (1 - ty) * top + ty * bottom


@njit(**NUMBA_OPTIONS)
def _bake(texel_uv, corners, tile, group, pixels, depth, facing, vertex_colour, zbuffer, owner, photo, tolerance,
          grazing_low, grazing_high, colour, weight, covered, base, visible):
    """Step 2 of the module docstring over the triangles whose corners (k, 3) into the
    head's vertices have atlas texel coordinates ``texel_uv`` (k, 3, 2): ``colour`` (H, W, 3)
    and ``weight`` (H, W) written where the photo shows the texel (the nearest surface at
    its pixel is of the triangle's ``group`` and not much nearer than it: an eyeball
    under its lid lies closer behind the skin than any depth tolerance), ``covered`` (H, W) the
    triangle's ``tile`` + 1 and ``base`` (H, W, 3) the corners'
    ``vertex_colour`` interpolated, on every texel it covers; ``visible`` (H, W) set where
    the texel is the nearest surface at its pixel, at whatever angle."""
    h, w = zbuffer.shape
    rows, cols = colour.shape[0], colour.shape[1]
    sample = np.empty(3)
    for t in range(corners.shape[0]):
        a, b, c = corners[t, 0], corners[t, 1], corners[t, 2]
        ua, va = texel_uv[t, 0, 0], texel_uv[t, 0, 1]
        ub, vb = texel_uv[t, 1, 0], texel_uv[t, 1, 1]
        uc, vc = texel_uv[t, 2, 0], texel_uv[t, 2, 1]
        x0, x1 = _span(ua, ub, uc, cols)
        y0, y1 = _span(va, vb, vc, rows)
        # the depth test allows what the triangle's own depth changes over a pixel of the
        # photo: on a surface seen at a slant a texel and its pixel's centre lie that far
        # apart in depth (without it, lines of unseen texels ran along the triangles' edges)
        ex, ey = pixels[b, 0] - pixels[a, 0], pixels[b, 1] - pixels[a, 1]
        fx, fy = pixels[c, 0] - pixels[a, 0], pixels[c, 1] - pixels[a, 1]
        area = ex * fy - ey * fx
        slope = 0.0
        if abs(area) > 1e-12:
            dx = ((depth[b] - depth[a]) * fy - (depth[c] - depth[a]) * ey) / area
            dy = ((depth[c] - depth[a]) * ex - (depth[b] - depth[a]) * fx) / area
            slope = math.sqrt(dx * dx + dy * dy)
        allowed = tolerance + slope
        for y in range(y0, y1 + 1):
            for x in range(x0, x1 + 1):
                l0, l1, l2 = _barycentric(x + 0.5, y + 0.5, ua, va, ub, vb, uc, vc)
                if l0 < -1e-3 or l1 < -1e-3 or l2 < -1e-3:
                    continue
                covered[y, x] = tile[t] + 1
                for ch in range(3):
                    base[y, x, ch] = l0 * vertex_colour[a, ch] + l1 * vertex_colour[b, ch] + l2 * vertex_colour[c, ch]
                px = l0 * pixels[a, 0] + l1 * pixels[b, 0] + l2 * pixels[c, 0]
                py = l0 * pixels[a, 1] + l1 * pixels[b, 1] + l2 * pixels[c, 1]
                ix, iy = int(np.floor(px)), int(np.floor(py))
                if ix < 0 or iy < 0 or ix >= w or iy >= h:
                    continue
                d = l0 * depth[a] + l1 * depth[b] + l2 * depth[c]
                if owner[iy, ix] != group[t] or d < zbuffer[iy, ix] - allowed:
                    continue
                visible[y, x] = True
                cosine = l0 * facing[a] + l1 * facing[b] + l2 * facing[c]
                k = min(max((cosine - grazing_low) / (grazing_high - grazing_low), 0.0), 1.0)
                if k <= weight[y, x]:
                    continue
                _sample(photo, px, py, sample)
                weight[y, x] = k
                for ch in range(3):
                    colour[y, x, ch] = sample[ch]


def bake(head, camera, photo: np.ndarray, vertex_colour: np.ndarray, atlas=None) -> tuple[np.ndarray, np.ndarray]:
    """The atlas (2 TILE, 3 TILE, 3) uint8 of ``head`` (facesim.face.head.Head, the fitted
    identity) seen by ``camera`` (facesim.face.fit.Camera) in ``photo`` (h, w, 3) uint8, its
    layout ``atlas`` (``atlas_uv(head)``, found when not given).
    ``vertex_colour`` (N, 3+) in [0, 1], facesim's own colours of the head
    (facesim.face.figure), paints the eyes' inner spheres where the photo does not show them,
    and any part the photo does not show at all. Also returns the atlas's --onto alpha
    (2 TILE, 3 TILE) uint8: where the photo saw a texel, how fully (the GRAZING weight:
    near the silhouette the photo, not the render, shows the head's edge, and the hair
    or background beyond it); 255 wherever the photo did not see it (hidden or turned
    away: only the render can show it)."""
    from scipy.ndimage import distance_transform_edt

    from ..geometry import _vertex_normals

    x = np.ascontiguousarray(head.vertices, dtype=np.float64)
    normals = np.empty_like(x)
    _vertex_normals(x, np.ascontiguousarray(head.triangles), normals)
    pixels = camera.project(x)
    depth = camera.turned(x)[:, 2].copy()
    facing = np.einsum("ij,ij->i", normals, camera.toward_camera(x))
    rows, tile, uv = atlas_uv(head) if atlas is None else atlas
    corners = np.ascontiguousarray(head.triangles[rows])
    group = np.asarray(SURFACE, dtype=np.int64)[tile]
    zbuffer, owner = np.empty((camera.height, camera.width)), np.empty((camera.height, camera.width), dtype=np.int64)
    _depth_buffer(pixels, depth, corners, group, zbuffer, owner)

    shape = (TILE * len(TILES) // COLUMNS, TILE * COLUMNS)
    texel = np.empty_like(uv)
    texel[:, :, 0] = uv[:, :, 0] * shape[1]
    texel[:, :, 1] = (1.0 - uv[:, :, 1]) * shape[0]  # image rows run down, v up
    colour, weight, covered = np.zeros(shape + (3,)), np.zeros(shape), np.zeros(shape, dtype=np.int64)
    tone, visible = np.zeros(shape + (3,)), np.zeros(shape, dtype=np.bool_)
    image = np.ascontiguousarray(photo[:, :, :3], dtype=np.float64) / 255.0
    tolerance = max(DEPTH_TOLERANCE[0], DEPTH_TOLERANCE[1] / camera.scale)
    _bake(texel, corners, tile.astype(np.int64), group, pixels, depth, facing, np.ascontiguousarray(vertex_colour[:, :3], dtype=np.float64),
          zbuffer, owner, image, tolerance, GRAZING[0], GRAZING[1], colour, weight, covered, tone, visible)
    seen = (covered == 1) & (weight >= 0.99)  # the face's skin seen face-on
    scale = np.ones(3)
    if seen.sum() > 50:  # facesim's colours of the skin scaled to the photo's skin; the eyes stay painted
        scale = np.median(colour[seen], axis=0) / np.asarray(SKIN[:3])
    # what was seen keeps the photo's colour; beyond it the nearest colour seen fades into
    # the tone over FEATHER texels
    full = weight >= 0.99
    if full.any():
        distance, (seen_y, seen_x) = distance_transform_edt(~full, return_indices=True)
    else:  # nothing seen fully: the tone everywhere beyond
        distance, seen_y, seen_x = np.full(shape, np.inf), np.zeros(shape, np.int64), np.zeros(shape, np.int64)
    # texels no triangle covers take the nearest covered one's values, so that filtering
    # at an island's edge does not bleed black
    covered_y, covered_x = distance_transform_edt(covered == 0, return_distances=False, return_indices=True)
    texture, onto = np.empty(shape + (3,), np.uint8), np.empty(shape, np.uint8)
    _composite(colour, weight, tone, covered, visible, scale, distance, seen_y, seen_x, covered_y, covered_x,
               float(FEATHER), texture, onto)
    return texture, onto


@njit(**NUMBA_OPTIONS)
def _composite(colour, weight, tone, covered, visible, scale, distance, seen_y, seen_x, covered_y, covered_x,
               feather, texture, onto):
    """Step 3 of the module docstring, every texel of the atlas at once: at the covered
    texel nearest it (``covered_y``, ``covered_x``: itself where a triangle covers it), the
    photo's colour by its weight over the nearest colour seen fully (``seen_y``,
    ``seen_x``, ``distance`` away) fading into the tone (scaled by ``scale`` on the skin's
    two tiles, ``covered`` 1 and 2) over ``feather`` texels; into ``texture`` (uint8), and
    the --onto alpha (the weight where the photo saw the texel, else 1) into ``onto``."""
    rows, cols = weight.shape
    for y in range(rows):
        for x in range(cols):
            py, px = covered_y[y, x], covered_x[y, x]
            w = weight[py, px]
            fade = min(max(distance[py, px] / feather, 0.0), 1.0)
            qy, qx = seen_y[py, px], seen_x[py, px]
            skin = covered[py, px] == 1 or covered[py, px] == 2
            for ch in range(3):
                t = tone[py, px, ch] * scale[ch] if skin else tone[py, px, ch]
                beyond = (1.0 - fade) * colour[qy, qx, ch] + fade * t
                value = w * colour[py, px, ch] + (1.0 - w) * beyond
                texture[y, x, ch] = np.uint8(min(max(np.rint(value * 255.0), 0.0), 255.0))
            alpha = w if visible[py, px] else 1.0
            onto[y, x] = np.uint8(min(max(np.rint(alpha * 255.0), 0.0), 255.0))
