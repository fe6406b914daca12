"""An exact point cache as USD (``facesim render x.yaml -o x.usdc``, with the ``usd`` extra:
Pixar's ``usd-core``): the head as one UsdGeomMesh, every one of ICT FaceKit's 26,719
vertices as facesim draws it at each frame as a time sample of its points (the head's
pose, the jaw, the eyes' turn and the tongue in them, as in the NPZ and the PC2), ICT's
texture coordinates as the face-varying primvar ``st``, and each of ICT's material parts
(M_Face, M_Teeth, M_EyeBall, ...) as a GeomSubset of the family ``part``.

Centimetres (``metersPerUnit`` 0.01), y up, the face toward +z; time codes are frames at
the clip's fps (``timeCodesPerSecond``). USD's crate format keeps the time samples in
memory until the layer is saved: a head's frame is 320 KB.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from ..errors import InputError
from ..files import WriteError, atomic_path

#: The family a mesh's parts are GeomSubsets of.
PARTS = "part"


def check_usd() -> None:
    """InputError, before any work, when USD's Python package is missing."""
    try:
        import pxr  # noqa: F401
    except ImportError:
        raise InputError("-o x.usdc needs Pixar's USD: pip install 'facesim[usd]' (usd-core)") from None


def _verify(points: int, frames: int):
    def verify(tmp: Path) -> None:
        from pxr import Usd, UsdGeom

        stage = Usd.Stage.Open(str(tmp))
        mesh = UsdGeom.Mesh(stage.GetPrimAtPath("/Head/Head")) if stage else None
        samples = mesh.GetPointsAttr().GetTimeSamples() if mesh else []
        if not samples or len(samples) != frames or len(mesh.GetPointsAttr().Get(samples[-1])) != points:
            raise WriteError(f"the written USD holds {len(samples)} of {frames} frames")

    return verify


def write_usd(animation, path: str | Path, replace: bool = False) -> int:
    """The animation of a head as a USD crate file; the bytes written."""
    from pxr import Sdf, Usd, UsdGeom, Vt

    figure = animation.ready().figure
    if figure is None:
        raise ValueError("a point cache holds a head's vertices: simulate a head, not a face mask")
    head = animation.model.mesh.head
    with atomic_path(path, replace=replace, verify=_verify(len(figure.rest), animation.frames)) as tmp:
        stage = Usd.Stage.CreateNew(str(tmp))
        UsdGeom.SetStageUpAxis(stage, UsdGeom.Tokens.y)
        UsdGeom.SetStageMetersPerUnit(stage, 0.01)
        stage.SetStartTimeCode(0)
        stage.SetEndTimeCode(max(animation.frames - 1, 0))
        stage.SetTimeCodesPerSecond(animation.fps)
        stage.SetFramesPerSecond(animation.fps)
        root = UsdGeom.Xform.Define(stage, "/Head")
        stage.SetDefaultPrim(root.GetPrim())
        root.GetPrim().SetDocumentation(f"facesim {animation.name}: ICT FaceKit's head, every vertex as drawn, per frame")
        mesh = UsdGeom.Mesh.Define(stage, "/Head/Head")
        mesh.CreateSubdivisionSchemeAttr(UsdGeom.Tokens.none)
        mesh.CreateFaceVertexCountsAttr(Vt.IntArray.FromNumpy(np.full(len(head.triangles), 3, dtype=np.int32)))
        mesh.CreateFaceVertexIndicesAttr(Vt.IntArray.FromNumpy(head.triangles.ravel().astype(np.int32)))
        st = UsdGeom.PrimvarsAPI(mesh).CreatePrimvar("st", Sdf.ValueTypeNames.TexCoord2fArray, UsdGeom.Tokens.faceVarying)
        st.Set(Vt.Vec2fArray.FromNumpy(head.uv[head.triangle_uv].reshape(-1, 2).astype(np.float32)))
        for k, material in enumerate(head.materials):
            faces = np.flatnonzero(head.triangle_material == k).astype(np.int32)
            if len(faces):
                UsdGeom.Subset.CreateGeomSubset(mesh, material, UsdGeom.Tokens.face, Vt.IntArray.FromNumpy(faces), PARTS)
        points, extent = mesh.CreatePointsAttr(), mesh.CreateExtentAttr()
        for k in range(animation.frames):
            x = animation.head_at(k).astype(np.float32)
            points.Set(Vt.Vec3fArray.FromNumpy(x), Usd.TimeCode(k))
            extent.Set(Vt.Vec3fArray.FromNumpy(np.stack([x.min(axis=0), x.max(axis=0)])), Usd.TimeCode(k))
        stage.GetRootLayer().Save()
        del stage
    return Path(path).stat().st_size
