"""Exact point caches: every vertex of the head as facesim draws it, frame by frame, for a
tool to play without a rig (``facesim render x.yaml -o x.pc2``).

PC2 (3ds Max's point cache, which Blender's Mesh Cache modifier reads): a 32-byte header
(``POINTCACHE2\\0``, version 1, the point count, the start frame, the sample rate, the
sample count; little-endian) and then each frame's points as float32 x, y, z. Beside it,
``x.obj`` is the rest mesh the cache plays on, in the same vertex order: ICT FaceKit's
26,719 vertices and all of its triangles, each material's after its ``usemtl`` (the
hidden shells too: an importer drops a vertex no triangle uses, Blender's among them,
and the cache then no longer fits), positions and faces only (an OBJ with texture
coordinates is re-indexed by some importers, trimesh's among them). Both are in metres, as the GLB (facesim.export.gltf.METRES), y up, the face
toward +z; the head's pose, the jaw, the eyes' turn and the tongue are in the points, as
in facesim's NPZ and its frames. A frame is computed and written at a time: a clip of
any length takes the memory of one frame.
"""

from __future__ import annotations

import struct
from pathlib import Path

from ..files import WriteError, atomic_path, check_destination
from .gltf import METRES

SIGNATURE = b"POINTCACHE2\0"
_HEADER = struct.Struct("<12siiffi")


def rest_mesh_path(path: str | Path) -> Path:
    """The OBJ written beside a PC2: its name with ``.obj``."""
    return Path(path).with_suffix(".obj")


def check_point_cache(path: str | Path, force: bool) -> None:
    """Both files of a point cache may be written (facesim.files.check_destination)."""
    check_destination(Path(path), force)
    check_destination(rest_mesh_path(path), force)


def _verify_pc2(points: int, frames: int):
    def verify(tmp: Path) -> None:
        with open(tmp, "rb") as stream:
            header = stream.read(_HEADER.size)
        try:
            signature, version, count, _, _, samples = _HEADER.unpack(header)
        except struct.error:
            raise WriteError("the written PC2 has no header") from None
        expected = _HEADER.size + points * frames * 12
        if signature != SIGNATURE or (count, samples) != (points, frames) or tmp.stat().st_size != expected:
            raise WriteError(f"the written PC2 is incomplete ({tmp.stat().st_size} of {expected} bytes)")

    return verify


def _verify_obj(points: int, triangles: int):
    def verify(tmp: Path) -> None:
        kinds = [line[:2] for line in tmp.read_text().splitlines()]
        if kinds.count("v ") != points or kinds.count("f ") != triangles:
            raise WriteError("the written OBJ is incomplete")

    return verify


def write_point_cache(animation, path: str | Path, replace: bool = False) -> int:
    """The animation of a head as ``path`` (PC2) and its rest mesh beside it (OBJ); the
    bytes written."""
    figure = animation.ready().figure
    if figure is None:
        raise ValueError("a point cache holds a head's vertices: simulate a head, not a face mask")
    path = Path(path)
    head = animation.model.mesh.head
    rest = figure.rest * METRES
    lines = [f"# facesim {animation.name}: the rest mesh of {path.name} (metres, ICT FaceKit's vertex order)\n"]
    lines += [f"v {x:.7g} {y:.7g} {z:.7g}\n" for x, y, z in rest]
    for k, material in enumerate(head.materials):  # every triangle of ICT's, so that no vertex is loose
        lines.append(f"usemtl {material}\n")
        lines += [f"f {a + 1} {b + 1} {c + 1}\n" for a, b, c in head.triangles[head.triangle_material == k]]
    triangles = head.triangles
    # the cache renamed into place first, then its mesh: a failure in either leaves neither
    with atomic_path(rest_mesh_path(path), replace=replace, verify=_verify_obj(len(rest), len(triangles))) as mesh:
        mesh.write_text("".join(lines))
        with atomic_path(path, replace=replace, verify=_verify_pc2(len(rest), animation.frames)) as tmp:
            with open(tmp, "wb") as stream:
                stream.write(_HEADER.pack(SIGNATURE, 1, len(rest), 0.0, 1.0, animation.frames))
                for k in range(animation.frames):
                    stream.write((animation.head_at(k) * METRES).astype("<f4").tobytes())
    return path.stat().st_size + rest_mesh_path(path).stat().st_size
