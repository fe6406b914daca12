"""Prototype: facesim's clay head drawn with PyOpenGL directly (no pyrender, no trimesh).
Only the default path: a head figure, clay look, perspective camera, EGL, edge filter.
Usage: python direct.py [compare|render ARGS...]"""
import ctypes
import sys
import time
from pathlib import Path

T0 = time.perf_counter()
import importlib.util  # noqa: E402

import numpy as np  # noqa: E402

from facesim.renderer import scene as S  # noqa: E402
from facesim.renderer.backend import LIT_SHADER, use_backend  # noqa: E402

# pyrender's mesh.vert, read from its package without importing it
SHADERS = Path(importlib.util.find_spec("pyrender").submodule_search_locations[0]) / "shaders"


def _source(text, defines):
    first, rest = text.split("\n", 1)
    return first + "\n" + "".join(f"#define {k} {v}\n" for k, v in defines.items()) + rest


class EGLContext:
    def __init__(self, width, height):
        from OpenGL import EGL, GL
        from OpenGL.EGL.EXT.device_base import egl_get_devices
        from OpenGL.EGL.EXT.platform_device import EGL_PLATFORM_DEVICE_EXT
        self.EGL = EGL
        self.display = EGL.eglGetPlatformDisplayEXT(EGL_PLATFORM_DEVICE_EXT, egl_get_devices()[0], None)
        major, minor = EGL.EGLint(), EGL.EGLint()
        EGL.eglInitialize(self.display, ctypes.pointer(major), ctypes.pointer(minor))
        attributes = (EGL.EGLint * 13)(EGL.EGL_SURFACE_TYPE, EGL.EGL_PBUFFER_BIT, EGL.EGL_RED_SIZE, 8, EGL.EGL_GREEN_SIZE, 8,
                                       EGL.EGL_BLUE_SIZE, 8, EGL.EGL_DEPTH_SIZE, 24, EGL.EGL_RENDERABLE_TYPE,
                                       EGL.EGL_OPENGL_BIT, EGL.EGL_NONE)
        config, count = EGL.EGLConfig(), EGL.EGLint()
        EGL.eglChooseConfig(self.display, attributes, ctypes.pointer(config), 1, ctypes.pointer(count))
        EGL.eglBindAPI(EGL.EGL_OPENGL_API)
        context = (EGL.EGLint * 7)(EGL.EGL_CONTEXT_MAJOR_VERSION, 4, EGL.EGL_CONTEXT_MINOR_VERSION, 1,
                                   EGL.EGL_CONTEXT_OPENGL_PROFILE_MASK, EGL.EGL_CONTEXT_OPENGL_CORE_PROFILE_BIT, EGL.EGL_NONE)
        self.context = EGL.eglCreateContext(self.display, config, EGL.EGL_NO_CONTEXT, context)
        self.make_current()
        self.fb = GL.glGenFramebuffers(1)
        GL.glBindFramebuffer(GL.GL_FRAMEBUFFER, self.fb)
        self.rb = GL.glGenRenderbuffers(2)
        GL.glBindRenderbuffer(GL.GL_RENDERBUFFER, self.rb[0])
        GL.glRenderbufferStorage(GL.GL_RENDERBUFFER, GL.GL_RGBA8, width, height)
        GL.glFramebufferRenderbuffer(GL.GL_FRAMEBUFFER, GL.GL_COLOR_ATTACHMENT0, GL.GL_RENDERBUFFER, self.rb[0])
        GL.glBindRenderbuffer(GL.GL_RENDERBUFFER, self.rb[1])
        GL.glRenderbufferStorage(GL.GL_RENDERBUFFER, GL.GL_DEPTH_COMPONENT24, width, height)
        GL.glFramebufferRenderbuffer(GL.GL_FRAMEBUFFER, GL.GL_DEPTH_ATTACHMENT, GL.GL_RENDERBUFFER, self.rb[1])
        self.width, self.height = width, height

    def make_current(self):
        E = self.EGL
        E.eglMakeCurrent(self.display, E.EGL_NO_SURFACE, E.EGL_NO_SURFACE, self.context)

    def delete(self):
        E = self.EGL
        E.eglMakeCurrent(self.display, E.EGL_NO_SURFACE, E.EGL_NO_SURFACE, E.EGL_NO_CONTEXT)
        E.eglDestroyContext(self.display, self.context)
        E.eglTerminate(self.display)


class Part:
    """A vertex buffer (positions, normals, RGBA) and its triangles, with its material."""

    def __init__(self, vertices, triangles, roughness, blended):
        from OpenGL import GL
        self.count = triangles.size
        self.roughness, self.blended = roughness, blended
        self.vao = GL.glGenVertexArrays(1)
        GL.glBindVertexArray(self.vao)
        self.vbo, self.ibo = GL.glGenBuffers(2)
        GL.glBindBuffer(GL.GL_ARRAY_BUFFER, self.vbo)
        GL.glBufferData(GL.GL_ARRAY_BUFFER, vertices.nbytes, vertices, GL.GL_DYNAMIC_DRAW)
        stride = vertices.shape[1] * 4
        for location, (offset, size) in enumerate(((0, 3), (3, 3), (6, 4))):
            GL.glEnableVertexAttribArray(location)
            GL.glVertexAttribPointer(location, size, GL.GL_FLOAT, GL.GL_FALSE, stride, ctypes.c_void_p(4 * offset))
        for k in range(4):  # pyrender's per-instance model matrix: one instance, the identity
            GL.glDisableVertexAttribArray(3 + k)
            GL.glVertexAttrib4f(3 + k, *np.eye(4)[k])
        GL.glBindBuffer(GL.GL_ELEMENT_ARRAY_BUFFER, self.ibo)
        indices = np.ascontiguousarray(triangles, dtype=np.uint32)
        GL.glBufferData(GL.GL_ELEMENT_ARRAY_BUFFER, indices.nbytes, indices, GL.GL_STATIC_DRAW)
        GL.glBindVertexArray(0)


def _perspective(yfov, aspect, near, far):
    t = np.tan(yfov / 2)
    p = np.zeros((4, 4))
    p[0, 0], p[1, 1], p[3, 2] = 1 / (aspect * t), 1 / t, -1
    p[2, 2], p[2, 3] = (far + near) / (near - far), 2 * far * near / (near - far)
    return p


class DirectRenderer(S.FaceRenderer):
    def __init__(self, rest, faces, settings=S.RenderSettings(), backend="auto", figure=None, face=None):
        settings = settings.for_face(face)
        assert figure is not None and settings.look == "clay" and settings.onto is None
        assert not (settings.wireframe or settings.show_muscles or settings.supersample)
        self.backend = use_backend(backend)
        from OpenGL import GL
        self.GL = GL
        self.settings = settings
        self._figure = figure
        self._factor, self._smooth = 1, settings.antialias
        self._wire = self._arrows = None
        self._backdrop = None
        self._context = EGLContext(settings.width, settings.height)
        self._faces = np.ascontiguousarray(figure.triangles, dtype=np.int64)
        self._normals = np.empty_like(figure.rest)
        S._vertex_normals(figure.rest, self._faces, self._normals)
        self._parts = []
        gl_parts = []
        for part in figure.parts:
            rows, local = np.unique(part.triangles, return_inverse=True)
            colour = figure.colour[rows].copy()
            see_through = bool((colour[:, 3] < 1).any())
            attribute = np.asarray(colour, dtype=np.float32)
            vertices = np.hstack([figure.rest[rows], self._normals[rows], attribute]).astype(np.float32)
            handle = Part(vertices, local.reshape(-1, 3), part.roughness, see_through)
            self._parts.append((handle, rows, attribute))
            gl_parts.append(handle)
        self._gl_parts = [p for p in gl_parts if not p.blended] + [p for p in gl_parts if p.blended]
        self._vertex_arrays = [np.empty((len(rows), 6 + a.shape[1]), dtype=np.float32) for _, rows, a in self._parts]
        arrays = self._vertex_arrays
        self._slots = [(self._normals, arrays), (np.empty_like(self._normals), [np.empty_like(a) for a in arrays])]
        self._neck = figure.neck
        framed = rest if settings.framing == "face" else figure.rest
        centre = (framed.min(axis=0) + framed.max(axis=0)) / 2
        extent = np.ptp(framed, axis=0)
        fov = np.radians(25.0)
        distance = 0.62 * max(extent[1], extent[0] * settings.height / settings.width) / np.tan(fov / 2) + extent[2] / 2
        yaw = np.radians(S.CAMERAS[settings.camera])
        eye = centre + distance * np.array([-np.sin(yaw), 0.0, np.cos(yaw)])
        camera_pose = S._look_at(eye, centre)
        self._V = np.linalg.inv(camera_pose)
        self._P = _perspective(fov, settings.width / settings.height, 1.0, 10 * distance)
        self._cam_pos = camera_pose[:3, 3]
        self._lights = []
        for colour, intensity, direction in (((1.0, 0.97, 0.92), S.KEY_LIGHT, S.KEY_DIRECTION),
                                             ((0.85, 0.9, 1.0), S.FILL_LIGHT, S.FILL_DIRECTION)):
            pose = S._look_at(centre + direction, centre)
            self._lights.append((np.array(colour), intensity, -pose[:3, 2]))
        defines = dict(NORMAL_LOC=1, COLOR_0_LOC=2, INST_M_LOC=3, MAX_DIRECTIONAL_LIGHTS=2, MAX_SPOT_LIGHTS=0,
                       MAX_POINT_LIGHTS=0, DIRECTIONAL_LIGHTS=2)
        from OpenGL.GL import shaders
        self._program = shaders.compileProgram(
            shaders.compileShader(_source((SHADERS / "mesh.vert").read_text(), defines), GL.GL_VERTEX_SHADER),
            shaders.compileShader(_source(LIT_SHADER.read_text(), defines), GL.GL_FRAGMENT_SHADER))
        self._M = np.eye(4)
        GL.glUseProgram(self._program)
        self._location = {}
        u = self._uniform
        GL.glUniformMatrix4fv(u("V"), 1, GL.GL_TRUE, self._V.astype(np.float32))
        GL.glUniformMatrix4fv(u("P"), 1, GL.GL_TRUE, self._P.astype(np.float32))
        GL.glUniform3fv(u("cam_pos"), 1, self._cam_pos.astype(np.float32))
        GL.glUniform3fv(u("ambient_light"), 1, np.array([0.28, 0.26, 0.26], np.float32))
        for i, (colour, intensity, direction) in enumerate(self._lights):
            GL.glUniform3fv(u(f"directional_lights[{i}].color"), 1, colour.astype(np.float32))
            GL.glUniform1f(u(f"directional_lights[{i}].intensity"), intensity)
            GL.glUniform3fv(u(f"directional_lights[{i}].direction"), 1, direction.astype(np.float32))
        GL.glUniform3fv(u("material.emissive_factor"), 1, np.zeros(3, np.float32))
        GL.glUniform4fv(u("material.base_color_factor"), 1, np.ones(4, np.float32))
        GL.glUniform1f(u("material.metallic_factor"), 0.0)

    def _uniform(self, name):
        if name not in self._location:
            self._location[name] = self.GL.glGetUniformLocation(self._program, name)
        return self._location[name]

    def pose(self, head_yaw=0.0, head_pitch=0.0, head_roll=0.0, *rest):
        head = S.rotation(head_yaw, head_pitch, head_roll)
        self._M = S._pose(head, self._neck - head @ self._neck)

    def _upload(self, part, data):
        GL = self.GL
        GL.glBindBuffer(GL.GL_ARRAY_BUFFER, part.vbo)
        GL.glBufferSubData(GL.GL_ARRAY_BUFFER, 0, data.nbytes, data)

    def _drawn(self, prepared):
        GL = self.GL
        self._context.make_current()
        angles, uploads = prepared
        self.pose(*angles)
        for part, data in uploads:
            self._upload(part, data)
        GL.glBindFramebuffer(GL.GL_FRAMEBUFFER, self._context.fb)
        GL.glViewport(0, 0, self.settings.width, self.settings.height)
        GL.glEnable(GL.GL_DEPTH_TEST)
        GL.glDepthMask(GL.GL_TRUE)
        GL.glDepthFunc(GL.GL_LESS)
        GL.glClearColor(*S.BACKGROUND)
        GL.glClear(GL.GL_COLOR_BUFFER_BIT | GL.GL_DEPTH_BUFFER_BIT)
        GL.glUseProgram(self._program)
        GL.glUniformMatrix4fv(self._uniform("M"), 1, GL.GL_TRUE, self._M.astype(np.float32))
        GL.glEnable(GL.GL_BLEND)
        for part in self._gl_parts:
            GL.glUniform1f(self._uniform("material.roughness_factor"), part.roughness)
            if part.blended:
                GL.glBlendFunc(GL.GL_SRC_ALPHA, GL.GL_ONE_MINUS_SRC_ALPHA)
                GL.glDisable(GL.GL_CULL_FACE)
            else:
                GL.glBlendFunc(GL.GL_ONE, GL.GL_ZERO)
                GL.glEnable(GL.GL_CULL_FACE)
                GL.glCullFace(GL.GL_BACK)
            GL.glBindVertexArray(part.vao)
            GL.glDrawElements(GL.GL_TRIANGLES, part.count, GL.GL_UNSIGNED_INT, None)
        GL.glBindVertexArray(0)
        w, h = self.settings.width, self.settings.height
        data = GL.glReadPixels(0, 0, w, h, GL.GL_RGB, GL.GL_UNSIGNED_BYTE)
        return np.frombuffer(data, dtype=np.uint8).reshape(h, w, 3)[::-1]

    def close(self):
        if getattr(self, "_context", None) is not None:
            self._context.delete()
            self._context = None


def patch():
    S.FaceRenderer.__init__ = DirectRenderer.__init__
    for name in ("_uniform", "pose", "_upload", "_drawn", "close"):
        setattr(S.FaceRenderer, name, getattr(DirectRenderer, name))


if __name__ == "__main__":
    if sys.argv[1] == "compare":
        import facesim
        spec = facesim.load_spec("happy")
        a = facesim.simulate(spec)
        settings = S.RenderSettings(512, 512)
        ref = S.FaceRenderer.of(a, settings)
        frames_ref = [ref.frame(a, k) for k in (0, 17, 34)]
        ref.close()
        patch()
        new = S.FaceRenderer.of(a, settings)
        frames_new = [new.frame(a, k) for k in (0, 17, 34)]
        print("direct context:", type(new._context).__name__, "pyrender renderer:", hasattr(new, "_renderer"))
        new.close()
        import imageio.v3 as iio
        for k, (x, y) in enumerate(zip(frames_ref, frames_new)):
            d = np.abs(x.astype(int) - y.astype(int))
            print(k, "mean", d.mean().round(3), "max", d.max(), "pixels >2:", int((d.max(axis=2) > 2).sum()))
        iio.imwrite("direct_cmp.png", np.vstack([np.hstack(frames_ref), np.hstack(frames_new)]))
    else:
        patch()
        from facesim.cli import main
        sys.argv = ["facesim"] + sys.argv[2:]
        main()
