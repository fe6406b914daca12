"""What a step is checked for: triangles inverted against the skin around them (the
overlap edge repulsion exists to prevent, thesis fig. 3.16).
"""

import math

import numpy as np
from numba import njit

from ..config import NUMBA_OPTIONS
from ..geometry import _triangle_normal, _vertex_normals


@njit(**NUMBA_OPTIONS)
def _against_surroundings(x, faces, t, normals):
    """Whether triangle t faces against the skin around it: its normal against the sum
    of its corners' vertex normals (``normals``, from ``_vertex_normals``)."""
    nx, ny, nz = _triangle_normal(x, faces, t)
    around = 0.0
    for k in range(3):
        v = faces[t, k]
        around += nx * normals[v, 0] + ny * normals[v, 1] + nz * normals[v, 2]
    return around <= 0.0


@njit(**NUMBA_OPTIONS)
def _triangle_checks(x, faces, rest_normal, rest_area, rest_against, normals):
    """Inverted triangles, the first of them, and the smallest area relative to rest.

    A triangle is inverted when it has turned over (its normal against its rest normal)
    and folded over the skin around it: it now faces against its surroundings where it
    faced with them at rest (``_against_surroundings``; or the other way round for the
    few triangles in the sharpest creases). That is the overlap of elements that edge
    repulsion exists to prevent (thesis fig. 3.16). Turning over alone is not enough: a
    patch of skin that turns as a whole (a lip rolling at the mouth corner, a lid sliding
    over the eyeball) keeps facing with its surroundings, and a sliver triangle turns over
    its long edge when its short vertex moves a fraction of a millimetre out of the surface.
    """
    inverted = 0
    first = -1
    smallest = np.inf
    have_normals = False
    for t in range(faces.shape[0]):
        nx, ny, nz = _triangle_normal(x, faces, t)
        smallest = min(smallest, 0.5 * math.sqrt(nx * nx + ny * ny + nz * nz) / rest_area[t])
        if nx * rest_normal[t, 0] + ny * rest_normal[t, 1] + nz * rest_normal[t, 2] > 0.0:
            continue
        if not have_normals:
            _vertex_normals(x, faces, normals)
            have_normals = True
        if _against_surroundings(x, faces, t, normals) == rest_against[t]:
            continue
        inverted += 1
        if first < 0:
            first = t
    return inverted, first, smallest
