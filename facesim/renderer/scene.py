"""Offscreen rendering of face animations with pyrender (the maintained ``pyrender2``),
on a machine with no display and no GPU: OSMesa or Mesa's software EGL.

One :class:`FaceRenderer` per process is built once and reused for every frame: the
scene (skin, eyeballs with iris and pupil behind the eye openings, a dark mouth cavity
behind the lips, a key and a fill light, a plain background) never changes; per frame
only the face's vertex buffer is rewritten in place (positions and Numba-computed
normals), never the scene, and the head and eye nodes get their pose: the head turns as a
rigid body about a pivot at the neck (yaw, pitch, roll), the eyeballs about their centres
(gaze yaw, pitch), under a fixed camera and fixed lights.

``PYOPENGL_PLATFORM`` must be set before anything imports OpenGL, so nothing here imports
pyrender until :func:`use_backend` has chosen the platform.
"""

from __future__ import annotations

import ctypes.util
import functools
import gc
import os
import sys
import types
from concurrent.futures import ThreadPoolExecutor
from contextlib import contextmanager
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np
from numba import njit, prange

from ..config import NUMBA_OPTIONS, PARALLEL_OPTIONS
from ..errors import InputError, RenderError
from ..face.colours import IRIS, MOUTH, PUPIL, SCLERA, SKIN
from ..geometry import _vertex_normals, rotation
from ..physics.mesh import FaceMesh
from ..physics.rig import eyeball

#: Tried in this order by ``--backend auto``. Mesa's software EGL (surfaceless) first: it
#: renders the same frames about twice as fast as OSMesa here (BENCHMARKS.md), and newer
#: Mesa releases drop OSMesa; OSMesa remains the fallback.
BACKENDS = ("egl", "osmesa")
_LIBRARIES = {"osmesa": "OSMesa", "egl": "EGL"}
CAMERAS = {"front": 0.0, "three-quarter": 35.0, "profile": 90.0}
#: What a head's frame holds: its face (the simulated skin, brow to chin: expressions are
#: read there), or the whole head and shoulders.
FRAMINGS = ("face", "head")
#: How a head looks: facesim's materials under a key and a fill light (clay), or a face
#: directory's baked photo (photo), drawn unlit: the photo's own light is in its colours.
LOOKS = ("auto", "clay", "photo")  # auto: photo for a head with a face directory, clay otherwise
#: In the photo look the parts a photo does not texture (teeth, gums and tongue) keep their
#: colours, shaded once at rest by the key light's direction (this much ambient, the rest
#: by the cosine to the light) and darkening with depth behind the front teeth, to the
#: second value at the third (cm): an open mouth is dark inside.
PHOTO_AMBIENT, MOUTH_DARKEST, MOUTH_DEEP = 0.45, 0.2, 3.5

BACKGROUND = (0.93, 0.93, 0.95, 1.0)
ARROW = (0.85, 0.05, 0.05, 1.0)
WIRE = (0.12, 0.14, 0.22, 1.0)
#: A head's wireframe is drawn this far (cm) in front of the skin, toward the camera.
WIRE_LIFT = 0.15
KEY_LIGHT, FILL_LIGHT = 3.2, 1.3
#: Where the key light comes from (up and to the subject's right, in front), and the fill.
KEY_DIRECTION, FILL_DIRECTION = np.array([-0.6, 0.7, 1.0]), np.array([0.9, -0.1, 0.6])
#: Antialiasing, by default, filters the frame as drawn along its edges (``_smooth_edges``):
#: a pixel whose 3x3 neighbourhood's luma spans at least ``EDGE_CONTRAST`` of its
#: brightest (and ``EDGE_FLOOR`` levels) is blended toward its neighbour across the edge.
#: ``supersample`` renders each frame this many times wider and taller and averages the
#: blocks instead (``_downsample``): 4 samples per pixel, twice the frame's cost, faster
#: than pyrender's multisampling in software (``_single_sample``). Frames larger than
#: ``SUPERSAMPLE_LIMIT`` are filtered; frames with lines (their one-pixel lines would fade
#: or smear) use pyrender's multisampling.
SUPERSAMPLE, SUPERSAMPLE_LIMIT = 2, 4096
EDGE_CONTRAST, EDGE_FLOOR = 0.125, 255.0 / 24.0
#: Height of the head's pivot (the atlanto-occipital joint) above the chin, in face heights.
NECK_HEIGHT = 0.25


@dataclass(frozen=True)
class RenderSettings:
    width: int = 512
    height: int = 512
    camera: str = "front"
    wireframe: bool = False
    show_muscles: bool = False
    antialias: bool = True
    framing: str = "face"
    look: str = "auto"
    onto: Path | None = None  # a photo to render into, through its face directory's fitted camera
    supersample: bool = False  # antialias by 4 samples per pixel, not by the edge filter

    def __post_init__(self):
        if not (16 <= self.width <= 8192 and 16 <= self.height <= 8192):
            raise InputError(f"--size: expected WxH between 16 and 8192, got {self.width}x{self.height}")
        if self.camera not in CAMERAS:
            raise InputError(f"--camera: expected one of {', '.join(CAMERAS)}, got {self.camera!r}")
        if self.framing not in FRAMINGS:
            raise InputError(f"--framing: expected one of {', '.join(FRAMINGS)}, got {self.framing!r}")
        if self.look not in LOOKS:
            raise InputError(f"--look: expected one of {', '.join(LOOKS)}, got {self.look!r}")

    def for_face(self, face) -> "RenderSettings":
        """These settings for a head with the face directory ``face`` (or None): the auto
        look made photo or clay; InputError when the photo look or --onto has no face."""
        if face is None and (self.look == "photo" or self.onto is not None):
            what = "--onto" if self.onto is not None else "--look photo"
            raise InputError(f"{what}: needs a face directory (--face DIR, or face: in the spec; "
                             "make one with `facesim face from-photo`)")
        return replace(self, look="clay" if face is None else "photo") if self.look == "auto" else self


def parse_size(text: str) -> tuple[int, int]:
    try:
        w, h = (int(v) for v in text.lower().split("x"))
    except ValueError:
        raise InputError(f"--size: expected WxH such as 512x512, got {text!r}") from None
    return w, h


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


@njit(**NUMBA_OPTIONS)
def _interleave(x, normals, rows, attribute, out):
    """pyrender's interleaved vertex of the vertices ``rows`` of a part, in float32 into
    ``out``: position, normal, then its uv or colour (``attribute``, one row a vertex)."""
    for k in range(rows.shape[0]):
        i = rows[k]
        for d in range(3):
            out[k, d] = x[i, d]
            out[k, 3 + d] = normals[i, d]
        for d in range(attribute.shape[1]):
            out[k, 6 + d] = attribute[k, d]


@njit(**NUMBA_OPTIONS)
def _downsample(image, factor, out):
    """The mean of each ``factor`` x ``factor`` block of ``image`` (H, W, C) uint8 into
    ``out`` (H / factor, W / factor, C): a box filter, 4 samples per pixel at factor 2."""
    count = factor * factor
    for y in range(out.shape[0]):
        for x in range(out.shape[1]):
            for c in range(out.shape[2]):
                total = count // 2
                for dy in range(factor):
                    for dx in range(factor):
                        total += image[factor * y + dy, factor * x + dx, c]
                out[y, x, c] = total // count


@njit(**NUMBA_OPTIONS)
def _luma(image, y, x):
    """Rec. 601 luma of pixel (y, x) of an RGB(A) uint8 image."""
    return 0.299 * image[y, x, 0] + 0.587 * image[y, x, 1] + 0.114 * image[y, x, 2]


@njit(**NUMBA_OPTIONS)
def _near(plane, y, x):
    """plane[y, x], its coordinates clamped to the plane."""
    return plane[min(max(y, 0), plane.shape[0] - 1), min(max(x, 0), plane.shape[1] - 1)]


@njit(**dict(PARALLEL_OPTIONS, fastmath=False))
def _smooth_edges(image, out):
    """Antialiasing after drawing: the sub-pixel pass of FXAA (T. Lottes, "FXAA", NVIDIA
    white paper, 2009) on ``image`` (H, W, C) uint8 into ``out``. Where a pixel's 3x3
    luma spans enough (``EDGE_CONTRAST``, ``EDGE_FLOOR``), the edge runs across the
    steeper of its two second differences; the pixel is blended toward its neighbour
    on the side of the larger step, by s² for s = smoothstep(|mean of the 3x3 - M| / span):
    a pixel lying as a step between its neighbours moves most, one on a smooth ramp not
    at all. Every channel, alpha too (``--onto``), by the same weight. Measured on the
    head's smile at 512², against 4 samples per pixel: 41.5 dB unfiltered, 44.3 dB
    filtered; its cost is a few milliseconds against the 30 ms more that supersampling
    draws. Compiled without ``fastmath``: with it, a dataset sample's bytes differed
    between a process that compiled the kernel and one that loaded it from Numba's cache
    (measured on a cold cache; the lumas tie often, at whole levels, and a reordered sum
    breaks a tie either way); without it they agree. Each pixel's luma is taken once, into
    a plane of its own, where the filter reads nine (the head at 512², side by side in one
    process: 1.51 -> 0.95 ms a frame, the same bytes over 56 frames of four expressions)."""
    height, width = image.shape[0], image.shape[1]
    luma = np.empty((height, width))
    for row in prange(height):
        for x in range(width):
            luma[row, x] = _luma(image, row, x)
    for row in prange(height):
        y = np.int64(row)  # a parallel loop's index may be unsigned, and y - 1 must not wrap
        for x in range(width):
            m = luma[y, x]
            n, s, w, e = _near(luma, y - 1, x), _near(luma, y + 1, x), _near(luma, y, x - 1), _near(luma, y, x + 1)
            brightest = max(m, n, s, w, e)
            span = brightest - min(m, n, s, w, e)
            for c in range(image.shape[2]):
                out[y, x, c] = image[y, x, c]
            if span < max(EDGE_FLOOR, EDGE_CONTRAST * brightest):
                continue
            nw, ne = _near(luma, y - 1, x - 1), _near(luma, y - 1, x + 1)
            sw, se = _near(luma, y + 1, x - 1), _near(luma, y + 1, x + 1)
            across_rows = 2.0 * abs(n + s - 2.0 * m) + abs(ne + se - 2.0 * e) + abs(nw + sw - 2.0 * w)
            across_columns = 2.0 * abs(e + w - 2.0 * m) + abs(ne + nw - 2.0 * n) + abs(se + sw - 2.0 * s)
            if across_rows >= across_columns:  # a horizontal edge: blend with the pixel above or below
                dy, dx = (-1 if abs(n - m) >= abs(s - m) else 1), 0
            else:
                dy, dx = 0, (-1 if abs(w - m) >= abs(e - m) else 1)
            ny, nx = min(max(y + dy, 0), height - 1), min(max(x + dx, 0), width - 1)
            mean = (2.0 * (n + s + w + e) + nw + ne + sw + se) / 12.0
            t = min(abs(mean - m) / span, 1.0)
            t = (3.0 - 2.0 * t) * t * t
            blend = t * t
            for c in range(image.shape[2]):
                out[y, x, c] = np.uint8(min(255.0, (1.0 - blend) * image[y, x, c] + blend * image[ny, nx, c] + 0.5))


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


def _openings(rest: np.ndarray, faces: np.ndarray) -> tuple[list[np.ndarray], np.ndarray | None]:
    """The eye openings (right, left) and the mouth opening among the mesh's inner
    boundary loops: the mouth is the lowest loop on the midline, the eyes the highest
    pair on either side. Missing ones are left out."""
    loops = FaceMesh(rest, faces).boundary_loops[1:]
    centres = [rest[loop].mean(axis=0) for loop in loops]
    width = np.ptp(rest[:, 0])
    mouth = min((i for i, c in enumerate(centres) if abs(c[0]) < 0.05 * width), key=lambda i: centres[i][1], default=None)
    sides = [min((i for i, c in enumerate(centres) if s * c[0] > 0.1 * width and i != mouth),
                 key=lambda i: -centres[i][1], default=None) for s in (-1, 1)]
    eyes = [loops[i] for i in sides if i is not None]
    return eyes, (loops[mouth] if mouth is not None else None)


def _texture_vertices(triangles: np.ndarray, uv: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """A textured part's vertices, one per (figure vertex, texture coordinate) pair: a
    vertex where the atlas's islands meet has several. Returns (m,) their figure rows,
    (m, 2) their UVs and the triangles (t, 3) over them."""
    corners = np.column_stack([triangles.reshape(-1).astype(np.float64), uv.reshape(-1, 2)])
    unique, local = np.unique(corners, axis=0, return_inverse=True)
    return unique[:, 0].astype(np.int64), unique[:, 1:], local.reshape(-1, 3)


def _fitted_camera(camera, factor: int, pyrender) -> tuple:
    """The pyrender camera and its pose in the head's frame for a fitted camera
    (facesim.fit.Camera), in a viewport ``factor`` times the photo's size: a pinhole
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


class FaceRenderer:
    """A pyrender scene of one face, rendered offscreen frame after frame."""

    def __init__(self, rest: np.ndarray, faces: np.ndarray, settings: RenderSettings = RenderSettings(), backend: str = "auto",
                 figure=None, face=None):
        """A face mesh ``rest``/``faces`` (a mask, drawn with eyeballs and a mouth cavity
        behind its openings) or, with ``figure`` (facesim.figure), a whole head driven
        by its simulation mesh ``rest``; ``face`` (facesim.own_face.FaceDirectory), the
        face directory of that head, for the photo look and --onto."""
        settings = settings.for_face(None if figure is None else face)
        self.backend = use_backend(backend)
        pyrender = offscreen_pyrender()
        import trimesh

        self.settings = settings
        self._pyrender = pyrender
        self._figure = figure
        self._head = pyrender.Node(name="head", matrix=np.eye(4))
        scene = pyrender.Scene(bg_color=BACKGROUND, ambient_light=(0.28, 0.26, 0.26))
        scene.add_node(self._head)
        _stable_draw_order(scene)
        self._eyes: list[tuple] = []
        if figure is None:
            self._faces = np.ascontiguousarray(faces, dtype=np.int64)
            self._normals = np.empty_like(rest)
            _vertex_normals(rest, self._faces, self._normals)
            skin = pyrender.MetallicRoughnessMaterial(baseColorFactor=SKIN, metallicFactor=0.0, roughnessFactor=0.75, doubleSided=True)
            self._face = pyrender.Primitive(positions=rest, normals=self._normals, indices=self._faces, material=skin)
            scene.add(pyrender.Mesh([self._face]), parent_node=self._head)
            self._add_eyes_and_mouth(scene, rest, faces, pyrender, trimesh)
            low, high = rest.min(axis=0), rest.max(axis=0)
            # The head turns about the top of the spine: behind the jaw, on the mask's back plane.
            self._neck = np.array([(low[0] + high[0]) / 2, low[1] + NECK_HEIGHT * (high[1] - low[1]), low[2]])
            framed = rest
        else:
            self._add_figure(scene, figure, pyrender, face if settings.look == "photo" else None)
            self._neck = figure.neck
            framed = rest if settings.framing == "face" else figure.rest
        self._arrows = self._lines(scene, np.repeat(rest, 2, axis=0), ARROW) if settings.show_muscles else None
        # two sets of the arrays a frame writes before its upload, for ``frames``' two frames in flight
        arrays = getattr(self, "_vertex_arrays", [])
        self._slots = [(self._normals, arrays), (np.empty_like(self._normals), [np.empty_like(a) for a in arrays])]
        # A head's wireframe is its simulation mesh, drawn over the skin it drives.
        self._edges = FaceMesh(rest, faces).edges if figure is not None and settings.wireframe else None
        self._wire = None if self._edges is None else self._lines(scene, rest[self._edges.ravel()], WIRE)

        # lines (wireframe, arrows) are one pixel wide: supersampled they would fade to half
        lines = settings.wireframe or settings.show_muscles
        supersample = (settings.antialias and settings.supersample and not lines
                       and max(settings.width, settings.height) <= SUPERSAMPLE_LIMIT)
        self._factor = SUPERSAMPLE if supersample else 1
        self._smooth = settings.antialias and not lines and not supersample
        centre = (framed.min(axis=0) + framed.max(axis=0)) / 2
        extent = np.ptp(framed, axis=0)
        fov = np.radians(25.0)
        distance = 0.62 * max(extent[1], extent[0] * settings.height / settings.width) / np.tan(fov / 2) + extent[2] / 2
        yaw = np.radians(CAMERAS[settings.camera])
        eye = centre + distance * np.array([-np.sin(yaw), 0.0, np.cos(yaw)])
        self._centre, self._distance, self._yaw = centre, distance, yaw
        self._toward_camera = WIRE_LIFT * (eye - centre) / np.linalg.norm(eye - centre)
        self._backdrop = None
        if settings.onto is None:
            camera = pyrender.PerspectiveCamera(yfov=fov, aspectRatio=settings.width / settings.height, znear=1.0, zfar=10 * distance)
            self._camera = scene.add(camera, pose=_look_at(eye, centre))
        else:
            from ..face.own_face import onto_photo

            self._backdrop, fitted = onto_photo(face, settings.onto, (settings.width, settings.height))
            view, pose = _fitted_camera(fitted, self._factor, pyrender)
            self._camera = scene.add(view, pose=pose)
        self._lights = [
            scene.add(pyrender.DirectionalLight(color=(1.0, 0.97, 0.92), intensity=KEY_LIGHT),
                      pose=_look_at(centre + KEY_DIRECTION, centre)),
            scene.add(pyrender.DirectionalLight(color=(0.85, 0.9, 1.0), intensity=FILL_LIGHT),
                      pose=_look_at(centre + FILL_DIRECTION, centre)),
        ]
        self._scene = scene
        with _collection_paused():  # the context is current from its creation to the first frame
            try:
                self._renderer = pyrender.OffscreenRenderer(self._factor * settings.width, self._factor * settings.height)
            except Exception as exc:
                raise RenderError(
                    f"cannot open an offscreen GL context with {self.backend} ({type(exc).__name__}: {exc}); "
                    "install Debian's libosmesa6 or try --backend egl"
                ) from None
            _share_egl_display(self._renderer)
            multisampled = settings.antialias and not supersample and not self._smooth  # lines, antialiased
            if not multisampled:
                _single_sample(self._renderer._renderer)
            _lit_shader(self._renderer._renderer, len(self._lights))
            if settings.onto is None:
                _colour_only(self._renderer._renderer, multisampled)
            wireframe = settings.wireframe and figure is None
            self._flags = pyrender.RenderFlags.ALL_WIREFRAME if wireframe else pyrender.RenderFlags.NONE
            if settings.look == "photo":
                self._flags |= pyrender.RenderFlags.FLAT
            if settings.onto is not None:
                self._flags |= pyrender.RenderFlags.RGBA
            self._renderer.render(self._scene, flags=self._flags)  # uploads the buffers once

    def _lines(self, scene, points: np.ndarray, colour) -> "pyrender.Primitive":
        """Line segments (point pairs) in one unlit colour, moved with the head."""
        pyrender = self._pyrender
        lines = pyrender.Primitive(positions=points, mode=pyrender.constants.GLTF.LINES,
                                   material=pyrender.MetallicRoughnessMaterial(baseColorFactor=colour, emissiveFactor=colour[:3]))
        scene.add(pyrender.Mesh([lines]), parent_node=self._head)
        return lines

    def _add_figure(self, scene, figure, pyrender, face=None) -> None:
        """One primitive per part of the figure, each over its own vertices, coloured per
        vertex; smooth normals over the whole figure, so seams between parts that share
        vertices (face, scalp, neck) do not show. With ``face`` (the photo look) the parts
        the atlas holds are textured by its baked photo, their vertices split where the
        atlas's islands meet (``_texture_vertices``); the eyelashes are left out (the
        photo's own are in the texture), and the other parts' colours are shaded once at
        rest (``PHOTO_AMBIENT``), the whole drawn unlit."""
        self._faces = np.ascontiguousarray(figure.triangles, dtype=np.int64)
        self._normals = np.empty_like(figure.rest)
        _vertex_normals(figure.rest, self._faces, self._normals)
        texture = None
        if face is not None:  # with --onto, the atlas's alpha says how much of each texel is drawn over the photo
            import imageio.v3 as iio

            image = iio.imread(face.texture)[:, :, :3]
            if self.settings.onto is not None:
                image = np.dstack([image, iio.imread(face.onto_alpha)])
            # No mipmaps: the atlas is the photo magnified several times (the face's 1024 texels
            # against its hundreds of pixels), so it has nothing to alias, and mipmaps average
            # across the islands' seams (they showed as dotted lines along them)
            linear = pyrender.Sampler(magFilter=pyrender.constants.GLTF.LINEAR, minFilter=pyrender.constants.GLTF.LINEAR)
            texture = pyrender.Texture(source=image, source_channels="RGBA" if image.shape[2] == 4 else "RGB", sampler=linear)
        self._parts = []
        # Back faces are culled but for the see-through eyelashes, cards seen from both
        # sides: a frame draws 12-15% faster (llvmpipe, 512², measured on 2026-12-02) and
        # differs only where a back face peeked past a silhouette, a few pixels of a few
        # frames (the open neck's rim, the inner upper lip of a wide-open mouth).
        if face is not None:
            key = KEY_DIRECTION / np.linalg.norm(KEY_DIRECTION)
            lit = PHOTO_AMBIENT + (1 - PHOTO_AMBIENT) * np.clip(self._normals @ key, 0.0, 1.0)
            teeth = np.concatenate([p.triangles.ravel() for p in figure.parts if p.name == "M_Teeth"])
            deep = figure.rest[teeth, 2].max() - figure.rest[:, 2]
            shade = lit * np.clip(1.0 - (1.0 - MOUTH_DARKEST) * deep / MOUTH_DEEP, MOUTH_DARKEST, 1.0)
        for part in figure.parts:
            if face is not None and part.name == "M_EyeLashes":
                continue
            if texture is not None and part.uv is not None:
                rows, uv, local = _texture_vertices(part.triangles, part.uv)
                material = pyrender.MetallicRoughnessMaterial(baseColorTexture=texture, metallicFactor=0.0, doubleSided=False)
                primitive = pyrender.Primitive(positions=figure.rest[rows], normals=self._normals[rows], texcoord_0=uv,
                                               indices=local, material=material)
                attribute = uv
            else:
                rows, local = np.unique(part.triangles, return_inverse=True)
                colour = figure.colour[rows].copy()
                if face is not None:
                    colour[:, :3] *= shade[rows, None]
                see_through = bool((colour[:, 3] < 1).any())  # eyelashes fade to their tips
                material = pyrender.MetallicRoughnessMaterial(baseColorFactor=(1.0, 1.0, 1.0, 1.0), metallicFactor=0.0,
                                                              roughnessFactor=part.roughness, doubleSided=see_through,
                                                              alphaMode="BLEND" if see_through else "OPAQUE")
                primitive = pyrender.Primitive(positions=figure.rest[rows], normals=self._normals[rows], color_0=colour,
                                               indices=local.reshape(-1, 3), material=material)
                attribute = colour
            scene.add(pyrender.Mesh([primitive]), parent_node=self._head)
            self._parts.append((primitive, rows, np.asarray(attribute, dtype=np.float32)))
        self._vertex_arrays = [np.empty((len(rows), 6 + attribute.shape[1]), dtype=np.float32) for _, rows, attribute in self._parts]

    def _add_eyes_and_mouth(self, scene, rest, faces, pyrender, trimesh) -> None:
        eyes, mouth = _openings(rest, faces)
        for loop in eyes:
            centre, radius = eyeball(rest[loop])
            ball = trimesh.creation.icosphere(subdivisions=3, radius=radius)
            angle = np.arccos(np.clip(ball.vertices[:, 2] / radius, -1, 1))
            colours = np.where((angle < 0.2)[:, None], PUPIL, np.where((angle < 0.46)[:, None], IRIS, SCLERA))
            ball.visual.vertex_colors = (np.asarray(colours) * 255).astype(np.uint8)
            node = scene.add(pyrender.Mesh.from_trimesh(ball, smooth=True), pose=_pose(np.eye(3), centre),
                             parent_node=self._head)
            self._eyes.append((node, centre))
        if mouth is not None:
            points = rest[mouth]
            cavity = trimesh.creation.icosphere(subdivisions=3, radius=1.0)
            # deep and tall enough to fill the opening when the jaw drops (facesim.rig)
            cavity.apply_scale([0.6 * np.ptp(points[:, 0]), 2.4, 1.0])
            cavity.apply_translation(points.mean(axis=0) - np.array([0.0, 0.9, 1.9]))
            material = pyrender.MetallicRoughnessMaterial(baseColorFactor=MOUTH, metallicFactor=0.0, roughnessFactor=1.0)
            scene.add(pyrender.Mesh.from_trimesh(cavity, material=material, smooth=True), parent_node=self._head)

    def view(self, yaw: float = 0.0, pitch: float = 0.0, light: float = 1.0) -> None:
        """Turn the camera about the face by yaw and pitch (degrees, added to the preset)
        and scale the lights' intensity: the jitter of a dataset."""
        yaw, pitch = self._yaw + np.radians(yaw), np.radians(pitch)
        direction = np.array([-np.sin(yaw) * np.cos(pitch), np.sin(pitch), np.cos(yaw) * np.cos(pitch)])
        self._scene.set_pose(self._camera, _look_at(self._centre + self._distance * direction, self._centre))
        for node, base in zip(self._lights, (KEY_LIGHT, FILL_LIGHT)):
            node.light.intensity = base * light

    def _upload(self, primitive, data: np.ndarray) -> None:
        from OpenGL import GL

        GL.glBindBuffer(GL.GL_ARRAY_BUFFER, primitive._buffers[0])
        GL.glBufferSubData(GL.GL_ARRAY_BUFFER, 0, data.nbytes, data)

    def pose(self, head_yaw=0.0, head_pitch=0.0, head_roll=0.0, gaze_yaw=0.0, gaze_pitch=0.0) -> None:
        """Turn the head about the neck and the eyes about their centres (degrees, in the
        order of facesim.spec.POSE)."""
        head = rotation(head_yaw, head_pitch, head_roll)
        self._scene.set_pose(self._head, _pose(head, self._neck - head @ self._neck))  # about the neck
        for node, centre in self._eyes:  # the eyeball is built at the origin, pupil along +z
            self._scene.set_pose(node, _pose(rotation(gaze_yaw, gaze_pitch), centre))

    def render(self, positions: np.ndarray, arrows: np.ndarray | None = None, pose=None, jaw: float = 0.0) -> np.ndarray:
        """One frame: positions (n, 3) of the face, optional arrows (n, 3) drawn from
        each vertex (muscle forces), optional head and gaze angles (5,) in degrees, the
        jaw's angle (radians; a figure's teeth and tongue turn with it).
        Returns (height, width, 3) uint8."""
        return self._finished(self._drawn(self._prepared(positions, arrows, pose, jaw)))

    def frames(self, animation, arrows: np.ndarray | None = None, pose=None):
        """Every frame of a facesim.simulate.Animation in order, as ``frame`` draws them,
        each frame's vertex arrays computed on a second thread while the frame before it
        draws, and each drawn frame filtered there while the next one draws (the same
        bytes): llvmpipe's vertex work runs on the calling thread and left a core idle.
        The head's 35 frames of happy, side by side in one process (2026-12-03): 16.9 ->
        13.1 ms a frame at 256², 21.1 -> 18.5 at 512²; the mask at 256² 4.2 -> 3.3.
        ``arrows`` (frames, n, 3) as ``render``'s, frame by frame; ``pose`` (5,), one for
        every frame instead of the animation's (as ``frame``'s). An animation simulated in
        the background is drawn as its frames come (``Animation.ready``)."""
        if animation.frames == 0:
            return

        def prepare(k):  # into slot k mod 2, once the frame is simulated (facesim.simulate: in the background)
            animation.ready(k)
            return self._prepared_frame(animation, k, None if arrows is None else arrows[k], pose, k % 2)

        with ThreadPoolExecutor(1, thread_name_prefix="facesim-frames") as pool:
            upcoming, finishing = pool.submit(prepare, 0), None
            for k in range(animation.frames):
                prepared = upcoming.result()
                if k + 1 < animation.frames:  # into the other slot: this one's arrays upload below
                    upcoming = pool.submit(prepare, k + 1)
                colour = self._drawn(prepared)
                if finishing is not None:
                    yield finishing.result()
                finishing = pool.submit(self._finished, colour)
            if finishing is not None:
                yield finishing.result()

    def _prepared(self, positions: np.ndarray, arrows, pose, jaw: float, slot: int = 0) -> tuple:
        """What a frame (``render``) uploads, computed without OpenGL, so on any thread:
        the head's angles (and a mask's gaze), and the vertex arrays as [(primitive,
        array)], a figure's written into the arrays of ``slot`` (0 or 1)."""
        pose = np.zeros(5) if pose is None else np.asarray(pose, dtype=np.float64)
        positions = np.ascontiguousarray(positions, dtype=np.float64)
        normals, vertex_arrays = self._slots[slot]
        if self._figure is None:
            _vertex_normals(positions, self._faces, normals)
            uploads = [(self._face, np.hstack([positions, normals]).astype(np.float32))]
            angles = pose
        else:
            scene = self._figure.positions(positions, jaw, tuple(pose[3:5]))
            uploads = self._figure_arrays(scene, slot)
            positions = scene[self._figure.anchor]
            if self._wire is not None:  # a hair in front of the skin, toward the camera
                uploads.append((self._wire, (positions[self._edges.ravel()] + self._toward_camera).astype(np.float32)))
            angles = pose[:3]
        if self._arrows is not None:
            vectors = np.zeros_like(positions) if arrows is None else arrows
            uploads.append((self._arrows, np.stack([positions, positions + vectors], axis=1).reshape(-1, 3).astype(np.float32)))
        return angles, uploads

    @_in_own_context
    def _drawn(self, prepared: tuple) -> np.ndarray:
        """A prepared frame (``_prepared``) uploaded and drawn: the colour as drawn, its
        alpha where the head is for --onto."""
        angles, uploads = prepared
        self.pose(*angles)
        for primitive, data in uploads:
            self._upload(primitive, data)
        colour, depth = self._renderer.render(self._scene, flags=self._flags)
        if self._backdrop is not None:  # --onto: the alpha drawn where the head is, none elsewhere
            colour = np.array(colour)
            colour[:, :, 3] *= depth > 0
        return colour

    def render_figure(self, scene: np.ndarray) -> np.ndarray:
        """One frame of a head given every vertex of its figure (N, 3) rather than its
        simulation mesh, at rest pose: a scanned shape drawn with the same camera and
        lights (``scripts/realism.py``'s atlas). Returns (height, width, 3) uint8."""
        uploads = self._figure_arrays(np.ascontiguousarray(scene, dtype=np.float64), 0)
        return self._finished(self._drawn((np.zeros(3), uploads)))

    def _figure_arrays(self, scene: np.ndarray, slot: int) -> list:
        """The figure's parts' vertex arrays for its vertices ``scene`` (N, 3), written
        into the arrays of ``slot``, as [(primitive, array)]."""
        normals, vertex_arrays = self._slots[slot]
        _vertex_normals(scene, self._faces, normals)
        for (primitive, rows, attribute), vertices in zip(self._parts, vertex_arrays):
            _interleave(scene, normals, rows, attribute, vertices)
        return [(primitive, vertices) for (primitive, _, _), vertices in zip(self._parts, vertex_arrays)]

    def _finished(self, colour: np.ndarray) -> np.ndarray:
        """A drawn frame antialiased (``_antialiased``), and laid over the photo for --onto."""
        image = self._antialiased(colour)
        if self._backdrop is None:
            return image
        alpha = image[:, :, 3:] / 255.0  # lays the frame over the photo
        return np.clip(np.rint(alpha * image[:, :, :3] + (1.0 - alpha) * self._backdrop), 0, 255).astype(np.uint8)

    def _antialiased(self, colour: np.ndarray) -> np.ndarray:
        """The frame as drawn, antialiased as the settings ask: filtered along its edges,
        averaged down from the supersampled size, or as it is."""
        if self._smooth:
            image = np.empty_like(colour)
            _smooth_edges(colour, image)
            return image
        if self._factor == 1:
            return colour
        image = np.empty((self.settings.height, self.settings.width, colour.shape[2]), dtype=np.uint8)
        _downsample(colour, self._factor, image)
        return image

    def project(self, points: np.ndarray) -> np.ndarray:
        """(k, 2) pixel coordinates (x right, y down) where points (k, 3) of the head at
        rest pose appear in the frame."""
        camera = self._camera.camera
        pose = self._scene.get_pose(self._camera)
        view = np.linalg.inv(pose)
        w, h = self._factor * self.settings.width, self._factor * self.settings.height  # the viewport drawn
        clip = np.c_[points, np.ones(len(points))] @ (camera.get_projection_matrix(w, h) @ view).T
        ndc = clip[:, :2] / clip[:, 3:4]
        return np.column_stack([(ndc[:, 0] + 1) / 2 * self.settings.width, (1 - ndc[:, 1]) / 2 * self.settings.height])

    def frame(self, animation, k: int, arrows: np.ndarray | None = None, pose=None) -> np.ndarray:
        """Frame ``k`` of a facesim.simulate.Animation: its positions, jaw and pose (or
        ``pose`` instead)."""
        return self._finished(self._drawn(self._prepared_frame(animation, k, arrows, pose)))

    def _prepared_frame(self, animation, k: int, arrows, pose, slot: int = 0) -> tuple:
        """``_prepared`` for frame ``k`` of an animation: its positions, jaw and pose (or
        ``pose`` instead), the arrays written into ``slot``."""
        return self._prepared(animation.positions[k], arrows, animation.pose_at(k) if pose is None else pose,
                              animation.jaw_at(k), slot)

    @classmethod
    def of(cls, animation, settings: RenderSettings, backend: str = "auto") -> "FaceRenderer":
        """A renderer of the face (or head) an animation was simulated on."""
        return cls(animation.rest, animation.faces, settings, backend, animation.figure, animation.face)

    def close(self) -> None:
        """Free the renderer's GL objects and its context: what pyrender's
        OffscreenRenderer.delete does, without the full garbage collection it ends with,
        which took 112-125 ms of each close at the end of a render of the head
        (2026-12-03). What the context held is gone with it; its Python wrappers are left
        to the collector's own pace."""
        offscreen = getattr(self, "_renderer", None)
        if offscreen is not None:
            with _collection_paused():
                offscreen._platform.make_current()
                offscreen._renderer.delete()
                offscreen._platform.delete_context()
                offscreen._renderer = offscreen._platform = None  # its __del__ then finds nothing to delete
            self._renderer = None

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()


def probe(backend: str) -> str:
    """Open a tiny offscreen context with one backend and draw a triangle: 'ok' or why not.
    Run it in a fresh process (``facesim info`` does): a process keeps its first GL platform."""
    if not backend_available(backend):
        return f"missing ({_LIBRARIES[backend]} library not installed)"
    try:
        rest = np.array([[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]])
        with FaceRenderer(rest, np.array([[0, 1, 2]]), RenderSettings(32, 32), backend) as renderer:
            image = renderer.render(rest)
        return "ok" if image.std() > 0 else "renders blank frames"
    except Exception as exc:  # the probe reports every failure rather than raising
        return f"fails: {type(exc).__name__}: {str(exc).splitlines()[0] if str(exc) else ''}"


_shared: dict = {}


def shared_renderer(rest: np.ndarray, faces: np.ndarray, settings: RenderSettings, backend: str = "auto",
                    figure=None, face=None) -> FaceRenderer:
    """One renderer per process for each face (or head figure, or face directory) and
    settings, kept for every later call: how batch and dataset workers reuse their
    context across many specs or samples."""
    key = (rest.tobytes(), faces.tobytes(), settings, backend, None if figure is None else id(figure), None if face is None else face.path)
    if key not in _shared:
        _shared[key] = FaceRenderer(rest, faces, settings, backend, figure, face)
    return _shared[key]
