"""OpenGL without a display: the platform (Mesa's software EGL, else OSMesa) chosen
before anything imports OpenGL (``use_backend``: ``PYOPENGL_PLATFORM`` is read once, at
OpenGL's import), and facesim's lit shader.
"""

from __future__ import annotations

import ctypes.util
import os
import sys
from pathlib import Path

from ..errors import InputError, RenderError
from .settings import _LIBRARIES, BACKENDS


def backend_available(name: str) -> bool:
    """Whether the backend's shared library is installed (not that it works)."""
    return ctypes.util.find_library(_LIBRARIES[name]) is not None


def use_backend(requested: str = "auto") -> str:
    """Choose the GL platform and set it for PyOpenGL; returns the one chosen.

    Must run before OpenGL is imported; in a process that already imported it, the
    platform it imported with is kept.
    """
    if requested not in ("auto",) + BACKENDS:
        raise InputError(f"--backend: expected auto, osmesa or egl, got {requested!r}")
    if "OpenGL" in sys.modules:
        current = os.environ.get("PYOPENGL_PLATFORM", "")
        if requested not in ("auto", current):
            raise RenderError(f"OpenGL is already loaded with the {current!r} platform in this process")
        return current
    candidates = BACKENDS if requested == "auto" else (requested,)
    for name in candidates:
        if backend_available(name):
            os.environ["PYOPENGL_PLATFORM"] = name
            if name == "egl":
                os.environ.setdefault("EGL_PLATFORM", "surfaceless")
            return name
    raise RenderError(
        f"no working GL backend ({'/'.join(candidates)}): install Debian's libosmesa6 "
        "(sudo apt-get install libosmesa6) or Mesa's EGL (libegl1 libegl-mesa0)"
    )


#: facesim's lit fragment shader (the module's shaders/mesh.frag): pyrender's PBR shader
#: without the light types and shadows facesim does not use, the same pixels (within one
#: level) in about half the time in Mesa's software rasteriser; its loop over the lights
#: runs to DIRECTIONAL_LIGHTS, the scene's fixed count, compiled in as a constant (a
#: uniform count made Mesa run the loop under a mask: 31.6 -> 28.8 ms a frame at 512²).
LIT_SHADER = Path(__file__).with_name("shaders") / "mesh.frag"
