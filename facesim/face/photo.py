"""Build a neutral face mesh from one photograph with MediaPipe Face Mesh (offline).

The 468 landmarks (no iris refinement) become the vertices and the tessellation's 852
triangles the faces, so every mesh built here shares one topology and the default muscle
file fits it by landmark index. Steps, each a function below:

1. image coordinates to 3D: +x the subject's left, +y up, +z toward the viewer;
2. frontalise: rotate so the plane of symmetry, fitted against the mesh's own mirror
   image, is x = 0, and pitch so the area-weighted mean normal has no y component;
3. scale to centimetres: the outer eye corners (33, 263) are put 8.9 cm apart, the adult
   mean biocular width ex-ex (Farkas, "Anthropometry of the Head and Face": about 87 mm
   in women, 91 mm in men);
4. optionally symmetrise: average with the mirror image through the landmark mirror map;
5. place the origin on the head's vertical axis (a cylinder fitted to the mask), y = 0 at
   eye level, and orient every triangle toward +z.

MediaPipe is an optional dependency (``pip install facesim[photo]``); nothing is
downloaded at run time, its wheel carries the models.
"""

from __future__ import annotations

import ast
import contextlib
import inspect
import os
import sys
from pathlib import Path

import numpy as np

from ..errors import InputError
from ..physics.mesh import FaceMesh, fit_vertical_axis, mirror_map, triangle_normals

#: Outer eye corners (exocanthion) and their reference distance in cm.
EYE_CORNERS = (33, 263)
BIOCULAR_WIDTH_CM = 8.9
#: Inner eye corners, whose mean height is y = 0.
INNER_EYE_CORNERS = (133, 362)
#: Pairs of landmarks known to mirror each other (eye corners, mouth corners, cheekbones):
#: a first estimate of the symmetry plane, close enough for the full mirror map to be found.
ANCHOR_PAIRS = np.array([(33, 263), (133, 362), (61, 291), (123, 352)])


def tessellation() -> np.ndarray:
    """(852, 3) triangles of MediaPipe's FACEMESH_TESSELATION.

    The package exposes the tessellation as a frozenset of edges, which loses which edges
    form a triangle; its source lists them as consecutive triples (a, b), (b, c), (c, a),
    so the triangles are read back from that literal.
    """
    from mediapipe.python.solutions import face_mesh_connections as connections

    for node in ast.parse(inspect.getsource(connections)).body:
        if isinstance(node, ast.Assign) and getattr(node.targets[0], "id", "") == "FACEMESH_TESSELATION":
            edges = ast.literal_eval(node.value.args[0])
            break
    else:  # pragma: no cover - depends on the installed mediapipe
        raise RuntimeError("FACEMESH_TESSELATION not found in mediapipe")
    triples = np.array(edges, dtype=np.int64).reshape(-1, 3, 2)
    if not (np.array_equal(triples[:, 0, 1], triples[:, 1, 0]) and np.array_equal(triples[:, 1, 1], triples[:, 2, 0])):
        raise RuntimeError("FACEMESH_TESSELATION is not a list of triangles")
    return triples[:, :, 0]


#: Faces looked for in a photo; the largest is used. Where the whole photo shows none (two
#: faces side by side, each then too small for the detector's square), square crops of it
#: overlapping by half are looked in too.
MAX_FACES = 4
#: MediaPipe's landmark at the tip of the nose.
NOSE_TIP = 1
#: The face mesh's landmarks (the attention model adds 10 iris points after them).
LANDMARKS = 468


def detect_landmarks(image: np.ndarray, source: str, notice=None, refine: bool = False) -> np.ndarray:
    """(468, 3) landmarks in pixels of the photo's largest face: x right, y down, z away
    from the camera (image-width units). ``notice`` is told when there are several.

    ``refine``: MediaPipe's attention model, which places the eyes' and lips' points more
    closely (its 10 iris points are dropped). The head's fit uses it; the 468-vertex
    masks keep the plain model, which built meshes/face.obj. Measured on 35 facesim renders of known
    identities, fitting the head to them (facesim.face.fit): the whole head's RMS from the truth
    falls from 0.387 to 0.382 cm (mean; median 0.385 to 0.362) on 30 identities, and from
    0.370 to 0.322 on five others."""
    with _face_mesh(refine) as faces_in:
        faces = faces_in(image)
        if not faces:  # MediaPipe's detector sees the photo squeezed into a square: look in square crops of it too
            side = min(image.shape[:2])
            for y0 in _crop_starts(image.shape[0], side):
                for x0 in _crop_starts(image.shape[1], side):
                    for face in faces_in(image[y0:y0 + side, x0:x0 + side]):
                        face += (x0, y0, 0.0)  # into the photo's pixels
                        if not _seen(face, faces):
                            faces.append(face)
    if not faces:
        raise InputError(f"{source}: no face found in the image")
    sizes = [_across(face) for face in faces]
    largest = int(np.argmax(sizes))
    if len(faces) > 1 and notice is not None:
        notice(f"{source}: {len(faces)} faces found; using the largest ({sizes[largest]:.0f} pixels across)")
    return faces[largest]


@contextlib.contextmanager
def _face_mesh(refine: bool):
    """A function giving the faces MediaPipe's face mesh finds in an image, (468, 3) pixels
    each; one graph for every image it is given within the block (each found afresh).

    File descriptor 2 stays silenced from the graph's start to its close: its calculators
    open on MediaPipe's own threads, and TensorFlow Lite's "Created ... delegate" line once
    came out after a narrower silence had ended (one CI run in many)."""
    with quiet_stderr():
        import mediapipe as mp

        face_mesh = mp.solutions.face_mesh.FaceMesh(
            static_image_mode=True, max_num_faces=MAX_FACES, refine_landmarks=refine, min_detection_confidence=0.5)

        def faces_in(image: np.ndarray) -> list[np.ndarray]:
            height, width = image.shape[:2]
            result = face_mesh.process(np.ascontiguousarray(image[:, :, :3]))
            return [np.array([(p.x * width, p.y * height, p.z * width) for p in face.landmark[:LANDMARKS]],
                             dtype=np.float64) for face in result.multi_face_landmarks or []]

        try:
            yield faces_in
        finally:
            face_mesh.close()


def _across(face: np.ndarray) -> float:
    """How many pixels a face's landmarks span, its larger side."""
    return float(np.ptp(face[:, :2], axis=0).max())


def _crop_starts(length: int, side: int) -> list[int]:
    """Where square crops of ``side`` start along ``length``, overlapping by half."""
    if length <= side:
        return [0]
    count = int(np.ceil((length - side) / (side / 2))) + 1
    return sorted({int(round(k * (length - side) / (count - 1))) for k in range(count)})


def _seen(face: np.ndarray, faces: list[np.ndarray]) -> bool:
    """Whether a face found in one crop is one already found in another (nose tips within
    a tenth of its size)."""
    return any(np.linalg.norm(face[NOSE_TIP, :2] - other[NOSE_TIP, :2]) < 0.1 * _across(face) for other in faces)


@contextlib.contextmanager
def quiet_stderr():
    """Silence what C++ writes to file descriptor 2 meanwhile: MediaPipe's TensorFlow Lite
    and absl print 4-5 lines per run before any logging setting of theirs is read."""
    sys.stderr.flush()
    saved = os.dup(2)
    try:
        with open(os.devnull, "w") as devnull:
            os.dup2(devnull.fileno(), 2)
        yield
    finally:
        os.dup2(saved, 2)
        os.close(saved)


def image_to_face_frame(landmarks: np.ndarray) -> np.ndarray:
    """Pixels to the face frame: image right is the subject's left (+x), up is +y, and
    MediaPipe's depth grows away from the camera, so +z (toward the viewer) is its negative."""
    return landmarks * np.array([1.0, -1.0, -1.0])


def _rotation_between(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """The smallest rotation taking unit vector a to unit vector b (Rodrigues)."""
    v = np.cross(a, b)
    c = float(np.dot(a, b))
    vx = np.array([[0, -v[2], v[1]], [v[2], 0, -v[0]], [-v[1], v[0], 0]])
    return np.eye(3) + vx + vx @ vx / (1.0 + c)


def frontalise(points: np.ndarray, faces: np.ndarray, iterations: int = 4) -> tuple[np.ndarray, np.ndarray]:
    """Rotate and translate so the plane of symmetry is x = 0.

    Each pass pairs every landmark with its mirror (optimal assignment against the
    reflected points), takes the plane's normal as the principal direction of the pair
    differences and its offset from the pair midpoints, and rotates that normal onto +x.
    Then it pitches about x so the mean normal lies along +z. Returns the points and the
    mirror map of the last pass.
    """
    p = points - points.mean(axis=0)
    mapping = np.arange(len(p))
    mapping[ANCHOR_PAIRS[:, 0]], mapping[ANCHOR_PAIRS[:, 1]] = ANCHOR_PAIRS[:, 1], ANCHOR_PAIRS[:, 0]
    for _ in range(iterations):
        d = p - p[mapping]
        normal = np.linalg.svd(d[np.linalg.norm(d, axis=1) > 0], full_matrices=False)[2][0]
        normal *= np.sign(normal[0]) or 1.0
        offset = float(np.mean((p + p[mapping]) / 2 @ normal))
        p = (p - offset * normal) @ _rotation_between(normal, np.array([1.0, 0.0, 0.0])).T
        mapping = mirror_map(p)
    n = (triangle_normals(p, faces) * _areas(p, faces)[:, None]).sum(axis=0)
    if n[2] < 0:
        n = -n
    angle = np.arctan2(n[1], n[2])
    c, s = np.cos(angle), np.sin(angle)
    pitch = np.array([[1, 0, 0], [0, c, -s], [0, s, c]])
    return p @ pitch.T, mapping


def _areas(p: np.ndarray, faces: np.ndarray) -> np.ndarray:
    v = p[faces]
    return 0.5 * np.linalg.norm(np.cross(v[:, 1] - v[:, 0], v[:, 2] - v[:, 0]), axis=1)


def symmetrise(points: np.ndarray, mapping: np.ndarray) -> np.ndarray:
    """Average with the mirror image; midline landmarks land exactly on x = 0."""
    mirrored = points[mapping] * np.array([-1.0, 1.0, 1.0])
    return (points + mirrored) / 2


def symmetric_tessellation(points: np.ndarray, faces: np.ndarray, mapping: np.ndarray) -> np.ndarray:
    """The tessellation made mirror-symmetric.

    MediaPipe's tessellation is symmetric but for three quads per side (at the lower
    eyelid, the nostril and the upper lip) whose diagonals are mirrored the wrong way, so
    no vertex map sends all its triangles to triangles. The right half (-x) is kept, the
    left half is rebuilt as its mirror image, and triangles that the map sends to
    themselves (across the midline) are kept: same vertices, same triangle count.
    """
    self_mapped = np.array([sorted(t) == sorted(mapping[t]) for t in faces.tolist()])
    right = ~self_mapped & (points[faces, 0].sum(axis=1) < 0)
    rebuilt = np.concatenate([faces[self_mapped], faces[right], mapping[faces[right]][:, ::-1]])
    if len(rebuilt) != len(faces):
        raise ValueError("the two halves of the tessellation differ in size")
    return rebuilt


def build_face_mesh(image: np.ndarray, source: str = "image", symmetric: bool = True) -> FaceMesh:
    """The whole pipeline: a photo in, a frontal face mesh in centimetres out."""
    faces = tessellation()
    points = image_to_face_frame(detect_landmarks(image, source))
    try:
        points, mapping = frontalise(points, faces)
    except ValueError as exc:
        raise InputError(f"{source}: the detected face is too far from symmetric to frontalise ({exc})") from None
    a, b = EYE_CORNERS
    points *= BIOCULAR_WIDTH_CM / np.linalg.norm(points[a] - points[b])
    if symmetric:
        points = symmetrise(points, mapping)
        faces = symmetric_tessellation(points, faces, mapping)
        mirror_map(points, faces)  # the topology check: raises if a triangle has no mirror
    cx, cz, _ = fit_vertical_axis(points)
    points -= np.array([0.0 if symmetric else cx, points[list(INNER_EYE_CORNERS), 1].mean(), cz])
    if (triangle_normals(points, faces) * _areas(points, faces)[:, None]).sum(axis=0)[2] < 0:
        faces = faces[:, ::-1]
    return FaceMesh(points, faces)


def as_rgb(image) -> np.ndarray:
    """(h, w, 3) uint8 of a Pillow image of any mode: 16- and 32-bit grey scaled to 8
    bits (Pillow's own conversion clips them), palettes, CMYK and alpha (dropped) through
    Pillow's conversions."""
    if image.mode in ("I", "I;16", "I;16B", "I;16L", "I;16N", "F"):
        grey = np.asarray(image, dtype=np.float64)
        if image.mode == "F":  # floats: their own range
            top = max(float(grey.max()), 1e-12)
        elif image.mode.startswith("I;16") or grey.max() > 255:  # Pillow reads 16-bit grey PNGs as I;16 or I
            top = 65535.0
        else:
            top = 255.0
        grey = np.clip(grey * (255.0 / top), 0, 255).astype(np.uint8)
        return np.repeat(grey[:, :, None], 3, axis=2)
    return np.asarray(image.convert("RGB"), dtype=np.uint8)


def read_image(path: str | Path) -> np.ndarray:
    """A photo as (h, w, 3) uint8 RGB, whatever its mode, upright as its camera meant
    (EXIF orientation), the first frame of an animation."""
    from PIL import Image, ImageOps

    path = Path(path)
    if not path.is_file():
        raise InputError(f"{path}: photo not found")
    try:
        with Image.open(path) as image:
            image.seek(0)
            image.load()
            return as_rgb(ImageOps.exif_transpose(image))
    except Exception as exc:  # Pillow raises many kinds: unidentified, truncated, bombs
        reason = "not an image Pillow reads" if type(exc).__name__ == "UnidentifiedImageError" else str(exc)
        raise InputError(f"{path}: not a readable image ({reason})") from None


def mesh_from_photo(photo: str | Path, output: str | Path, symmetric: bool = True, replace: bool = True) -> FaceMesh:
    """Build a mesh from a photo file and write it as OBJ."""
    from .loading import write_obj
    try:
        import mediapipe  # noqa: F401
    except ImportError:
        raise InputError("mesh from-photo needs MediaPipe: pip install -e '.[photo]' (or make mesh)") from None
    mesh = build_face_mesh(read_image(photo), source=str(photo), symmetric=symmetric)
    header = (
        f"facesim face mesh built from {Path(photo).name} by facesim mesh from-photo\n"
        f"468 MediaPipe Face Mesh landmarks, 852 triangles; cm, +x subject's left, +y up, +z forward\n"
        f"symmetrised: {symmetric}"
    )
    write_obj(output, mesh, header=header, replace=replace)
    return mesh
