"""What the renderer draws: a figure of parts, and how each vertex follows the simulation.

A :class:`Figure` holds every vertex of the scene at rest, a colour per vertex and the
parts (skin, teeth, eyes, ...) with their triangles and material. Per frame,
:meth:`Figure.positions` turns the simulated skin (n vertices) and the jaw's pose into
the figure's vertices, in four linear steps:

1. ``follow``: vertices that ride the skin take a fixed linear combination of the
   simulation's displacements (for a bare mask, its own vertices one for one);
2. ``jaw``: vertices on the mandible (lower teeth, tongue, the floor of the mouth) turn
   with it about the hinge and glide with its condyles, by their weight; the tongue
   protrudes and raises its tip in the mandible's frame (:class:`Tongue`);
3. ``eyes``: each eyeball turns about its centre for the gaze;
4. the skin around each eye is kept outside its eyeball (a contact, as the lids slide).

For ICT's head (:func:`head_figure`) the face area follows the simulation mesh by
biharmonic interpolation (the smooth minimiser of the squared graph Laplacian, exact at
each landmark's vertex, zero on the rigid scalp, ears and neck); the mouth and eye sockets
follow the face area's openings harmonically, the eyelashes and the eye's lacrimal and
occlusion shells the lid vertices nearest them.
"""

from __future__ import annotations

from collections import OrderedDict
from dataclasses import dataclass, fields, replace
from pathlib import Path
from typing import NamedTuple

import numpy as np
from numba import njit, prange

from .. import cache
from ..config import PARALLEL_OPTIONS, VERSION
from ..geometry import axis_rotation, rotation
from ..physics import mesh
from ..physics.mesh import FaceMesh, smooth_interpolation, unique_edges
from ..physics.rig import LID_GAP
from .colours import BROWS, CARUNCLE, GUMS, IRIS, LASHES, LIPS, MOUTH_SOCKET, PUPIL, SCLERA, SKIN, TEETH
from .head import Head, HeadMesh
from .tongue import TONGUE_ROOT, Tongue, tongue_rig

#: ICT's parts drawn, with the colour (None: per vertex, see head_figure) and roughness of
#: each; the lacrimal fluid, eye blend and eye occlusion shells exist for a shader's
#: transparency and shadowing and are hidden.
HEAD_PARTS = {
    "M_Face": (None, 0.75), "M_BackHead": (None, 0.75), "M_GumsTongue": (GUMS, 0.4), "M_Teeth": (TEETH, 0.3),
    "M_ScleraLeft": (SCLERA, 0.2), "M_ScleraRight": (SCLERA, 0.2), "M_IrisLeft": (None, 0.2),
    "M_IrisRight": (None, 0.2), "M_EyeLashes": (LASHES, 0.9),
}
#: The skin inside the mouth (the socket) darkens with depth behind the lips (cm).
MOUTH_DEPTH = 1.5
#: Rigid skin of the face area: behind this depth (cm) above the jaw's angle (the ears and
#: mastoid), and below NECK_Y (the neck).
EAR_Z, EAR_ABOVE_Y, NECK_Y = 3.0, -3.5, -11.0
#: The head turns about the top of the spine (atlanto-occipital joint), in ICT's frame.
HEAD_NECK = (0.0, -1.5, 0.0)
#: Follow weights smaller than this are dropped (skin_follow).
FOLLOW_TOLERANCE = 1e-4
#: Eyelashes (upper, lower): opacity at the lid margin and length over which they fade (cm).
LASH_ALPHA, LASH_LENGTH = (0.9, 0.35), (0.7, 0.4)
#: Pupil and iris radii (cm), and the width of the iris's darker limbal ring: an adult
#: iris is about 11.7 mm across.
PUPIL_RADIUS, IRIS_RADIUS, LIMBUS = 0.2, 0.585, 0.1
#: The pupil dilates (ICT's PupilDilate, a control per eye: ``pupil_dilate_l``/``_r``) as
#: the iris's dilator draws the iris back toward its root: each iris vertex within
#: DILATING of the axis slides outward over the iris's surface, a fraction (the control)
#: of the way to PUPIL_OPEN, where ICT's fully dilated iris lies (its inner rim moves
#: from 0.12 to 0.55-0.62 cm from the axis, 0.575 on average).
DILATING, PUPIL_OPEN = 0.55, 0.575


@dataclass(frozen=True)
class Part:
    name: str
    triangles: np.ndarray  # (t, 3) into Figure.rest
    roughness: float = 0.75
    uv: np.ndarray | None = None  # (t, 3, 2) its corners in a face directory's texture atlas (facesim.face.bake), if textured


@dataclass(frozen=True)
class Pupil:
    """An eye's iris vertices within DILATING of its optical axis (rows), each's outward
    direction (k, 3) and distance from the axis (k,), and the iris's surface as heights
    along the axis over distances from it (sorted), which a vertex sliding outward follows."""

    rows: np.ndarray
    centre: np.ndarray
    axis: np.ndarray
    outward: np.ndarray
    radius: np.ndarray
    surface_radius: np.ndarray
    surface_height: np.ndarray

    def dilated(self, opening: float) -> np.ndarray:
        """(k, 3) the rows' displacement with the pupil dilated by ``opening`` (0-1)."""
        moved = self.radius + opening * (PUPIL_OPEN - self.radius)
        height = np.interp(moved, self.surface_radius, self.surface_height)
        rise = height - np.interp(self.radius, self.surface_radius, self.surface_height)
        return self.outward * (moved - self.radius)[:, None] + rise[:, None] * self.axis


#: ICT's tongue: the UV island of M_GumsTongue that holds this vertex, its tip (the
#: dorsum, which wraps round the tip onto the underside: 451 vertices from the root at
#: z 3.4 cm to the tip at z 9.75, behind the lower incisors and below their edge).
TONGUE_TIP = 16761


def _tongue_rows(head: Head) -> np.ndarray:
    """The tongue's vertices (TONGUE_TIP's island)."""
    rows = drawn_rows(head, "M_GumsTongue")
    triangles, uv = head.triangles[rows], head.triangle_uv[rows]
    tip_uv = uv[triangles == TONGUE_TIP][0]
    island = next(i for i in _components(uv, np.unique(uv)) if tip_uv in i)
    return np.unique(triangles[np.isin(uv, island).all(axis=1)])


def _pupil(x: np.ndarray, head: Head, side: str) -> Pupil:
    centre, axis, iris = _iris_axis(x, head, side)
    d = x[iris] - centre
    height = d @ axis
    across = d - height[:, None] * axis
    radius = np.linalg.norm(across, axis=1)
    front = height > 0
    order = np.argsort(radius[front])
    rows = front & (radius < DILATING) & (radius > 0)
    return Pupil(iris[rows], centre, axis, across[rows] / radius[rows, None], radius[rows],
                 radius[front][order], height[front][order])


class Follow(NamedTuple):
    """A sparse (k, n) matrix in compressed rows (as SciPy's csr_matrix holds one): row r's
    weights ``data[indptr[r]:indptr[r + 1]]`` on the columns ``indices`` of the same range.
    Kept as its arrays so that a figure read from facesim's cache imports no SciPy."""

    data: np.ndarray
    indices: np.ndarray
    indptr: np.ndarray
    shape: tuple[int, int]

    def __matmul__(self, x: np.ndarray) -> np.ndarray:
        """(k, ...) the weights times ``x`` (n, ...): SciPy's product (the calibration's,
        facesim.animation.calibration, not a render's)."""
        from scipy.sparse import csr_matrix

        return csr_matrix((self.data, self.indices, self.indptr), shape=self.shape) @ x

    def row_sums(self) -> np.ndarray:
        """(k,) each row's sum, its weights added in their order (as SciPy's product does)."""
        return np.bincount(np.repeat(np.arange(self.shape[0]), np.diff(self.indptr)), weights=self.data,
                           minlength=self.shape[0])


@dataclass(frozen=True)
class Figure:
    """rest : (N, 3); colour : (N, 4); sim_rest : (n, 3) the simulation mesh at rest;
    anchor : (n,) the figure vertex where each simulated vertex shows (muscle arrows);
    follow_rows : (k,), follow : (k, n) sparse displacement weights (shared by every identity),
    follow_gain : (n,) each simulated vertex's displacement scaled by it first; jaw_rows, jaw_weight : (j,);
    jaw_hinge, jaw_axis : (3,); eyes : (rows, centre) per eyeball; guards : (rows,
    centre, radius) per eye, skin kept outside it; neck : (3,) the head's pivot; pupils :
    per eye, ``Pupil``: the iris vertices a dilating pupil moves; tongue : ``Tongue``, its
    rig, or None."""

    rest: np.ndarray
    colour: np.ndarray
    parts: tuple[Part, ...]
    sim_rest: np.ndarray
    anchor: np.ndarray
    follow_rows: np.ndarray
    follow: np.ndarray
    follow_gain: np.ndarray
    jaw_rows: np.ndarray
    jaw_weight: np.ndarray
    jaw_hinge: np.ndarray
    jaw_axis: np.ndarray
    eyes: tuple
    guards: tuple
    neck: np.ndarray
    pupils: tuple = ()
    tongue: Tongue | None = None

    @property
    def triangles(self) -> np.ndarray:
        return np.concatenate([p.triangles for p in self.parts])

    def upper_lashes(self, lashes: Part) -> Part:
        """The eyelashes' part with only the upper lids' lashes: what a face directory's
        photo look draws (facesim.renderer.scene) and its rig carries (facesim.export.gltf).
        The photo's texture has the lashes the photo shows, drawn on the lids; a closing
        upper lid stretches them into a murky band over the eye with a gap at its foot,
        which neither a viewer nor MediaPipe reads as a closed eye (the capture's round
        trip read the astronaut's left blink at 0.81). The upper lashes close the eye with
        a lash line (0.91); the lower ones, over the photo's own, showed as a grey shelf
        under the open eye."""
        centres = np.array([centre for _, centre in self.eyes])
        middle = self.rest[lashes.triangles].mean(axis=1)
        nearest = centres[np.argmin(np.abs(middle[:, None, 0] - centres[None, :, 0]), axis=1)]
        return replace(lashes, triangles=lashes.triangles[middle[:, 1] > nearest[:, 1]])

    def positions(self, sim: np.ndarray, jaw=0.0, gaze: tuple[float, float] = (0.0, 0.0), look=None) -> np.ndarray:
        """(N, 3): the figure for simulated positions ``sim`` (n, 3), the jaw (its angle
        in radians, or (4,): the angle and its glide in cm, as Animation.jaw), the gaze
        (yaw, pitch in degrees) and each eye's own turn on top of it (``look``, (8,): the
        subject's left eye's yaw and pitch, then the right's, then each pupil's dilation,
        0-1, left and right, then the tongue's protrusion and tip raise, 0-1;
        facesim.animation.simulate.look_table)."""
        jaw = np.atleast_1d(np.asarray(jaw, dtype=np.float64))
        jaw_angle, glide = jaw[0], jaw[1:4]
        x = np.empty_like(self.rest)
        follow = self.follow
        _followed(self.rest, self.follow_rows, follow.indptr, follow.indices, follow.data, self.follow_gain,
                  np.ascontiguousarray(sim, dtype=np.float64), self.sim_rest, x)
        if jaw_angle and len(self.jaw_rows):
            rest = self.rest[self.jaw_rows] - self.jaw_hinge
            turned = rest @ axis_rotation(self.jaw_axis, jaw_angle).T
            x[self.jaw_rows] += self.jaw_weight[:, None] * (turned - rest)
        if glide.any() and len(self.jaw_rows):
            x[self.jaw_rows] += self.jaw_weight[:, None] * glide
        if self.tongue is not None and look is not None and len(look) > 7 and (look[6] or look[7]):
            moved = self.tongue.displaced(look[6], look[7], jaw_angle)  # in the mandible's frame: turned with it
            x[self.tongue.rows] += moved @ axis_rotation(self.jaw_axis, jaw_angle).T if jaw_angle else moved
        if look is not None and len(look) > 4:
            for pupil in self.pupils:
                opening = look[4] if pupil.centre[0] > 0 else look[5]
                if opening:
                    x[pupil.rows] += pupil.dilated(opening)
        for rows, centre in self.eyes:
            own = (0.0, 0.0) if look is None else look[0:2] if centre[0] > 0 else look[2:4]
            yaw, pitch = gaze[0] + own[0], gaze[1] + own[1]
            if yaw or pitch:
                x[rows] = (x[rows] - centre) @ rotation(yaw, pitch).T + centre
        for rows, centre, radius in self.guards:
            d = x[rows] - centre
            r = np.linalg.norm(d, axis=1)
            inside = r < radius
            x[rows[inside]] = centre + d[inside] * (radius[inside] / r[inside])[:, None]
        return x


@njit(**dict(PARALLEL_OPTIONS, fastmath=False))
def _followed(rest, rows, indptr, indices, weights, gain, sim, sim_rest, out):
    """``out`` = the figure at rest, its skin rows moved by the follow (``skin_follow``,
    in compressed rows) of the simulated vertices' displacements times their gain: the
    sparse product of ``Figure.positions``, on every core, summed in the order SciPy's
    product sums (without fastmath, so the same bits in every process)."""
    moved = np.empty_like(sim)
    for j in range(sim.shape[0]):
        for d in range(3):
            moved[j, d] = gain[j] * (sim[j, d] - sim_rest[j, d])
    for i in prange(rest.shape[0]):
        for d in range(3):
            out[i, d] = rest[i, d]
    for r in prange(rows.shape[0]):
        sx = sy = sz = 0.0
        for k in range(indptr[r], indptr[r + 1]):
            j = indices[k]
            w = weights[k]
            sx += w * moved[j, 0]
            sy += w * moved[j, 1]
            sz += w * moved[j, 2]
        i = rows[r]
        out[i, 0] += sx
        out[i, 1] += sy
        out[i, 2] += sz


def _rigid_face(x: np.ndarray, face: FaceMesh) -> np.ndarray:
    """The face area's skin that no muscle moves: its rim, the ears and mastoid, the neck."""
    rigid = ((x[:, 2] < EAR_Z) & (x[:, 1] > EAR_ABOVE_Y)) | (x[:, 1] < NECK_Y)
    rigid[face.boundary_loops[0]] = True
    return np.flatnonzero(rigid)


def _inside_polygon(points: np.ndarray, polygon: np.ndarray) -> np.ndarray:
    """(k,) whether each 2D point lies inside the closed polygon (n, 2), by the even-odd
    rule: a ray from the point toward +x crosses its edges an odd number of times. (What
    matplotlib.path.Path.contains_points answers, without importing matplotlib, a sixth of
    a second of a fresh render.)"""
    a, b = polygon, np.roll(polygon, -1, axis=0)
    x, y = points[:, :1], points[:, 1:]
    spans = (a[:, 1] > y) != (b[:, 1] > y)  # (k, n): the edge straddles the ray's height
    with np.errstate(divide="ignore", invalid="ignore"):
        crossing = a[:, 0] + (y - a[:, 1]) * (b[:, 0] - a[:, 0]) / (b[:, 1] - a[:, 1])
    return (spans & (x < crossing)).sum(axis=1) % 2 == 1


def _lip_colour(x: np.ndarray, head: Head, rows: np.ndarray) -> np.ndarray:
    """(k,) how much of the lips' colour each skin vertex takes: inside the vermilion
    outline (MediaPipe's outer lip landmarks on this head), softened over 1.5 mm."""
    ring = [61, 185, 40, 39, 37, 0, 267, 269, 270, 409, 291, 375, 321, 405, 314, 17, 84, 181, 91, 146]
    outline = head.landmark_positions[ring]
    front = x[rows, 2] > outline[:, 2].min() - 1.0
    inside = _inside_polygon(x[rows, :2], outline[:, :2]) & front
    edge = np.min(np.linalg.norm(x[rows, None, :2] - outline[None, :, :2], axis=2), axis=1)
    return np.where(inside, np.clip(edge / 0.15, 0.0, 1.0) * 0.5 + 0.5, 0.0) * (edge < 3)


#: The eyebrows: MediaPipe's upper brow contour from the tail to the head of the brow,
#: then its lower contour back (the face's right brow, then its left).
BROW_OUTLINES = ([70, 63, 105, 66, 107, 55, 65, 52, 53, 46], [300, 293, 334, 296, 336, 285, 295, 282, 283, 276])
#: How much of the brows' colour their skin takes at most; how far (cm) the brow reaches
#: outside MediaPipe's outline (which hugs a brow's densest hair) and the width over which
#: it fades out there; the brow's head (toward the nose) takes BROW_HEAD of it.
BROW_DENSITY, BROW_MARGIN, BROW_EDGE, BROW_HEAD = 0.9, 0.12, 0.15, 0.65


def _distance_to_outline(points: np.ndarray, polygon: np.ndarray) -> np.ndarray:
    """(k,) each 2D point's distance to the closed polygon's (n, 2) edges."""
    a, b = polygon, np.roll(polygon, -1, axis=0)
    ab = b - a
    t = np.clip(((points[:, None] - a) * ab).sum(axis=2) / (ab * ab).sum(axis=1), 0.0, 1.0)
    return np.linalg.norm(points[:, None] - (a + t[:, :, None] * ab), axis=2).min(axis=1)


def _brow_colour(x: np.ndarray, head: Head, rows: np.ndarray) -> np.ndarray:
    """(k,) how much of the brows' colour each skin vertex takes: MediaPipe's brow outline
    on this head and BROW_MARGIN around it, fading out over BROW_EDGE, lighter toward the
    brow's head. A bald clay head reads its brows' motion (AU1, AU2, AU4) only from their
    colour, which rides the skin as the lips' does."""
    density = np.zeros(len(rows))
    reach = BROW_MARGIN + BROW_EDGE
    for ring in BROW_OUTLINES:
        outline = head.landmark_positions[ring]
        near = np.flatnonzero((np.abs(x[rows, :2] - outline[:, :2].mean(axis=0))
                               <= np.ptp(outline[:, :2], axis=0) / 2 + reach).all(axis=1))  # the outline's box
        points = x[rows[near]]
        inside = _inside_polygon(points[:, :2], outline[:, :2])
        edge = _distance_to_outline(points[:, :2], outline[:, :2])
        tail, brow_head = outline[0, 0], outline[4, 0]
        along = np.clip((points[:, 0] - brow_head) / (tail - brow_head), 0.0, 1.0)  # 0 at the head, 1 at the tail
        taper = BROW_HEAD + (1.0 - BROW_HEAD) * np.minimum(along / 0.3, 1.0)
        signed = np.where(inside, -edge, edge)  # cm outside the outline
        front = points[:, 2] > outline[:, 2].min() - 1.0
        fade = np.clip((BROW_MARGIN - signed) / BROW_EDGE, 0.0, 1.0) * front
        density[near] = np.maximum(density[near], fade * taper * BROW_DENSITY)
    return density


def _face_follow(head: Head) -> np.ndarray:
    """(9409, 468) biharmonic weights of the face area on the landmarks' vertices."""
    face = FaceMesh(head.neutral[: head.face_count], head.triangles_of("M_Face"))
    handles = head.landmarks
    rigid = np.setdiff1d(_rigid_face(face.vertices, face), handles)
    fixed = np.concatenate([handles, rigid])
    values = np.zeros((len(fixed), len(handles)))
    values[np.arange(len(handles)), np.arange(len(handles))] = 1.0
    return smooth_interpolation(face.edges, face.vertex_count, fixed, values, order=2)


_FOLLOW: dict[str, tuple[np.ndarray, np.ndarray]] = {}


def skin_follow(head: Head) -> tuple[np.ndarray, Follow]:
    """Rows (k,) and weights (k, 468), sparse: how the head's skin follows the
    displacements of the landmarks' vertices. The solves run over the mesh's graph
    Laplacian and the rigid and deep vertices are chosen on the generic head, so one set of
    weights serves every identity (computed once per process: the biharmonic solve takes a
    second). Weights under FOLLOW_TOLERANCE are dropped: 8% of them remain, a frame's
    skin costs 2 ms instead of 11 and moves less than 0.01 mm differently (measured on
    surprise), and no multi-threaded BLAS call competes with the software rasteriser's
    threads for the two cores. Kept on disk (facesim.cache): a fresh process reads them
    in about 20 ms."""
    key = cache.key(head.neutral.tobytes(), head.triangles.tobytes(), head.landmarks.tobytes(), Path(__file__).read_bytes(),
                    Path(mesh.__file__).read_bytes())
    if key not in _FOLLOW:
        stored = cache.cached_arrays("skin-follow", key, lambda: _skin_follow(head))
        _FOLLOW[key] = (stored["rows"], Follow(stored["data"], stored["indices"], stored["indptr"],
                                               tuple(int(n) for n in stored["shape"])))
    return _FOLLOW[key]


def _skin_follow(head: Head) -> dict[str, np.ndarray]:
    from scipy.sparse import csr_matrix

    x = head.neutral
    n_face = head.face_count
    face_follow = _face_follow(head)
    # Sockets follow the face's openings harmonically, fixed in the skull behind them.
    socket_triangles = head.triangles_of("M_BackHead")
    socket = np.setdiff1d(np.unique(socket_triangles), np.arange(n_face))
    shared = np.intersect1d(np.unique(socket_triangles), np.arange(n_face))
    deep = np.concatenate([head.part("head_neck"), _deep_mouth(head),
                           *[p[x[p, 2] < x[p, 2].max() - 0.8] for p in (head.part("eye_socket_left"), head.part("eye_socket_right"))]])
    fixed = np.concatenate([shared, np.setdiff1d(deep, shared)])
    socket_weights = smooth_interpolation(unique_edges(socket_triangles), len(x), fixed,
                                          np.vstack([face_follow[shared], np.zeros((len(fixed) - len(shared), len(head.landmarks)))]))
    # Eyelashes and the eyes' shells ride the three lid vertices nearest them.
    bound = []
    for part, lid_region in (("left", 1), ("right", -1)):
        for kind in ("eyelashes", "lacrimal_fluid", "eye_occlusion", "eye_blend"):
            rows = head.part(f"{kind}_{part}")
            lid = np.flatnonzero((np.sign(x[:n_face, 0]) == lid_region) & (np.linalg.norm(x[:n_face] - x[rows].mean(axis=0), axis=1) < 3.0))
            d = np.linalg.norm(x[rows, None] - x[None, lid], axis=2)
            near = np.argsort(d, axis=1)[:, :3]
            w = 1.0 / (np.take_along_axis(d, near, axis=1) + 1e-3)
            w /= w.sum(axis=1, keepdims=True)
            bound.append((rows, np.einsum("kj,kjn->kn", w, face_follow[lid[near]])))
    rows = np.concatenate([np.arange(n_face), socket] + [r for r, _ in bound])
    weights = np.vstack([face_follow, socket_weights[socket]] + [w for _, w in bound])
    weights = csr_matrix(np.where(np.abs(weights) > FOLLOW_TOLERANCE, weights, 0.0))
    return dict(rows=rows, data=weights.data, indices=weights.indices, indptr=weights.indptr, shape=np.array(weights.shape))


def _deep_mouth(head: Head) -> np.ndarray:
    """The mouth socket's vertices deeper than MOUTH_DEPTH behind the lips: rigid in the
    skull, or turning with the mandible."""
    mouth = head.part("mouth_socket")
    return mouth[head.neutral[mouth, 2] < head.neutral[mouth, 2].max() - MOUTH_DEPTH]


def head_figure(head: Head, model) -> Figure:
    """ICT's head driven by the simulation ``model`` of its skin (facesim.physics.model.Model)."""
    sim_rest = model.rest_position
    x = head.vertices
    n_face = head.face_count
    n = len(sim_rest)
    follow_rows, follow = skin_follow(head)
    # The lids travel as far as the head's own opening: a lid landmark's motion is scaled by
    # the ratio of the head's lid gap to the simulation mesh's (eyes open wider on ICT's head).
    gain = np.ones(n)
    for upper, lower in [(lid.upper, lid.lower) for lid in model.muscles.eyelids]:
        head_gap = x[head.landmarks[upper], 1] - x[head.landmarks[lower], 1]
        sim_gap = sim_rest[upper, 1] - sim_rest[lower, 1]
        ratio = np.clip((head_gap - LID_GAP) / np.maximum(sim_gap - LID_GAP, 1e-3), 0.5, 3.0)  # closed: both LID_GAP
        gain[upper] = gain[lower] = ratio
    mouth = head.part("mouth_socket")
    deep_mouth = _deep_mouth(head)

    # The mandible: lower teeth and gums, the tongue, the floor of the mouth.
    teeth = head.part("teeth")
    upper_teeth_bottom = np.percentile(x[teeth, 1], 35)
    lower_rows = np.concatenate([teeth, head.part("gums_tongue"), mouth])
    y = x[lower_rows, 1]
    weight = np.clip((upper_teeth_bottom + 0.3 - y) / 0.6, 0.0, 1.0)
    teeth_components = _components(head.triangles_of("M_Teeth"), teeth)
    for rows in teeth_components:  # a tooth is rigid: upper or lower as a whole
        weight[np.isin(lower_rows, rows)] = float(x[rows, 1].mean() < np.mean([x[r, 1].mean() for r in teeth_components]))
    # The socket's lining turns with the mandible in the mouth's depth; nearer the lips, only
    # as far as the skin does not already carry it (its follow rows): turned there and
    # carried too, the lining in front of the lower incisors went down with them twice over
    # and hid them (happy with the jaw open: 392 -> 74 pixels of teeth).
    socket_part = np.isin(lower_rows, mouth)
    shallow = socket_part & ~np.isin(lower_rows, deep_mouth)
    followed = np.zeros(len(x))
    followed[follow_rows] = follow.row_sums()
    weight[shallow] *= np.clip(1.0 - followed[lower_rows[shallow]], 0.0, 1.0)
    tongue = tongue_rig(x, _tongue_rows(head))  # on the floor of the mouth: all of it that its rig moves turns with the mandible
    in_tongue = np.isin(lower_rows, tongue.rows)
    weight[in_tongue] = np.maximum(weight[in_tongue], np.clip((x[lower_rows[in_tongue], 2] - TONGUE_ROOT + 2.0) / 2.0, 0, 1))

    colour = np.tile(np.array(SKIN), (len(x), 1))
    lips = _lip_colour(x, head, np.arange(n_face))
    colour[:n_face] = (1 - lips[:, None]) * np.array(SKIN) + lips[:, None] * np.array(LIPS)
    brows = _brow_colour(x, head, np.arange(n_face))[:, None]
    colour[:n_face] = (1 - brows) * colour[:n_face] + brows * np.array(BROWS)
    colour[mouth] = MOUTH_SOCKET
    for side in ("left", "right"):
        colour[head.part(f"eye_socket_{side}")] = CARUNCLE
    colour[head.part("gums_tongue")] = GUMS
    colour[teeth] = TEETH
    parts = []
    eyes, guards = [], []
    _, tile, atlas = atlas_uv(head)
    for material in HEAD_PARTS:
        tri = head.triangles[drawn_rows(head, material)]
        if HEAD_PARTS[material][0] is not None:
            colour[np.unique(tri)] = HEAD_PARTS[material][0]
        uv = atlas[tile == TILES.index(material)] if material in TILES else None
        parts.append(Part(material, tri, HEAD_PARTS[material][1], uv))
    colour[:, 3] = 1.0
    for side in ("left", "right"):
        colour[head.part(f"eyelashes_{side}"), 3] = _lash_alpha(x, head, side)
    for side in ("left", "right"):
        ball = head.part(f"eyeball_{side}")
        centre, radius = head.eyeball(side)
        colour[_iris_axis(x, head, side)[2]] = _eye_colour(x, head, side)
        eyes.append((ball, centre))
        near = np.flatnonzero(np.linalg.norm(x[:n_face] - centre, axis=1) < 1.6 * radius)
        distance = np.linalg.norm(x[near] - centre, axis=1)
        guards.append((near, centre, np.minimum(distance, radius + 0.02)))
    return Figure(
        rest=x, colour=colour.astype(np.float32), parts=tuple(parts), sim_rest=np.asarray(sim_rest), anchor=head.landmarks,
        follow_rows=follow_rows, follow=follow, follow_gain=gain, jaw_rows=lower_rows[weight > 0], jaw_weight=weight[weight > 0],
        jaw_hinge=model.rig.jaw_hinge, jaw_axis=model.rig.jaw_axis, eyes=tuple(eyes), guards=tuple(guards), neck=np.array(HEAD_NECK),
        pupils=tuple(_pupil(x, head, side) for side in ("left", "right")), tongue=tongue,
    )


def drawn_rows(head: Head, material: str) -> np.ndarray:
    """The indices of one of ICT's materials' triangles that the figure draws: all of
    them, but for the sclera, which runs on over the iris as a clear cornea, left out there."""
    rows = np.flatnonzero(head.triangle_material == head.materials.index(material))
    if material.startswith("M_Sclera"):
        rows = rows[~_over_iris(head.vertices, head, material[len("M_Sclera"):].lower(), head.triangles[rows])]
    return rows


def _iris_axis(x: np.ndarray, head: Head, side: str):
    """The eye's centre, its unit optical axis (toward the apex of the cornea: the front
    sclera vertices farthest from the centre) and the vertices of its inner sphere."""
    centre, _ = head.eyeball(side)
    sclera = np.unique(head.triangles_of(f"M_Sclera{side.title()}"))
    d = x[sclera] - centre
    reach = np.where(d[:, 2] > 0, np.linalg.norm(d, axis=1), 0.0)
    axis = d[np.argsort(reach)[-20:]].mean(axis=0)
    return centre, axis / np.linalg.norm(axis), np.unique(head.triangles_of(f"M_Iris{side.title()}"))


def _lash_alpha(x: np.ndarray, head: Head, side: str) -> np.ndarray:
    """(k,) opacity of ICT's eyelash cards (made for a hair texture with alpha): dense at
    the lid margin, fading to nothing at the tips, the lower lashes sparser. Drawn solid,
    the cards read as a dark band of eyeliner under the eye."""
    from scipy.spatial import cKDTree

    rows = head.part(f"eyelashes_{side}")
    reach, _ = cKDTree(x[: head.face_count]).query(x[rows])  # from the skin they grow out of
    centre, _ = head.eyeball(side)
    upper = x[rows, 1] > centre[1]
    length = np.where(upper, LASH_LENGTH[0], LASH_LENGTH[1])
    return np.where(upper, LASH_ALPHA[0], LASH_ALPHA[1]) * np.clip(1 - reach / length, 0.0, 1.0) ** 1.5


def _eye_colour(x: np.ndarray, head: Head, side: str) -> np.ndarray:
    """(k, 4) colours of the eye's inner sphere (ICT's M_Iris, which a texture would paint
    whole): a dark pupil on the axis, the iris around it darkening to a limbal ring at
    IRIS_RADIUS, white sclera beyond; the back half, seen only through the pupil, dark."""
    centre, axis, iris = _iris_axis(x, head, side)
    d = x[iris] - centre
    r = np.where(d @ axis > 0, np.linalg.norm(np.cross(d, axis), axis=1), np.inf)
    limbus = np.clip((r - (IRIS_RADIUS - LIMBUS)) / LIMBUS, 0.0, 1.0)[:, None]
    iris_colour = (1 - 0.55 * limbus) * np.array(IRIS) + 0.55 * limbus * np.array(PUPIL)
    colour = np.where((r < IRIS_RADIUS)[:, None], iris_colour, np.array(SCLERA))
    colour[(r < PUPIL_RADIUS) | (d @ axis <= 0)] = PUPIL
    return colour


def _over_iris(x: np.ndarray, head: Head, side: str, triangles: np.ndarray) -> np.ndarray:
    """(t,) which sclera triangles lie in front of the iris (the clear cornea)."""
    centre, axis, _ = _iris_axis(x, head, side)
    points = x[triangles].mean(axis=1) - centre
    return (points @ axis > 0) & (np.linalg.norm(np.cross(points, axis), axis=1) < IRIS_RADIUS + LIMBUS)


def _components(triangles: np.ndarray, rows: np.ndarray) -> list[np.ndarray]:
    """The pieces of ``rows`` that ``triangles`` join, in the order of their smallest vertex."""
    label = mesh.component_labels(triangles[:, [0, 1, 1, 2]].reshape(-1, 2), rows.max() + 1)
    return [rows[label[rows] == k] for k in np.unique(label[rows])]


#: Figures kept per process (a dataset of many identities keeps only the latest).
FIGURE_CACHE = 4
_figures: "OrderedDict[int, tuple]" = OrderedDict()


def figure_for(model):
    """What the renderer draws for a model: a head's figure (built once per model), or
    None for a face mask."""
    if not isinstance(model.mesh, HeadMesh):
        return None
    if id(model) not in _figures:
        _figures[id(model)] = (model, _stored_figure(model))  # the model kept alive with its key
        while len(_figures) > FIGURE_CACHE:
            _figures.popitem(last=False)
    _figures.move_to_end(id(model))
    return _figures[id(model)][1]


#: The code a figure is built by: a stored figure (``_stored_figure``) is keyed by it.
FIGURE_CODE = tuple(sorted(Path(__file__).parent.glob("*.py"))) + tuple(
    Path(__file__).parent.parent / "physics" / name for name in ("mesh.py", "rig.py", "muscles.py", "model.py"))


def _stored_figure(model) -> Figure:
    """``head_figure`` of a model's head, kept in facesim's cache (a warm render reads it
    in milliseconds, where building it took 0.15 s and SciPy's spatial and graph modules),
    keyed by everything it is built from: the head's arrays and parts, the simulation
    mesh at rest, the eyelids' landmarks, the jaw's hinge and axis, and the code."""
    head = model.mesh.head
    arrays = [np.ascontiguousarray(getattr(head, f.name)).tobytes() for f in fields(head)
              if isinstance(getattr(head, f.name), np.ndarray)]
    lids = [np.ascontiguousarray(np.r_[lid.upper, lid.lower]).tobytes() for lid in model.muscles.eyelids]
    key = cache.key(*arrays, repr((head.materials, sorted(head.parts.items()))).encode(), *lids,
                    np.ascontiguousarray(model.rest_position).tobytes(), np.asarray(model.rig.jaw_hinge).tobytes(),
                    np.asarray(model.rig.jaw_axis).tobytes(), VERSION.encode(), *(path.read_bytes() for path in FIGURE_CODE))
    # 3.4 MB each: 16 kept (4 kept, the suite built 55 figures again in a run)
    stored = cache.cached_arrays("figure", key, lambda: _figure_arrays(head_figure(head, model)), keep=16)
    return _figure_from(stored, head)


def _figure_arrays(figure: Figure) -> dict[str, np.ndarray]:
    """A figure as named arrays (facesim.cache keeps no Python objects), but for what its
    head gives again at no cost: its vertices at rest, and the skin's follow weights,
    shared by every identity and kept in the cache once (``skin_follow``: 7.5 of the
    entry's 11.8 MB, written again for every identity of a dataset)."""
    out = {name: np.asarray(getattr(figure, name)) for name in
           ("colour", "sim_rest", "anchor", "follow_gain", "jaw_rows", "jaw_weight", "jaw_hinge", "jaw_axis", "neck")}
    out.update(part_names=np.array([p.name for p in figure.parts]),
               part_roughness=np.array([p.roughness for p in figure.parts], dtype=np.float64),
               counts=np.array([len(figure.eyes), len(figure.guards), len(figure.pupils), figure.tongue is not None]))
    for k, part in enumerate(figure.parts):
        out[f"part{k}_triangles"] = part.triangles
        if part.uv is not None:
            out[f"part{k}_uv"] = part.uv
    for k, (rows, centre) in enumerate(figure.eyes):
        out[f"eye{k}_rows"], out[f"eye{k}_centre"] = rows, np.asarray(centre)
    for k, (rows, centre, radius) in enumerate(figure.guards):
        out[f"guard{k}_rows"], out[f"guard{k}_centre"], out[f"guard{k}_radius"] = rows, np.asarray(centre), radius
    for k, pupil in enumerate(figure.pupils):
        out.update({f"pupil{k}_{f.name}": np.asarray(getattr(pupil, f.name)) for f in fields(Pupil)})
    if figure.tongue is not None:
        out.update({f"tongue_{f.name}": np.asarray(getattr(figure.tongue, f.name)) for f in fields(Tongue)})
    return out


def _figure_from(arrays: dict[str, np.ndarray], head: Head) -> Figure:
    """The figure of ``head`` that ``_figure_arrays`` wrote."""
    eyes, guards, pupils, tongue = (int(n) for n in arrays["counts"])
    follow_rows, follow = skin_follow(head)
    parts = tuple(Part(str(name), arrays[f"part{k}_triangles"], float(roughness), arrays.get(f"part{k}_uv"))
                  for k, (name, roughness) in enumerate(zip(arrays["part_names"], arrays["part_roughness"])))
    return Figure(
        rest=head.vertices, colour=arrays["colour"], parts=parts, sim_rest=arrays["sim_rest"], anchor=arrays["anchor"],
        follow_rows=follow_rows, follow=follow, follow_gain=arrays["follow_gain"], jaw_rows=arrays["jaw_rows"], jaw_weight=arrays["jaw_weight"],
        jaw_hinge=arrays["jaw_hinge"], jaw_axis=arrays["jaw_axis"],
        eyes=tuple((arrays[f"eye{k}_rows"], arrays[f"eye{k}_centre"]) for k in range(eyes)),
        guards=tuple((arrays[f"guard{k}_rows"], arrays[f"guard{k}_centre"], arrays[f"guard{k}_radius"]) for k in range(guards)),
        neck=arrays["neck"],
        pupils=tuple(Pupil(**{f.name: arrays[f"pupil{k}_{f.name}"] for f in fields(Pupil)}) for k in range(pupils)),
        tongue=Tongue(**{f.name: arrays[f"tongue_{f.name}"] for f in fields(Tongue)}) if tongue else None,
    )


#: The baked photo's texture atlas (facesim.face.bake): each ICT material that takes the
#: photo in a tile of its own.
#: The atlas's tiles: the ICT material each holds, in order left to right, top to bottom.
TILES = ("M_Face", "M_BackHead", "M_ScleraLeft", "M_IrisLeft", "M_ScleraRight", "M_IrisRight")
#: Tiles across the atlas (and so, down: two).
COLUMNS = 3
#: Texels per tile side.
TILE = 1024


def atlas_uv(head) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The head's textured triangles as drawn: (k,) their indices, (k,) their tile, and
    (k, 3, 2) their corners' UVs in the atlas's [0, 1]² (v up, as OBJ has it)."""
    rows = len(TILES) // COLUMNS
    rows_of, tiles, uvs = [], [], []
    for index, material in enumerate(TILES):
        keep = drawn_rows(head, material)
        uv = head.uv[head.triangle_uv[keep]].astype(np.float64)  # (k, 3, 2)
        uv -= np.floor(uv.mean(axis=1, keepdims=True))  # into [0, 1]² of its own ICT tile
        uv = np.clip(uv, 0.0, 1.0)
        column, row = index % COLUMNS, index // COLUMNS
        uv[:, :, 0] = (uv[:, :, 0] + column) / COLUMNS
        uv[:, :, 1] = (uv[:, :, 1] + (rows - 1 - row)) / rows
        rows_of.append(keep)
        tiles.append(np.full(len(keep), index))
        uvs.append(uv)
    return np.concatenate(rows_of), np.concatenate(tiles), np.concatenate(uvs)
