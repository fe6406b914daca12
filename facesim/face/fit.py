"""Fitting the head to a photo: ICT FaceKit's identity modes, a pose and a camera from
MediaPipe's 468 landmarks.

Where each landmark lies on the head is a fixed blend of head vertices
(``Head.landmark_vertex``/``landmark_weight``: ICT's measurement), and the head is the
generic neutral plus Σ wᵢ modeᵢ, so the landmarks are linear in the identity weights w:
P(w) = P₀ + B w. The camera (:class:`Camera`) is a pinhole on the head's turned +z axis:
a head point X, turned to C = R X, shows at pixel

    (W/2 + p Cₓ + tₓ, H/2 - p Cᵧ - tᵧ),   p = s / (1 - κ C_z),

s the scale in pixels per cm at the head's origin and κ the inverse of the camera's
distance (κ = 0 is weak perspective). Weak perspective was tried first and measured
wrong: on facesim's own render of the generic head from 105 cm it fitted a head 0.18 cm
RMS from the truth with MediaPipe's landmarks and 0.18 with the exact ones, against
0.007 with κ fitted (the nose, 10 cm nearer than the ears, shows 10% larger).

The fit alternates (:func:`fit_head`), ``ROUNDS`` times:

1. the camera: R, t, s and κ (0 ≤ κ ≤ 1/15 cm) for the landmarks as they are, by
   scipy.optimize.least_squares on the reprojection error;
2. the identity: for that camera, each landmark's two equations
   (u - tₓ)(1 - κ C_z) = s Cₓ (and v) are linear in w; solved with the modes' prior
   (ICT draws wᵢ from the standard normal distribution) as a ridge regression, the
   residuals in cm against a landmark's uncertainty ``LANDMARK_SIGMA``.

Only x and y are used: MediaPipe's depth is its network's guess, and with it the fit
was worse. What a frontal photo cannot see (the back of the head, the ears' depth) comes
from the modes' correlations with what it can, and from the prior where there are none.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..errors import InputError
from .align import similarity
from .head import IDENTITY_MODES, Head, _identity_deltas

#: A landmark's uncertainty on the head (cm), the prior's weight against the landmarks:
#: MediaPipe's landmarks on facesim's renders of known heads lie 0.7-1.1% of the face's
#: width (0.1-0.15 cm) from where ICT's measurement puts them.
LANDMARK_SIGMA = 0.3
#: Alternations of camera and identity, and the nearest camera fitted (cm).
ROUNDS = 8
NEAREST = 15.0
#: The smallest face fitted: its landmarks' bounding box at least this many pixels on its
#: longer side (a face that small gives the landmarks about a pixel of play each).
MIN_FACE_SIZE = 100
#: The largest head turn (yaw, degrees) fitted: beyond it the far cheek's landmarks are
#: guesses behind the nose.
MAX_YAW = 35.0
#: A photo's face is at rest when its lips are apart by at most the first (cm) more than
#: the fitted neutral head's and its mouth's corners raised by at most the second
#: (``Fit.mouth_against_rest``). Measured (2026-12-07): facesim's head at rest, identity
#: 7 at rest, its sad face and Grace Hopper's portrait, lips -0.13 to -0.07 and corners
#: -0.22 to -0.13 (the fit puts the corners a little high); the astronaut's smile with
#: her teeth showing 0.81 and 0.26, facesim's happy apex -0.01 and 0.28 (a smile with
#: closed lips), its surprise 1.58 (the jaw open).
PHOTO_AT_REST = (0.3, 0.1)


#: A fitted camera facesim takes from a face directory: a photo of 16 to 65,536 pixels a
#: side; the head's origin at most a photo's width or height from its centre; and a scale
#: (pixels per cm) at which a head ``HEAD_WIDTH`` cm wide spans ``HEAD_SPAN`` of the
#: photo's width, from a fiftieth (a face of ten-odd pixels, below what the fit accepts)
#: to five photos. Outside them a camera draws no head onto the photo (a translation of
#: inf, a scale of 1e300 or 1e-300: every frame was the photo untouched) or breaks the
#: composite (a width of 0).
PHOTO_SIDE, HEAD_WIDTH, HEAD_SPAN = (16, 65536), 15.0, (0.02, 5.0)


@dataclass(frozen=True)
class Camera:
    """The fitted pinhole (module docstring): ``rotation`` R (3, 3) turns the head's frame
    into the camera's (+z toward the camera), ``translation`` (tₓ, tᵧ) pixels from the
    image's centre, ``scale`` s pixels per cm at the head's origin, ``kappa`` κ the
    inverse distance (1/cm), for an image of ``width`` x ``height``."""

    rotation: np.ndarray
    translation: np.ndarray
    scale: float
    kappa: float
    width: int
    height: int

    def turned(self, points: np.ndarray) -> np.ndarray:
        """(k, 3) head points in the camera's frame, C = R X."""
        return points @ self.rotation.T

    def project(self, points: np.ndarray) -> np.ndarray:
        """(k, 2) pixels (x right, y down) of head points (k, 3)."""
        c = self.turned(points)
        p = self.scale / (1.0 - self.kappa * c[:, 2])
        return np.column_stack([self.width / 2 + p * c[:, 0] + self.translation[0],
                                self.height / 2 - p * c[:, 1] - self.translation[1]])

    def resized(self, width: int, height: int) -> "Camera":
        """The same camera for the photo resized to ``width`` x ``height``."""
        ratio = width / self.width
        return Camera(self.rotation, self.translation * ratio, self.scale * ratio, self.kappa, int(width), int(height))

    def toward_camera(self, points: np.ndarray) -> np.ndarray:
        """(k, 3) unit vectors from head points toward the camera, in the head's frame."""
        if self.kappa == 0.0:
            return np.tile(self.rotation[2], (len(points), 1))
        eye = self.rotation[2] / self.kappa  # the camera, in the head's frame
        d = eye - points
        return d / np.linalg.norm(d, axis=1, keepdims=True)

    @property
    def yaw(self) -> float:
        """The head's turn away from the camera, degrees (positive: its nose toward the
        image's right)."""
        return float(np.degrees(np.arctan2(self.rotation[0, 2], self.rotation[2, 2])))

    def as_dict(self) -> dict:
        return dict(model="pinhole on the head's axis (facesim.face.fit.Camera)", rotation=self.rotation.tolist(),
                    translation=[float(v) for v in self.translation], scale=float(self.scale), kappa=float(self.kappa),
                    width=int(self.width), height=int(self.height))

    @classmethod
    def from_dict(cls, data: dict, where: str) -> "Camera":
        try:
            camera = cls(np.asarray(data["rotation"], dtype=np.float64), np.asarray(data["translation"], dtype=np.float64),
                         float(data["scale"]), float(data["kappa"]), int(data["width"]), int(data["height"]))
        except (KeyError, TypeError, ValueError) as exc:
            raise InputError(f"{where}: not a fitted camera ({type(exc).__name__}: {exc})") from None
        r = camera.rotation
        if r.shape != (3, 3) or camera.translation.shape != (2,) or not camera.scale > 0 or not 0 <= camera.kappa < 1:
            raise InputError(f"{where}: expected a 3x3 rotation, a 2-vector translation, a positive scale and 0 <= kappa < 1")
        if not np.isfinite(r).all() or not np.allclose(r @ r.T, np.eye(3), atol=1e-6) or np.linalg.det(r) < 0:
            raise InputError(f"{where}: the rotation is not a rotation")
        low, high = PHOTO_SIDE
        if not (low <= camera.width <= high and low <= camera.height <= high):
            raise InputError(f"{where}: width and height: expected the photo's size, {low} to {high} pixels, "
                             f"got {camera.width}x{camera.height}")
        if not (np.isfinite(camera.translation).all() and abs(camera.translation[0]) <= camera.width
                and abs(camera.translation[1]) <= camera.height):
            raise InputError(f"{where}: translation: expected the head within the photo, at most {camera.width}x"
                             f"{camera.height} pixels from its centre, got {camera.translation.tolist()}")
        span = camera.scale * HEAD_WIDTH / camera.width
        if not HEAD_SPAN[0] <= span <= HEAD_SPAN[1]:
            raise InputError(f"{where}: scale: {camera.scale:g} pixels per cm draws the head {span:.3g} photo widths "
                             f"wide; expected {HEAD_SPAN[0]:g} to {HEAD_SPAN[1]:g}")
        return camera


@dataclass(frozen=True)
class Fit:
    """A head fitted to a photo's landmarks: the identity weights (100,), the camera, and
    the landmarks as fitted (468, 2) and as MediaPipe found them (468, 2), in pixels."""

    identity: np.ndarray
    camera: Camera
    fitted: np.ndarray
    detected: np.ndarray

    @property
    def face_width(self) -> float:
        """The width of the detected landmarks' bounding box, pixels."""
        return float(np.ptp(self.detected[:, 0]))

    @property
    def residual(self) -> np.ndarray:
        """(468,) each landmark's distance from where MediaPipe found it, in face widths."""
        return np.linalg.norm(self.fitted - self.detected, axis=1) / self.face_width

    def mouth_against_rest(self) -> tuple[float, float]:
        """How the photo's mouth differs from the fitted head's at rest (cm, at the head's
        scale): its lips' gap (MediaPipe's inner-lip landmarks 13 and 14) wider by, and its
        corners (61, 291) nearer the eyes' outer corners (33, 263) by, as a smile raises
        and widens them; each against the same landmarks of the fitted neutral head as the
        camera shows it. The identity's modes fit a face's shape, not its expression: what
        an expression moves is left here (``PHOTO_AT_REST``)."""
        def gap(points):
            return np.linalg.norm(points[13] - points[14])

        def corners_to_eyes(points):
            return (np.linalg.norm(points[61] - points[33]) + np.linalg.norm(points[291] - points[263])) / 2

        scale = self.camera.scale
        return (float(gap(self.detected) - gap(self.fitted)) / scale,
                float(corners_to_eyes(self.fitted) - corners_to_eyes(self.detected)) / scale)


def landmark_basis(head: Head, head_path) -> tuple[np.ndarray, np.ndarray]:
    """P₀ (468, 3) and B (468, 3, 100): the landmarks on the generic head and how each
    identity mode moves them."""
    weights, vertices = head.landmark_weight, head.landmark_vertex
    base = np.einsum("kj,kjd->kd", weights, head.neutral[vertices])
    deltas = _identity_deltas(head_path)  # (100, N, 3) float16
    basis = np.einsum("kj,mkjd->kdm", weights, deltas[:, vertices].astype(np.float64))
    return base, basis


def _camera(parameters: np.ndarray, width: int, height: int) -> Camera:
    """A Camera from (rotation vector (3), tₓ, tᵧ, s, κ)."""
    from scipy.spatial.transform import Rotation

    return Camera(Rotation.from_rotvec(parameters[:3]).as_matrix(), parameters[3:5].copy(), float(parameters[5]),
                  float(parameters[6]), width, height)


def fit_head(head: Head, head_path, landmarks: np.ndarray, width: int, height: int, source: str = "photo") -> Fit:
    """Fit identity and camera to MediaPipe's landmarks (468, 2 or 3) in pixels (x right,
    y down). Raises InputError for a face too small or turned too far to fit."""
    from scipy.optimize import least_squares
    from scipy.spatial.transform import Rotation

    detected = np.asarray(landmarks, dtype=np.float64)[:, :2]
    size = float(np.ptp(detected, axis=0).max())
    if size < MIN_FACE_SIZE:
        raise InputError(f"{source}: the face is {size:.0f} pixels across, too small to fit "
                         f"(at least {MIN_FACE_SIZE} needed)")
    base, basis = landmark_basis(head, head_path)
    u, v = detected[:, 0] - width / 2, height / 2 - detected[:, 1]  # from the centre, y up
    # a first camera: the similarity of the generic landmarks onto the photo's, as if flat
    s, rotation, t = similarity(base, np.column_stack([u, v, np.zeros(len(u))]))
    parameters = np.r_[Rotation.from_matrix(rotation).as_rotvec(), t[:2], s, 0.0]
    w = np.zeros(IDENTITY_MODES)
    low, high = [-np.inf] * 6 + [0.0], [np.inf] * 6 + [1.0 / NEAREST]
    for _ in range(ROUNDS):
        points = base + basis @ w

        def reprojection(x):
            return ((_camera(x, width, height).project(points) - detected) / x[5]).ravel()

        parameters = least_squares(reprojection, parameters, bounds=(low, high)).x
        camera = _camera(parameters, width, height)
        r, (tx, ty), s, kappa = camera.rotation, camera.translation, camera.scale, camera.kappa
        turned_basis = np.einsum("de,kem->kdm", r, basis)
        turned_base = base @ r.T
        rows, rhs = [], []
        for axis, pixels in ((0, u - tx), (1, v - ty)):  # (pixel - t)(1 - κ C_z) = s C_axis, in cm
            rows.append(turned_basis[:, axis] - (kappa * pixels / s)[:, None] * turned_basis[:, 2])
            rhs.append((pixels * (1.0 - kappa * turned_base[:, 2]) - s * turned_base[:, axis]) / s)
        a, b = np.concatenate(rows), np.concatenate(rhs)
        w = np.linalg.solve(a.T @ a + LANDMARK_SIGMA**2 * np.eye(IDENTITY_MODES), a.T @ b)
    points = base + basis @ w
    camera = _camera(parameters, width, height)
    if abs(camera.yaw) > MAX_YAW:
        raise InputError(f"{source}: the face is turned {abs(camera.yaw):.0f} degrees from the camera, too far to fit "
                         f"(at most {MAX_YAW:.0f})")
    return Fit(w, camera, camera.project(points), detected.copy())
