"""OpenGL without a display: the platform (Mesa's software EGL, else OSMesa) chosen
before anything imports OpenGL (``use_backend``: ``PYOPENGL_PLATFORM`` is read once, at
OpenGL's import), pyrender imported without its on-screen viewer, and the few places
facesim draws differently from pyrender's defaults: a single-sample framebuffer, its own
lit shader, colour read back alone, a stable draw order, one EGL display per process, and
a context's objects freed without a full garbage collection.
"""

from __future__ import annotations

import ctypes.util
import functools
import gc
import os
import sys
import types
from contextlib import contextmanager
from pathlib import Path

import numpy as np

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


def offscreen_pyrender():
    """pyrender, imported without its on-screen viewer. pyrender's ``__init__`` imports the
    viewer, and with it pyglet's windows and GL bindings: 150-180 ms of a fresh `facesim
    render` (pyrender imported after trimesh 251-317 ms, without the viewer 96-157;
    2026-12-03), for a window facesim never opens (``use_backend``). A stand-in takes the
    viewer's module while pyrender is imported, and leaves ``sys.modules`` after it: an
    ``import pyrender.viewer`` later in the process gets pyglet and the real viewer."""
    if "pyrender" not in sys.modules and "pyrender.viewer" not in sys.modules:
        stand_in = types.ModuleType("pyrender.viewer", "Not imported by facesim: import pyrender.viewer for the viewer.")

        class Viewer:
            def __init__(self, *args, **kwargs):
                raise RenderError("pyrender was imported offscreen by facesim: use pyrender.viewer.Viewer")

        stand_in.Viewer = Viewer
        sys.modules["pyrender.viewer"] = stand_in
        try:
            import pyrender
        finally:
            del sys.modules["pyrender.viewer"]
    import pyrender

    return pyrender


def _single_sample(renderer) -> None:
    """Make a pyrender Renderer draw without its fixed 4x multisampling. pyrender
    hard-codes the sample count, so the call that allocates the framebuffer is wrapped
    for this renderer only. Mesa's software rasteriser pays for a multisampled
    framebuffer at any sample count (measured on the head at 512², side by side: 108 ms a
    frame with 2 or 4 samples, 35 ms with none, 91 ms for one sample at 1024² averaged
    down), so antialiasing is done by supersampling instead (``SUPERSAMPLE``,
    ``_downsample``)."""
    import pyrender.renderer as module

    configure = renderer._configure_main_framebuffer

    def single_sample_framebuffer():
        allocate = module.glRenderbufferStorageMultisample
        module.glRenderbufferStorageMultisample = lambda target, _samples, fmt, w, h: allocate(target, 0, fmt, w, h)
        try:
            configure()
        finally:
            module.glRenderbufferStorageMultisample = allocate

    renderer._configure_main_framebuffer = single_sample_framebuffer


#: facesim's lit fragment shader (the module's shaders/mesh.frag).
LIT_SHADER = Path(__file__).with_name("shaders") / "mesh.frag"


def _lit_shader(renderer, directional_lights: int) -> None:
    """Make a pyrender Renderer shade lit surfaces with facesim's ``LIT_SHADER``, pyrender's
    PBR shader without the light types and shadows facesim does not use: the same pixels
    (within one level), in about half the time in Mesa's software rasteriser (measured on
    the head at 512² antialiased, side by side: ``scripts/bench.py``). Its loop over the
    lights runs to ``directional_lights``, the scene's fixed count, compiled in as a
    constant: pyrender's count is a uniform, and Mesa runs a loop of unknown length under
    a mask of the pixels still in it (the head at 512², the two shaders side by side in
    one process: 31.6 -> 28.8 and 34.4 -> 27.4 ms a frame, the same pixels). Other
    programs (the unlit photo look, depth) stay pyrender's."""
    from pyrender.shader_program import ShaderProgramCache

    class Programs(ShaderProgramCache):
        def get_program(self, vertex_shader, fragment_shader, geometry_shader=None, defines=None):
            if fragment_shader == "mesh.frag":
                fragment_shader = str(LIT_SHADER)  # an absolute path: os.path.join keeps it
                defines = dict(defines or {}, DIRECTIONAL_LIGHTS=directional_lights)
            program = super().get_program(vertex_shader, fragment_shader, geometry_shader, defines)
            if not hasattr(program, "_facesim_uniforms"):
                _remember_uniforms(program)
            return program

    renderer._program_cache = Programs()


def _remember_uniforms(program) -> None:
    """Make a pyrender ShaderProgram skip setting a uniform to the value it already holds.
    A program keeps its uniforms between draws, and pyrender sets every one of them
    before each part it draws (the camera, the lights, the material: 162 calls a frame
    for a head's nine parts, each a location looked up by name and a call through
    PyOpenGL, about 25 µs). Values are compared as their bytes, so what is set is exactly
    what pyrender would set."""
    set_uniform = program.set_uniform
    held = program._facesim_uniforms = {}

    def set_changed(name, value, unsigned=False):
        if isinstance(value, np.ndarray):
            key = (value.dtype.str, value.shape, value.tobytes(), unsigned)
        else:
            key = (type(value), value, unsigned)
        if held.get(name) != key:
            set_uniform(name, value, unsigned)
            held[name] = key

    program.set_uniform = set_changed


def _colour_only(renderer, multisampled: bool) -> None:
    """Make a pyrender Renderer read back only a frame's colour. pyrender also reads every
    pixel's depth and turns it into a distance (a blit, a read and several passes over the
    frame's floats), which facesim needs only to lay a frame over a photo (``--onto``);
    the depth it then returns is None. EGL reads pyrender's framebuffer
    (``_read_main_framebuffer``), OSMesa the context's own buffer (``read_depth_buf``).
    A framebuffer drawn with one sample a pixel (``_single_sample``) is read where it was
    drawn; only a multisampled one is first resolved by a blit (the head at 512², side by
    side in one process: 29.1 -> 27.4 and 25.8 -> 24.4 ms a frame, the same pixels)."""
    import pyrender
    from OpenGL import GL

    def read_main_framebuffer(scene, flags):
        width, height = renderer._main_fb_dims
        GL.glBindFramebuffer(GL.GL_READ_FRAMEBUFFER, renderer._main_fb_ms)
        if multisampled:
            GL.glBindFramebuffer(GL.GL_DRAW_FRAMEBUFFER, renderer._main_fb)
            GL.glBlitFramebuffer(0, 0, width, height, 0, 0, width, height, GL.GL_COLOR_BUFFER_BIT, GL.GL_LINEAR)
            GL.glBindFramebuffer(GL.GL_READ_FRAMEBUFFER, renderer._main_fb)
        channels, layout = (4, GL.GL_RGBA) if flags & pyrender.RenderFlags.RGBA else (3, GL.GL_RGB)
        data = GL.glReadPixels(0, 0, width, height, layout, GL.GL_UNSIGNED_BYTE)
        return np.frombuffer(data, dtype=np.uint8).reshape(height, width, channels)[::-1], None

    renderer._read_main_framebuffer = read_main_framebuffer
    renderer.read_depth_buf = lambda: None


class _InsertionOrder(dict):
    """A set that iterates in the order its members were added (a dict's keys)."""

    def add(self, item) -> None:
        self[item] = None

    def remove(self, item) -> None:
        del self[item]

    def discard(self, item) -> None:
        self.pop(item, None)


def _stable_draw_order(scene) -> None:
    """Make a pyrender Scene draw its meshes in the same order in every process. pyrender
    keeps them in a set, whose order follows their memory addresses, and sorts them by
    the distance of their nodes from the camera: every part of a head hangs from one
    node, so the sort ties and the draw order changed from run to run. The eyelashes are
    blended, so that order showed: a sample of a dataset differed by a pixel between two
    runs of the same seed. In the order they were added, the sort keeps it (it is stable)."""
    scene._mesh_nodes = _InsertionOrder.fromkeys(scene._mesh_nodes)


#: Open renderers per EGL display. Every EGL renderer of a process gets the same display
#: (one device), and pyrender terminates it when it deletes a renderer, which ended the
#: context of every other renderer still open (measured: the second one's eglMakeCurrent
#: then fails); so the display is terminated only with the last renderer on it.
_egl_displays: dict[int, int] = {}


def _share_egl_display(offscreen) -> None:
    """Make ``offscreen`` (a pyrender.OffscreenRenderer) delete only its own EGL context,
    and terminate the display when no other renderer is open on it."""
    platform = offscreen._platform
    display = getattr(platform, "_egl_display", None)
    if display is None:  # OSMesa: each context stands alone
        return
    key = ctypes.cast(display, ctypes.c_void_p).value
    _egl_displays[key] = _egl_displays.get(key, 0) + 1

    def delete_context():
        from OpenGL import EGL

        if platform._egl_display is None:
            return
        if platform._egl_context is not None:
            EGL.eglMakeCurrent(display, EGL.EGL_NO_SURFACE, EGL.EGL_NO_SURFACE, EGL.EGL_NO_CONTEXT)
            EGL.eglDestroyContext(display, platform._egl_context)
            platform._egl_context = None
        platform._egl_display = None
        _egl_displays[key] -= 1
        if _egl_displays[key] == 0:
            del _egl_displays[key]
            EGL.eglTerminate(display)

    platform.delete_context = delete_context


@contextmanager
def _collection_paused():
    """No garbage collection in the block. A renderer dropped without ``close`` is
    finalised by the collector, whenever it runs, and pyrender's finalizer makes that
    renderer's context current to delete it, then releases it: run between another
    renderer's ``make_current`` and its GL calls, it would leave them on no context. (CI
    once failed so, in glBindBuffer, after a test had dropped eight renderers; the
    finalizer also terminated the EGL display then, ``_share_egl_display``.)"""
    paused = gc.isenabled()
    gc.disable()
    try:
        yield
    finally:
        if paused:
            gc.enable()


def _in_own_context(method):
    """A FaceRenderer method whose GL calls run on its context (``_collection_paused``)."""

    @functools.wraps(method)
    def wrapper(self, *args, **kwargs):
        with _collection_paused():
            self._renderer._platform.make_current()
            return method(self, *args, **kwargs)

    return wrapper
