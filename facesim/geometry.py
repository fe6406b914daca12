"""Triangle-mesh geometry every layer shares: triangle and area-weighted vertex normals
(a Numba kernel: the renderer takes a head's normals every frame, the physics its
inversion checks), and the rotations of a head's pose.
"""

import math

import numpy as np
from numba import njit

from .config import NUMBA_OPTIONS


@njit(**NUMBA_OPTIONS)
def _triangle_normal(x, faces, t):
    """(b - a) x (c - a) of triangle t: its normal, twice its area long."""
    a = faces[t, 0]
    b = faces[t, 1]
    c = faces[t, 2]
    ux = x[b, 0] - x[a, 0]
    uy = x[b, 1] - x[a, 1]
    uz = x[b, 2] - x[a, 2]
    wx = x[c, 0] - x[a, 0]
    wy = x[c, 1] - x[a, 1]
    wz = x[c, 2] - x[a, 2]
    return uy * wz - uz * wy, uz * wx - ux * wz, ux * wy - uy * wx


@njit(**NUMBA_OPTIONS)
def _vertex_normals(x, faces, out):
    """Area-weighted vertex normals for smooth shading, written into ``out`` (n, 3)."""
    out[:] = 0.0
    for t in range(faces.shape[0]):
        nx, ny, nz = _triangle_normal(x, faces, t)
        for k in range(3):
            v = faces[t, k]
            out[v, 0] += nx
            out[v, 1] += ny
            out[v, 2] += nz
    for i in range(x.shape[0]):
        length = math.sqrt(out[i, 0] ** 2 + out[i, 1] ** 2 + out[i, 2] ** 2)
        if length > 0.0:
            for d in range(3):
                out[i, d] /= length


def rotation(yaw: float = 0.0, pitch: float = 0.0, roll: float = 0.0) -> np.ndarray:
    """3x3 rotation for angles in degrees (facesim.animation.spec.POSE): yaw about +y toward +x,
    pitch lifting +z toward +y, roll tilting +y toward +x."""
    y, p, r = np.radians([yaw, pitch, roll])
    turn = np.array([[np.cos(y), 0, np.sin(y)], [0, 1, 0], [-np.sin(y), 0, np.cos(y)]])
    lift = np.array([[1, 0, 0], [0, np.cos(p), np.sin(p)], [0, -np.sin(p), np.cos(p)]])
    tilt = np.array([[np.cos(r), np.sin(r), 0], [-np.sin(r), np.cos(r), 0], [0, 0, 1]])
    return turn @ lift @ tilt


def axis_rotation(axis: np.ndarray, angle: float) -> np.ndarray:
    """3x3 rotation by ``angle`` (radians) about the unit ``axis`` (Rodrigues)."""
    k = np.array([[0, -axis[2], axis[1]], [axis[2], 0, -axis[0]], [-axis[1], axis[0], 0]])
    return np.eye(3) + np.sin(angle) * k + (1 - np.cos(angle)) * k @ k
