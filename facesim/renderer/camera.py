"""Where the camera and the head stand: a look-at pose, a rotation and translation as a
4x4 pose, and the camera fitted to a photo (facesim.face.fit's) for drawing onto it.
"""

from __future__ import annotations

import numpy as np


def _look_at(eye: np.ndarray, target: np.ndarray) -> np.ndarray:
    forward = eye - target
    forward /= np.linalg.norm(forward)
    right = np.cross([0.0, 1.0, 0.0], forward)
    right /= np.linalg.norm(right)
    up = np.cross(forward, right)
    pose = np.eye(4)
    pose[:3, 0], pose[:3, 1], pose[:3, 2], pose[:3, 3] = right, up, forward, eye
    return pose


def _pose(rotation: np.ndarray, translation: np.ndarray) -> np.ndarray:
    """4x4 pose: turn by ``rotation``, then move by ``translation``."""
    matrix = np.eye(4)
    matrix[:3, :3] = rotation
    matrix[:3, 3] = translation
    return matrix


def _pinhole(x_scale: float, y_scale: float, near: float, far: float, centre=(0.0, 0.0)) -> np.ndarray:
    """4x4 OpenGL projection of a pinhole camera: x and y at unit depth scaled by
    ``x_scale`` and ``y_scale`` into clip space, the principal point moved by ``centre``
    (clip units), depth mapped from [near, far] to [-1, 1]."""
    projection = np.zeros((4, 4))
    projection[0, 0], projection[1, 1], projection[3, 2] = x_scale, y_scale, -1.0
    projection[0, 2], projection[1, 2] = centre
    projection[2, 2], projection[2, 3] = (far + near) / (near - far), 2.0 * far * near / (near - far)
    return projection


def _perspective(yfov: float, aspect: float, near: float, far: float) -> np.ndarray:
    """4x4 OpenGL projection of a pinhole camera (vertical field of view ``yfov``, radians)."""
    t = np.tan(yfov / 2.0)
    return _pinhole(1.0 / (aspect * t), 1.0 / t, near, far)


def _fitted_camera(camera, factor: int, width: int, height: int) -> tuple[np.ndarray, np.ndarray]:
    """The projection and the camera's pose in the head's frame for a fitted camera
    (facesim.face.fit.Camera), in a viewport ``width`` x ``height``, ``factor`` times the
    photo's size: a pinhole 1/κ away on the head's turned +z axis, focal length s/κ and
    principal point (W/2 + tₓ, H/2 - tᵧ) pixels, or, for κ = 0, an orthographic view of
    W/s x H/s cm."""
    turn = camera.rotation.T  # the camera's axes in the head's frame
    pose = np.eye(4)
    pose[:3, :3] = turn
    if camera.kappa > 1e-6:
        distance = 1.0 / camera.kappa
        focal = factor * camera.scale * distance
        cx, cy = factor * (camera.width / 2 + camera.translation[0]), factor * (camera.height / 2 - camera.translation[1])
        projection = _pinhole(2.0 * focal / width, 2.0 * focal / height, max(distance - 60.0, 1.0), distance + 60.0,
                              (1.0 - 2.0 * cx / width, 2.0 * cy / height - 1.0))
        pose[:3, 3] = turn @ np.array([0.0, 0.0, distance])
    else:
        ymag = camera.height / (2 * camera.scale)
        near, far = 1.0, 200.0
        projection = np.zeros((4, 4))
        projection[0, 0], projection[1, 1] = 1.0 / (width / height * ymag), 1.0 / ymag
        projection[2, 2], projection[2, 3], projection[3, 3] = 2.0 / (near - far), (far + near) / (near - far), 1.0
        pose[:3, 3] = turn @ np.array([-camera.translation[0] / camera.scale, -camera.translation[1] / camera.scale, 100.0])
    return projection, pose
