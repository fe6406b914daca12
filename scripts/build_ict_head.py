"""Vendor ICT FaceKit's head into facesim: ``meshes/ict/head.npz`` and its licence.

Reads the upstream data (``generic_neutral_mesh.obj`` and ``shapes.npz`` of ICT FaceKit,
github.com/ICT-VGL/ICT-FaceKit, MIT licence) and writes one compressed archive that
facesim loads in a few milliseconds:

- ``neutral`` (26719, 3) float32, cm, in ICT's own vertex order (the OBJ's ``v`` lines,
  read by hand: trimesh would re-index the vertices at UV seams);
- ``triangles`` (t, 3) int32, every polygon split into a fan, ``triangle_material``
  (t,) uint8 indexing ``materials`` (the OBJ's ``usemtl`` groups);
- ``uv`` (u, 2) float32 and ``triangle_uv`` (t, 3) int32: the texture layout, per corner;
- ``part_names`` and ``part_ranges`` (p, 2), inclusive vertex ranges (ICT's documentation);
- ``landmarks`` (468,) int32: the face-area vertex of each of MediaPipe's 468 landmarks
  (:func:`landmarks_on_head`), the handle the simulation moves; ``landmark_vertex`` and
  ``landmark_weight`` (468, 8): where each landmark lies, as weights of head vertices
  (:func:`symmetric_weights`), the simulation mesh's rest; ``simulation_triangles``
  (852, 3): MediaPipe's tessellation of them, the simulation mesh (facesim.face.figure);
- ``identity_deltas`` (100, 26719, 3) float16: all of ICT's identity modes (13 MB
  compressed), a new face being neutral + Σ wᵢ · deltaᵢ.

It also writes ``head.muscles.yaml``, the head's muscle file: the muscles, sphincters,
jaw and eyelids of the Hopper face's file (``meshes/face.muscles.yaml``), whose landmark
indices are the simulation mesh's vertices.

ICT's expression shapes are not vendored here: facesim's motion comes from its muscles.

Usage: ``python scripts/build_ict_head.py ICT_DIR [-o meshes/ict]``.
"""

from __future__ import annotations

import argparse
import shutil
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent

#: ICT FaceKit's parts, inclusive vertex ranges (its README).
PARTS = {
    "face": (0, 9408),
    "head_neck": (9409, 11247),
    "mouth_socket": (11248, 13293),
    "eye_socket_left": (13294, 13677),
    "eye_socket_right": (13678, 14061),
    "gums_tongue": (14062, 17038),
    "teeth": (17039, 21450),
    "eyeball_left": (21451, 23020),
    "eyeball_right": (23021, 24590),
    "lacrimal_fluid_left": (24591, 24794),
    "lacrimal_fluid_right": (24795, 24998),
    "eye_blend_left": (24999, 25022),
    "eye_blend_right": (25023, 25046),
    "eye_occlusion_left": (25047, 25198),
    "eye_occlusion_right": (25199, 25350),
    "eyelashes_left": (25351, 26034),
    "eyelashes_right": (26035, 26718),
}


def read_obj(path: Path):
    """Vertices, UVs, and per polygon its vertex and UV indices and material, in file order."""
    vertices, uv, polygons, polygon_uv, material, names = [], [], [], [], [], []
    current = 0
    for line in path.read_text().splitlines():
        if line.startswith("v "):
            vertices.append([float(c) for c in line.split()[1:4]])
        elif line.startswith("vt "):
            uv.append([float(c) for c in line.split()[1:3]])
        elif line.startswith("usemtl "):
            name = line.split()[1]
            if name not in names:
                names.append(name)
            current = names.index(name)
        elif line.startswith("f "):
            corners = [c.split("/") for c in line.split()[1:]]
            polygons.append([int(c[0]) - 1 for c in corners])
            polygon_uv.append([int(c[1]) - 1 for c in corners])
            material.append(current)
    return np.array(vertices), np.array(uv), polygons, polygon_uv, np.array(material), names


def fans(polygons: list[list[int]]) -> tuple[np.ndarray, np.ndarray]:
    """Each polygon as a fan of triangles; returns the triangles and their polygon."""
    triangles, owner = [], []
    for k, p in enumerate(polygons):
        for j in range(1, len(p) - 1):
            triangles.append([p[0], p[j], p[j + 1]])
            owner.append(k)
    return np.array(triangles, dtype=np.int32), np.array(owner)


def build(ict: Path, out: Path) -> None:
    vertices, uv, polygons, polygon_uv, material, names = read_obj(ict / "generic_neutral_mesh.obj")
    shapes = np.load(ict / "shapes.npz")
    neutral = shapes["neutral"].astype(np.float32)
    if neutral.shape != vertices.shape or np.abs(neutral - vertices).max() > 1e-4:
        raise SystemExit("shapes.npz's neutral does not match the OBJ's vertices")
    triangles, owner = fans(polygons)
    triangle_uv, _ = fans(polygon_uv)
    from facesim.face.loading import load_mesh
    from facesim.physics.mesh import FaceMesh
    face_triangles = triangles[material[owner] == names.index("M_Face")]
    hopper = load_mesh(ROOT / "meshes" / "face.obj")
    measured = np.load(ict / "mediapipe_landmarks_on_ict.npz")
    mediapipe = measured["position"]
    landmarks, mirror_landmark, mirror_vertex = landmarks_on_head(FaceMesh(neutral[:PARTS["face"][1] + 1], face_triangles), mediapipe, hopper)
    landmark_vertex, landmark_weight = symmetric_weights(measured, mirror_landmark, mirror_vertex)
    out.mkdir(parents=True, exist_ok=True)
    np.savez_compressed(
        out / "head.npz",
        neutral=neutral,
        triangles=triangles,
        triangle_material=material[owner].astype(np.uint8),
        materials=np.array(names),
        uv=uv.astype(np.float32),
        triangle_uv=triangle_uv,
        part_names=np.array(list(PARTS)),
        part_ranges=np.array(list(PARTS.values()), dtype=np.int32),
        landmarks=landmarks.astype(np.int32),
        landmark_vertex=landmark_vertex,
        landmark_weight=landmark_weight,
        simulation_triangles=hopper.faces.astype(np.int32),
        identity_deltas=shapes["identity_deltas"].astype(np.float16),
    )
    shutil.copyfile(ict / "LICENSE", out / "LICENSE")
    write_muscles(ict, out)
    print(f"wrote {out / 'head.npz'}: {len(neutral)} vertices, {len(triangles)} triangles, "
          f"{len(shapes['identity_deltas'])} identity modes, {(out / 'head.npz').stat().st_size / 1e6:.1f} MB")


def _arcs(x: np.ndarray, loop: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """An opening's upper and lower arcs between its corners (leftmost and rightmost vertices)."""
    first, last = sorted([int(np.argmin(x[loop, 0])), int(np.argmax(x[loop, 0]))])
    a = loop[first + 1:last]
    b = np.concatenate([loop[last + 1:], loop[:first]])
    return (a, b) if x[a, 1].mean() > x[b, 1].mean() else (b, a)


def _sheets(face, opening: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Which face-area vertices belong to the upper and to the lower lip (or lid) of an
    opening: those nearer, along the surface, to its upper or its lower arc. ICT's lips and
    lids are separate sheets that touch; they join only at the corners."""
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import dijkstra

    x, e = face.vertices, face.edges
    length = np.linalg.norm(x[e[:, 0]] - x[e[:, 1]], axis=1)
    graph = coo_matrix((length, (e[:, 0], e[:, 1])), shape=(len(x), len(x))).tocsr()
    upper, lower = _arcs(x, opening)
    to_upper = dijkstra(graph, directed=False, indices=upper, min_only=True)
    to_lower = dijkstra(graph, directed=False, indices=lower, min_only=True)
    return np.flatnonzero(to_upper < to_lower), np.flatnonzero(to_lower < to_upper)


def landmarks_on_head(face, mediapipe: np.ndarray, hopper) -> np.ndarray:
    """(468,) the face-area vertex of each MediaPipe landmark: the nearest one to where ICT
    measured it, the upper lips' and lids' landmarks on the upper sheet and the lower ones
    on the lower sheet, the left side the mirror image of the right (ICT's head is
    symmetric; MediaPipe's measurement is not quite)."""
    from facesim.physics.mesh import FaceMesh, mirror_map
    x = face.vertices
    mask = FaceMesh(mediapipe, hopper.faces)
    loops = face.boundary_loops[1:]
    centres = np.array([x[loop].mean(axis=0) for loop in loops])
    allowed = np.ones((len(mediapipe), len(x)), dtype=bool)
    for mask_loop in mask.boundary_loops[1:]:
        centre = mediapipe[mask_loop].mean(axis=0)
        opening = loops[int(np.argmin(np.linalg.norm(centres - centre, axis=1)))]
        upper_sheet, lower_sheet = _sheets(face, opening)
        mask_upper, mask_lower = _arcs(mediapipe, mask_loop)
        for points, sheet in ((mask_upper, upper_sheet), (mask_lower, lower_sheet)):
            allowed[points] = False
            allowed[np.ix_(points, sheet)] = True
    distance = np.where(allowed, np.linalg.norm(mediapipe[:, None] - x[None], axis=2), np.inf)
    mirror_landmark = mirror_map(hopper.vertices, hopper.faces)  # the same topology, made symmetric
    mirror_vertex = np.argmin(np.linalg.norm(x[:, None] * [-1, 1, 1] - x[None], axis=2), axis=1)
    right = np.flatnonzero(hopper.vertices[:, 0] <= 1e-9)
    midline = np.abs(x[:, 0]) < 1e-4
    distance[np.ix_(right[hopper.vertices[right, 0] > -1e-9], ~midline)] = np.inf
    # Each landmark its own vertex (two on one would be a zero-length spring), the nearest
    # first: a landmark whose nearest vertex is taken gets its nearest free one.
    nearest = np.full(len(mediapipe), -1)
    taken = np.zeros(len(x), dtype=bool)
    for k in right[np.argsort(distance[right].min(axis=1))]:
        choice = int(np.argmin(np.where(taken, np.inf, distance[k])))
        nearest[k], taken[choice] = choice, True
    left = np.setdiff1d(np.arange(len(mediapipe)), right)
    nearest[left] = mirror_vertex[nearest[mirror_landmark[left]]]
    if len(np.unique(nearest)) != len(nearest):
        raise SystemExit("two landmarks fell on one vertex of the head")
    return nearest, mirror_landmark, mirror_vertex


def symmetric_weights(measured, mirror_landmark: np.ndarray, mirror_vertex: np.ndarray):
    """Each landmark as weights of 8 head vertices: ICT's 4 for it and the mirror images
    of the 4 for its mirror landmark, half each, so the simulation mesh is symmetric on
    a symmetric head and follows any identity."""
    vertex, weight = measured["vertex"], measured["weight"]
    both = np.concatenate([vertex, mirror_vertex[vertex[mirror_landmark]]], axis=1)
    return both.astype(np.int32), (np.concatenate([weight, weight[mirror_landmark]], axis=1) / 2).astype(np.float32)


def write_muscles(ict: Path, out: Path) -> None:
    """The head's muscle file: the Hopper face's, all by landmark (the simulation mesh's
    vertices), the jaw's hinge included: the contour points 234 and 454 lie at the height of
    the head's temporomandibular joints, and the axis through them within 2 mm of the
    joints' (only the axis matters). Written as the head's coordinates, the hinge did not
    carry to the Hopper face (its jaw opened about an axis 6 cm off)."""
    text = (ROOT / "meshes" / "face.muscles.yaml").read_text()
    body = text[text.index("units:"):]
    header = (ROOT / "scripts" / "ict_muscles_header.txt").read_text()
    (out / "head.muscles.yaml").write_text(header + body)
    print(f"wrote {out / 'head.muscles.yaml'}")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("ict", type=Path, help="ICT FaceKit directory (generic_neutral_mesh.obj, shapes.npz, LICENSE)")
    parser.add_argument("-o", "--out", type=Path, default=Path(__file__).resolve().parent.parent / "meshes" / "ict")
    args = parser.parse_args()
    build(args.ict, args.out)


if __name__ == "__main__":
    main()
