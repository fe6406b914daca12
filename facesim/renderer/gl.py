"""OpenGL without a display, with PyOpenGL alone: a context (Mesa's EGL on its device
platform, or OSMesa), a framebuffer to draw into and read back, shader programs, vertex
arrays and textures. What facesim draws with it is the business of facesim.renderer.scene.

pyrender did this until 2026-12: importing it (with trimesh, networkx and scipy's
spatial, sparse and optimize modules) took 0.54-0.61 s of every render's start, where
PyOpenGL's GL and EGL take 0.075 s, and it drew the same pixels (byte for byte: the head
at 512², 2026-12-07). The shaders are pyrender's (MIT licence), kept in ``shaders/``.
"""

from __future__ import annotations

import ctypes
from pathlib import Path

import numpy as np

from ..errors import RenderError

#: facesim's shaders: pyrender's vertex and unlit fragment shaders, facesim's lit one.
SHADERS = Path(__file__).with_name("shaders")
#: The per-instance model matrix of every draw (one instance, not moved).
_IDENTITY = np.eye(4)


class Context:
    """An offscreen OpenGL 3.3+ core context on the platform PyOpenGL was imported with
    (facesim.renderer.backend.use_backend): ``egl`` or ``osmesa``. EGL contexts of one
    process share one display, terminated with the last of them. OSMesa's draws into its
    own ``width`` x ``height`` buffer (``Framebuffer(own=True)``): drawn into a framebuffer
    object instead, a few pixels of some frames came out up to 6 levels otherwise than
    pyrender's (its depth buffer is not the renderbuffer's)."""

    _displays: dict = {}

    def __init__(self, platform: str, width: int, height: int):
        self.platform, self.width, self.height = platform, width, height
        if platform == "egl":
            self._egl()
        else:
            self._osmesa()

    def _egl(self) -> None:
        from OpenGL import EGL
        from OpenGL.EGL.EXT.device_base import egl_get_devices
        from OpenGL.EGL.EXT.platform_device import EGL_PLATFORM_DEVICE_EXT

        devices = egl_get_devices()
        if not devices:
            raise RenderError("EGL found no device (Mesa's software device: libegl-mesa0)")
        display = EGL.eglGetPlatformDisplayEXT(EGL_PLATFORM_DEVICE_EXT, devices[0], None)
        key = ctypes.cast(display, ctypes.c_void_p).value
        if key not in Context._displays:
            major, minor = EGL.EGLint(), EGL.EGLint()
            if not EGL.eglInitialize(display, ctypes.pointer(major), ctypes.pointer(minor)):
                raise RenderError("EGL could not initialise its display")
            Context._displays[key] = 0
        Context._displays[key] += 1
        attributes = (EGL.EGLint * 13)(EGL.EGL_SURFACE_TYPE, EGL.EGL_PBUFFER_BIT, EGL.EGL_RED_SIZE, 8,
                                       EGL.EGL_GREEN_SIZE, 8, EGL.EGL_BLUE_SIZE, 8, EGL.EGL_DEPTH_SIZE, 24,
                                       EGL.EGL_RENDERABLE_TYPE, EGL.EGL_OPENGL_BIT, EGL.EGL_NONE)
        config, count = EGL.EGLConfig(), EGL.EGLint()
        if not EGL.eglChooseConfig(display, attributes, ctypes.pointer(config), 1, ctypes.pointer(count)) or not count.value:
            raise RenderError("EGL offers no configuration with an RGB8 colour and a 24-bit depth buffer")
        EGL.eglBindAPI(EGL.EGL_OPENGL_API)
        version = (EGL.EGLint * 7)(EGL.EGL_CONTEXT_MAJOR_VERSION, 4, EGL.EGL_CONTEXT_MINOR_VERSION, 1,
                                   EGL.EGL_CONTEXT_OPENGL_PROFILE_MASK, EGL.EGL_CONTEXT_OPENGL_CORE_PROFILE_BIT,
                                   EGL.EGL_NONE)
        self._context = EGL.eglCreateContext(display, config, EGL.EGL_NO_CONTEXT, version)
        if not self._context:
            raise RenderError("EGL could not create an OpenGL 4.1 core context")
        self._display, self._key = display, key

    def _osmesa(self) -> None:
        from OpenGL import arrays, osmesa

        attributes = arrays.GLintArray.asArray([
            osmesa.OSMESA_FORMAT, osmesa.OSMESA_RGBA, osmesa.OSMESA_DEPTH_BITS, 24,
            osmesa.OSMESA_PROFILE, osmesa.OSMESA_CORE_PROFILE,
            osmesa.OSMESA_CONTEXT_MAJOR_VERSION, 3, osmesa.OSMESA_CONTEXT_MINOR_VERSION, 3, 0])
        self._context = osmesa.OSMesaCreateContextAttribs(attributes, None)
        if not self._context:
            raise RenderError("OSMesa could not create an OpenGL 3.3 core context")
        self._buffer = arrays.GLubyteArray.zeros((self.height, self.width, 4))

    def make_current(self) -> None:
        if self.platform == "egl":
            from OpenGL import EGL

            if not EGL.eglMakeCurrent(self._display, EGL.EGL_NO_SURFACE, EGL.EGL_NO_SURFACE, self._context):
                raise RenderError("EGL could not make its context current")
        else:
            from OpenGL import GL, osmesa

            if not osmesa.OSMesaMakeCurrent(self._context, self._buffer, GL.GL_UNSIGNED_BYTE, self.width, self.height):
                raise RenderError("OSMesa could not make its context current")

    def delete(self) -> None:
        """Free the context and what it held (the display too, with the last context on it)."""
        if self._context is None:
            return
        if self.platform == "egl":
            from OpenGL import EGL

            EGL.eglMakeCurrent(self._display, EGL.EGL_NO_SURFACE, EGL.EGL_NO_SURFACE, EGL.EGL_NO_CONTEXT)
            EGL.eglDestroyContext(self._display, self._context)
            Context._displays[self._key] -= 1
            if Context._displays[self._key] == 0:
                del Context._displays[self._key]
                EGL.eglTerminate(self._display)
        else:
            from OpenGL import osmesa

            osmesa.OSMesaDestroyContext(self._context)
        self._context = None


class Framebuffer:
    """An RGBA8 colour and 24-bit depth framebuffer, ``samples`` per pixel (0: one), read
    back through a single-sample copy when multisampled; or, ``own``, the context's own
    buffer (OSMesa's: one sample a pixel)."""

    def __init__(self, width: int, height: int, samples: int = 0, own: bool = False):
        self.width, self.height = width, height
        self.samples = 0 if own else samples
        self.draw = 0 if own else self._framebuffer(self.samples)
        self.read = self._framebuffer(0) if self.samples else self.draw

    def _framebuffer(self, samples: int) -> int:
        from OpenGL import GL

        colour, depth = GL.glGenRenderbuffers(2)
        for buffer, layout in ((colour, GL.GL_RGBA), (depth, GL.GL_DEPTH_COMPONENT24)):
            GL.glBindRenderbuffer(GL.GL_RENDERBUFFER, buffer)
            GL.glRenderbufferStorageMultisample(GL.GL_RENDERBUFFER, samples, layout, self.width, self.height)
        framebuffer = GL.glGenFramebuffers(1)
        GL.glBindFramebuffer(GL.GL_FRAMEBUFFER, framebuffer)
        GL.glFramebufferRenderbuffer(GL.GL_FRAMEBUFFER, GL.GL_COLOR_ATTACHMENT0, GL.GL_RENDERBUFFER, colour)
        GL.glFramebufferRenderbuffer(GL.GL_FRAMEBUFFER, GL.GL_DEPTH_ATTACHMENT, GL.GL_RENDERBUFFER, depth)
        if GL.glCheckFramebufferStatus(GL.GL_FRAMEBUFFER) != GL.GL_FRAMEBUFFER_COMPLETE:
            raise RenderError(f"could not make a {self.width}x{self.height} framebuffer")
        return framebuffer

    def bind(self) -> None:
        from OpenGL import GL

        GL.glBindFramebuffer(GL.GL_FRAMEBUFFER, self.draw)
        GL.glViewport(0, 0, self.width, self.height)

    def pixels(self, alpha: bool = False) -> np.ndarray:
        """(height, width, 3 or 4) uint8, top row first."""
        from OpenGL import GL

        if self.samples:
            GL.glBindFramebuffer(GL.GL_READ_FRAMEBUFFER, self.draw)
            GL.glBindFramebuffer(GL.GL_DRAW_FRAMEBUFFER, self.read)
            GL.glBlitFramebuffer(0, 0, self.width, self.height, 0, 0, self.width, self.height,
                                 GL.GL_COLOR_BUFFER_BIT, GL.GL_LINEAR)
        GL.glBindFramebuffer(GL.GL_READ_FRAMEBUFFER, self.read)
        channels, layout = (4, GL.GL_RGBA) if alpha else (3, GL.GL_RGB)
        data = GL.glReadPixels(0, 0, self.width, self.height, layout, GL.GL_UNSIGNED_BYTE)
        return np.frombuffer(data, dtype=np.uint8).reshape(self.height, self.width, channels)[::-1]

    def covered(self) -> np.ndarray:
        """(height, width) bool: where something was drawn (its depth written), top row
        first. Single-sample framebuffers only."""
        from OpenGL import GL

        GL.glBindFramebuffer(GL.GL_READ_FRAMEBUFFER, self.draw)
        data = GL.glReadPixels(0, 0, self.width, self.height, GL.GL_DEPTH_COMPONENT, GL.GL_FLOAT)
        return (np.frombuffer(data, dtype=np.float32).reshape(self.height, self.width) < 1.0)[::-1]


class Program:
    """A vertex and a fragment shader from ``SHADERS``, compiled with ``defines``;
    uniforms set only when their value changes (a program keeps them between draws)."""

    def __init__(self, vertex: str, fragment: str, defines: dict):
        from OpenGL import GL
        from OpenGL.GL import shaders

        def source(name):
            first, rest = (SHADERS / name).read_text().split("\n", 1)
            return first + "\n" + "".join(f"#define {k} {v}\n" for k, v in sorted(defines.items())) + rest

        self.id = shaders.compileProgram(shaders.compileShader(source(vertex), GL.GL_VERTEX_SHADER),
                                         shaders.compileShader(source(fragment), GL.GL_FRAGMENT_SHADER),
                                         validate=False)
        self._locations: dict[str, int] = {}
        self._held: dict[str, bytes] = {}

    def use(self) -> None:
        from OpenGL import GL

        GL.glUseProgram(self.id)

    def set(self, name: str, value) -> None:
        """Set a float, an int (a texture unit), a vector or a 4x4 matrix uniform."""
        from OpenGL import GL

        if name not in self._locations:
            self._locations[name] = GL.glGetUniformLocation(self.id, name)
        location = self._locations[name]
        if location == -1:
            return  # not used by this program's shaders: pyrender skips these too
        if isinstance(value, int):
            data = np.int32(value)
        else:
            data = np.asarray(value, dtype=np.float32)
        key = data.tobytes()
        if self._held.get(name) == key:
            return
        self._held[name] = key
        if isinstance(value, int):
            GL.glUniform1i(location, value)
        elif data.ndim == 0:
            GL.glUniform1f(location, float(data))
        elif data.ndim == 2:
            GL.glUniformMatrix4fv(location, 1, GL.GL_TRUE, data)
        else:
            (GL.glUniform2fv, GL.glUniform3fv, GL.glUniform4fv)[len(data) - 2](location, 1, data)


class Primitive:
    """Vertices (float32 rows of interleaved attributes: position, then each of
    ``layout``'s (location, width)) and, for triangles, their indices; ``mode`` a GL
    primitive type. The per-instance model matrix of pyrender's vertex shader, at the
    location after the attributes (``instance``, its INST_M_LOC), is the identity."""

    def __init__(self, vertices: np.ndarray, layout: list[tuple[int, int]], indices: np.ndarray | None = None,
                 mode: int | None = None):
        from OpenGL import GL

        vertices = np.ascontiguousarray(vertices, dtype=np.float32)
        self.instance = 1 + len(layout)
        self.mode = GL.GL_TRIANGLES if mode is None else mode
        self.count = len(vertices) if indices is None else indices.size
        self.vao = GL.glGenVertexArrays(1)
        GL.glBindVertexArray(self.vao)
        self.vbo = GL.glGenBuffers(1)
        GL.glBindBuffer(GL.GL_ARRAY_BUFFER, self.vbo)
        GL.glBufferData(GL.GL_ARRAY_BUFFER, vertices.nbytes, vertices, GL.GL_DYNAMIC_DRAW)
        stride, offset = vertices.shape[1] * 4, 0
        for location, width in [(0, 3)] + list(layout):
            GL.glEnableVertexAttribArray(location)
            GL.glVertexAttribPointer(location, width, GL.GL_FLOAT, GL.GL_FALSE, stride, ctypes.c_void_p(offset))
            offset += 4 * width
        self.ibo = None
        if indices is not None:
            self.ibo = GL.glGenBuffers(1)
            GL.glBindBuffer(GL.GL_ELEMENT_ARRAY_BUFFER, self.ibo)
            data = np.ascontiguousarray(indices, dtype=np.uint32)
            GL.glBufferData(GL.GL_ELEMENT_ARRAY_BUFFER, data.nbytes, data, GL.GL_STATIC_DRAW)
        GL.glBindVertexArray(0)

    def upload(self, vertices: np.ndarray) -> None:
        """Rewrite the vertices in place (the same rows and attributes), float32 and
        C-contiguous. Handed to OpenGL by their address: as an array, PyOpenGL's
        conversion took 2.9 ms of each frame of the head (its 9 parts, 1 MB; 2026-12-07)."""
        from OpenGL import GL

        if vertices.dtype != np.float32 or not vertices.flags.c_contiguous:
            raise ValueError("vertices must be C-contiguous float32")
        GL.glBindBuffer(GL.GL_ARRAY_BUFFER, self.vbo)
        GL.glBufferSubData(GL.GL_ARRAY_BUFFER, 0, vertices.nbytes, ctypes.c_void_p(vertices.ctypes.data))

    def draw(self) -> None:
        from OpenGL import GL

        GL.glBindVertexArray(self.vao)
        for k in range(4):  # a vertex array's constant attributes are the context's: set per draw
            GL.glVertexAttrib4f(self.instance + k, *_IDENTITY[k])
        if self.ibo is None:
            GL.glDrawArrays(self.mode, 0, self.count)
        else:
            GL.glDrawElements(self.mode, self.count, GL.GL_UNSIGNED_INT, None)


class Texture:
    """An RGB or RGBA uint8 image (top row first) as a texture, filtered linearly and
    without mipmaps, repeating."""

    def __init__(self, image: np.ndarray):
        from OpenGL import GL

        layout = GL.GL_RGBA if image.shape[2] == 4 else GL.GL_RGB
        self.id = GL.glGenTextures(1)
        GL.glBindTexture(GL.GL_TEXTURE_2D, self.id)
        GL.glPixelStorei(GL.GL_UNPACK_ALIGNMENT, 1)
        data = np.ascontiguousarray(image[::-1], dtype=np.uint8)
        GL.glTexImage2D(GL.GL_TEXTURE_2D, 0, layout, image.shape[1], image.shape[0], 0, layout, GL.GL_UNSIGNED_BYTE, data)
        for parameter, value in ((GL.GL_TEXTURE_MAG_FILTER, GL.GL_LINEAR), (GL.GL_TEXTURE_MIN_FILTER, GL.GL_LINEAR),
                                 (GL.GL_TEXTURE_WRAP_S, GL.GL_REPEAT), (GL.GL_TEXTURE_WRAP_T, GL.GL_REPEAT)):
            GL.glTexParameteri(GL.GL_TEXTURE_2D, parameter, value)
        GL.glBindTexture(GL.GL_TEXTURE_2D, 0)

    def bind(self, unit: int = 0) -> None:
        from OpenGL import GL

        GL.glActiveTexture(GL.GL_TEXTURE0 + unit)
        GL.glBindTexture(GL.GL_TEXTURE_2D, self.id)
