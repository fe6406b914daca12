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


def _fitted_camera(camera, factor: int, pyrender) -> tuple:
    """The pyrender camera and its pose in the head's frame for a fitted camera
    (facesim.face.fit.Camera), in a viewport ``factor`` times the photo's size: a pinhole
    1/κ away on the head's turned +z axis, focal length s/κ and principal point
    (W/2 + tₓ, H/2 - tᵧ) pixels, or, for κ = 0, an orthographic view of W/s x H/s cm."""
    turn = camera.rotation.T  # the camera's axes in the head's frame
    pose = np.eye(4)
    pose[:3, :3] = turn
    if camera.kappa > 1e-6:
        distance = 1.0 / camera.kappa
        view = pyrender.IntrinsicsCamera(factor * camera.scale * distance, factor * camera.scale * distance,
                                         factor * (camera.width / 2 + camera.translation[0]),
                                         factor * (camera.height / 2 - camera.translation[1]),
                                         znear=max(distance - 60.0, 1.0), zfar=distance + 60.0)
        pose[:3, 3] = turn @ np.array([0.0, 0.0, distance])
    else:
        view = pyrender.OrthographicCamera(camera.width / (2 * camera.scale), camera.height / (2 * camera.scale), znear=1.0, zfar=200.0)
        pose[:3, 3] = turn @ np.array([-camera.translation[0] / camera.scale, -camera.translation[1] / camera.scale, 100.0])
    return view, pose
