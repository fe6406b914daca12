"""The face for other tools: the rig (``facesim rig -o head.glb``), an animation as that
rig plus its clip (``facesim render x.yaml -o x.glb``) and as ARKit weight curves in Live
Link Face's CSV layout (``-o x.csv``), which Unreal's Live Link and Blender's add-ons read.

Both fit facesim's simulated frames onto the rig's physics-baked shapes
(facesim.animation.blendshapes): what an engine plays back is the weights, so the
``wrote`` line says how far that playback lies from facesim's own frames. Every file is
checked before any work (its kind, its destination), written under a temporary name,
read back (the GLB parsed, its targets, accessors and clip counted; the CSV's rows and
columns counted) and only then renamed into place.
"""

from __future__ import annotations

import dataclasses
import io
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..animation.arkit import ARKIT_52
from ..animation.blendshapes import Fit, Shapes, bake, fit_weights, unturned, with_correctives
from ..files import WriteError, atomic_path
from .gltf import Clip, rig_glb

#: Live Link Face's CSV: after the timecode and the count, the 52 shapes (Apple's names
#: capitalised), then the head's and each eye's yaw, pitch and roll, in radians.
LIVE_LINK_ROTATIONS = ("HeadYaw", "HeadPitch", "HeadRoll", "LeftEyeYaw", "LeftEyePitch", "LeftEyeRoll",
                       "RightEyeYaw", "RightEyePitch", "RightEyeRoll")
LIVE_LINK_COLUMNS = ("Timecode", "BlendShapeCount", *(n[0].upper() + n[1:] for n in ARKIT_52), *LIVE_LINK_ROTATIONS)


@dataclass(frozen=True)
class Exported:
    """What an export wrote: its frames, size in bytes, and the playback's fit (None for a rig alone)."""

    frames: int
    size: int
    fit: Fit | None
    correctives: int = 0
    rest_beside: bool = True  # a point cache's rest mesh in a file of its own (PC2's OBJ; USD holds its own)

    def summary(self) -> str:
        size = f"{self.size / 2**20:.1f} MB" if self.size >= 2**20 else f"{self.size / 1024:.0f} KB"
        if self.fit is None and self.frames:
            beside = ", and its rest mesh beside it" if self.rest_beside else ", its parts and texture coordinates"
            return f"{self.frames} frames of every vertex of the head{beside}, {size}"
        if self.fit is None:
            return f"{len(ARKIT_52)} ARKit shapes baked by the physics, {size}"
        extra = f" and {self.correctives} correctives" if self.correctives else ""
        return (f"{self.frames} frames, {size}; ARKit's 52 weights{extra} play facesim's frames back within "
                f"{self.fit.rms.max() * 10:.2f} mm RMS, {self.fit.largest.max() * 10:.2f} mm at most, over the face")


def clip_of(animation, shapes: Shapes) -> tuple[Clip, Fit]:
    """The animation's clip for the rig: its frames fitted onto ``shapes``, its head pose
    and each eye's gaze (the pose's gaze plus the eye's own look)."""
    animation.ready()
    fit = fit_weights(shapes, (unturned(animation, k) for k in range(animation.frames)))
    pose = np.zeros((animation.frames, 5)) if animation.pose is None else np.asarray(animation.pose, dtype=np.float64)
    eyes = np.repeat(pose[:, None, 3:5], 2, axis=1)
    if pose.shape[1] > 5:
        eyes += pose[:, 5:9].reshape(-1, 2, 2)
    return Clip(animation.name, fit.weights, pose[:, 0:3], eyes, animation.fps), fit


def _verify_glb(targets: int, frames: int | None):
    def verify(tmp: Path) -> None:
        from pygltflib import GLTF2

        try:
            gltf = GLTF2().load_binary(str(tmp))
            blob = gltf.binary_blob()
            names = gltf.meshes[0].extras["targetNames"]
            complete = (len(names) == targets and all(len(p.targets) == targets for p in gltf.meshes[0].primitives)
                        and len(blob) >= gltf.buffers[0].byteLength
                        and all(v.byteOffset + v.byteLength <= len(blob) for v in gltf.bufferViews))
            if frames is not None:
                complete = complete and len(gltf.animations) == 1 and all(
                    gltf.accessors[s.input].count == frames for s in gltf.animations[0].samplers)
        except Exception as exc:  # a truncated file fails in many ways
            raise WriteError(f"the written GLB does not read back ({type(exc).__name__})") from None
        if not complete:
            raise WriteError("the written GLB is incomplete")

    return verify


def _write_bytes(data: bytes, path: Path, replace: bool, verify) -> None:
    with atomic_path(path, replace=replace, verify=verify) as tmp:
        tmp.write_bytes(data)


def write_rig(spec, path: str | Path, replace: bool = False) -> Exported:
    """``facesim rig``: the head of ``spec`` (its identity or face directory) as a GLB rig."""
    from ..animation.simulate import model_for
    from ..face.figure import figure_for

    shapes = bake(spec)
    face = spec.face_directory
    data = rig_glb(shapes, figure_for(model_for(spec)), name=f"facesim {spec.title}", texture=face and face.texture)
    _write_bytes(data, Path(path), replace, _verify_glb(len(shapes.names), None))
    return Exported(0, len(data), None)


def timecode(frame: int, fps: float) -> str:
    """Live Link Face's timecode of ``frame`` at ``fps``: HH:MM:SS:FF.fff, the frame within
    its second and, at a rate that is not whole, its fraction."""
    whole = int(frame / fps + 1e-9)
    within = frame - whole * fps
    ff = int(within + 1e-9)
    return f"{whole // 3600:02d}:{whole // 60 % 60:02d}:{whole % 60:02d}:{ff:02d}.{min(round((within - ff) * 1000), 999):03d}"


def live_link_csv(clip: Clip) -> str:
    """The clip's weights and rotations as Live Link Face writes a take (``LIVE_LINK_COLUMNS``)."""
    out = io.StringIO()
    out.write(",".join(LIVE_LINK_COLUMNS) + "\n")
    yaw_pitch_roll = np.radians(clip.head)
    eyes = np.radians(np.concatenate([clip.eyes, np.zeros((len(clip.eyes), 2, 1))], axis=2)).reshape(-1, 6)
    for k, (weights, head, eye) in enumerate(zip(clip.weights, yaw_pitch_roll, eyes)):
        values = ",".join(f"{v:.6f}" for v in (*np.clip(weights, 0.0, 1.0), *head, *eye))
        out.write(f"{timecode(k, clip.fps)},{len(LIVE_LINK_COLUMNS) - 2},{values}\n")
    return out.getvalue()


def _verify_csv(frames: int):
    def verify(tmp: Path) -> None:
        lines = tmp.read_text().splitlines()
        rows = [line.split(",") for line in lines]
        if not rows or tuple(rows[0]) != LIVE_LINK_COLUMNS or len(rows) != frames + 1 or \
                any(len(r) != len(LIVE_LINK_COLUMNS) for r in rows):
            raise WriteError(f"the written CSV holds {max(len(rows) - 1, 0)} of {frames} frames or lost columns")

    return verify


def write_clip(animation, spec, path: str | Path, kind: str, replace: bool = False) -> Exported:
    """An animation as ``kind``: ``glb`` (the rig and its clip), ``csv`` (Live Link Face's
    curves), ``pc2`` (the point cache and its rest mesh: facesim.export.pointcache) or
    ``usdc`` (the point cache as USD: facesim.export.usd)."""
    if kind == "pc2":
        from .pointcache import write_point_cache

        return Exported(animation.frames, write_point_cache(animation, path, replace), None)
    if kind == "usdc":
        from .usd import write_usd

        return Exported(animation.frames, write_usd(animation, path, replace), None, rest_beside=False)
    shapes = bake(spec)
    clip, fit = clip_of(animation, shapes)
    if kind == "glb":  # the clip's own correctives on top (blendshapes.with_correctives): played as facesim drew it
        shapes, fit = with_correctives(shapes, lambda k: unturned(animation, k), animation.frames, fit)
        clip = dataclasses.replace(clip, weights=fit.weights)
        data = rig_glb(shapes, animation.figure, clip, name=f"facesim {spec.title}",
                       texture=animation.face and animation.face.texture)
        _write_bytes(data, Path(path), replace, _verify_glb(len(shapes.names), animation.frames))
    else:
        data = live_link_csv(clip).encode()
        _write_bytes(data, Path(path), replace, _verify_csv(animation.frames))
    return Exported(animation.frames, len(data), fit, len(shapes.names) - len(ARKIT_52))
