"""Offscreen rendering of face animations with OpenGL (facesim.renderer.gl), on a machine
with no display and no GPU: OSMesa or Mesa's software EGL.

One :class:`FaceRenderer` per process is built once and reused for every frame: the
scene (skin, eyeballs with iris and pupil behind the eye openings, a dark mouth cavity
behind the lips, a key and a fill light, a plain background) never changes; per frame
only the face's vertex buffer is rewritten in place (positions and Numba-computed
normals), never the scene, and the head and eye nodes get their pose: the head turns as a
rigid body about a pivot at the neck (yaw, pitch, roll), the eyeballs about their centres
(gaze yaw, pitch), under a fixed camera and fixed lights.

It draws what pyrender drew, byte for byte (its shaders, its state per part, its draw
order: solid parts farthest node first, then blended ones), without importing it.
``PYOPENGL_PLATFORM`` must be set before anything imports OpenGL, so nothing here imports
OpenGL until :func:`use_backend` has chosen the platform.
"""

from __future__ import annotations

from concurrent.futures import ThreadPoolExecutor

import numpy as np

from ..errors import RenderError
from ..face.colours import IRIS, MOUTH, PUPIL, SCLERA, SKIN
from ..geometry import _vertex_normals, rotation
from ..physics.mesh import FaceMesh
from ..physics.rig import eyeball
from .backend import LIT_SHADER, backend_available, use_backend
from .camera import _fitted_camera, _look_at, _perspective, _pose
from .filters import _downsample, _interleave, _smooth_edges
from .settings import (
    _LIBRARIES,
    ARROW,
    BACKGROUND,
    CAMERAS,
    FILL_DIRECTION,
    FILL_LIGHT,
    KEY_DIRECTION,
    KEY_LIGHT,
    MOUTH_DARKEST,
    MOUTH_DEEP,
    NECK_HEIGHT,
    PHOTO_AMBIENT,
    SUPERSAMPLE,
    SUPERSAMPLE_LIMIT,
    WIRE,
    WIRE_LIFT,
    RenderSettings,
)


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


class _Node:
    """A pose in the scene: the head's, or an eyeball's within the head (``parent``)."""

    def __init__(self, pose: np.ndarray, parent: "_Node | None" = None):
        self.pose, self.parent = pose, parent

    def world(self) -> np.ndarray:
        return self.pose if self.parent is None else self.parent.world() @ self.pose


class _Part:
    """A primitive (facesim.renderer.gl.Primitive) on a node, drawn with a material as
    pyrender's MetallicRoughnessMaterial: ``colour`` (its base colour factor), metallic,
    roughness, emissive, a texture, blended (alphaMode BLEND) or not, double-sided or
    culled; ``see_through``: drawn after the solid parts (pyrender's transparency)."""

    def __init__(self, primitive, node, colour=(1.0, 1.0, 1.0, 1.0), metallic=1.0, roughness=1.0, emissive=(0.0, 0.0, 0.0),
                 texture=None, blended=False, double_sided=False, see_through=False, defines=()):
        self.primitive, self.node = primitive, node
        self.colour, self.metallic, self.roughness, self.emissive = colour, metallic, roughness, emissive
        self.texture, self.blended, self.double_sided, self.see_through = texture, blended, double_sided, see_through
        self.defines = dict(defines)


def _texture_vertices(triangles: np.ndarray, uv: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """A textured part's vertices, one per (figure vertex, texture coordinate) pair: a
    vertex where the atlas's islands meet has several. Returns (m,) their figure rows,
    (m, 2) their UVs and the triangles (t, 3) over them."""
    corners = np.column_stack([triangles.reshape(-1).astype(np.float64), uv.reshape(-1, 2)])
    unique, local = np.unique(corners, axis=0, return_inverse=True)
    return unique[:, 0].astype(np.int64), unique[:, 1:], local.reshape(-1, 3)


class FaceRenderer:
    """One face drawn offscreen frame after frame, in a GL context of its own."""

    #: The fragment shader of lit parts (a test draws with pyrender's own instead).
    lit_shader = LIT_SHADER

    def __init__(self, rest: np.ndarray, faces: np.ndarray, settings: RenderSettings = RenderSettings(), backend: str = "auto",
                 figure=None, face=None):
        """A face mesh ``rest``/``faces`` (a mask, drawn with eyeballs and a mouth cavity
        behind its openings) or, with ``figure`` (facesim.face.figure), a whole head driven
        by its simulation mesh ``rest``; ``face`` (facesim.face.own_face.FaceDirectory), the
        face directory of that head, for the photo look and --onto."""
        settings = settings.for_face(None if figure is None else face)
        self.backend = use_backend(backend)
        self.settings = settings
        self._figure = figure
        self._context = None
        # lines (wireframe, arrows) are one pixel wide: supersampled they would fade to half
        lines = settings.wireframe or settings.show_muscles
        supersample = (settings.antialias and settings.supersample and not lines
                       and max(settings.width, settings.height) <= SUPERSAMPLE_LIMIT)
        self._factor = SUPERSAMPLE if supersample else 1
        self._smooth = settings.antialias and not lines and not supersample
        multisampled = settings.antialias and not supersample and not self._smooth  # lines, antialiased
        self._flat = settings.look == "photo"
        self._rgba = settings.onto is not None
        self._polygon_lines = settings.wireframe and figure is None
        width, height = self._factor * settings.width, self._factor * settings.height
        try:
            from . import gl

            self._context = gl.Context(self.backend, width, height)
            self._context.make_current()
            self._framebuffer = gl.Framebuffer(width, height, 4 if multisampled else 0, own=self.backend == "osmesa")
        except RenderError:
            raise
        except Exception as exc:
            raise RenderError(
                f"cannot open an offscreen GL context with {self.backend} ({type(exc).__name__}: {exc}); "
                "install Debian's libosmesa6 or try --backend egl"
            ) from None
        self._gl = gl
        self._programs: dict = {}
        self._head = _Node(np.eye(4))
        self._parts: list = []  # a figure's: (part, rows, attribute)
        self._drawn_parts: list[_Part] = []
        self._eyes: list[tuple] = []
        if figure is None:
            self._faces = np.ascontiguousarray(faces, dtype=np.int64)
            self._normals = np.empty_like(rest)
            _vertex_normals(rest, self._faces, self._normals)
            self._face = gl.Primitive(np.hstack([rest, self._normals]), [(1, 3)], self._faces)
            self._drawn_parts.append(_Part(self._face, self._head, SKIN, metallic=0.0, roughness=0.75, double_sided=True,
                                           defines=dict(NORMAL_LOC=1)))
            self._add_eyes_and_mouth(rest, faces)
            low, high = rest.min(axis=0), rest.max(axis=0)
            # The head turns about the top of the spine: behind the jaw, on the mask's back plane.
            self._neck = np.array([(low[0] + high[0]) / 2, low[1] + NECK_HEIGHT * (high[1] - low[1]), low[2]])
            framed = rest
        else:
            self._add_figure(figure, face if settings.look == "photo" else None)
            self._neck = figure.neck
            framed = rest if settings.framing == "face" else figure.rest
        self._arrows = self._lines(np.repeat(rest, 2, axis=0), ARROW) if settings.show_muscles else None
        # two sets of the arrays a frame writes before its upload, for ``frames``' two frames in flight
        arrays = getattr(self, "_vertex_arrays", [])
        self._slots = [(self._normals, arrays), (np.empty_like(self._normals), [np.empty_like(a) for a in arrays])]
        # A head's wireframe is its simulation mesh, drawn over the skin it drives.
        self._edges = FaceMesh(rest, faces).edges if figure is not None and settings.wireframe else None
        self._wire = None if self._edges is None else self._lines(rest[self._edges.ravel()], WIRE)

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
            self._projection = _perspective(fov, settings.width / settings.height, 1.0, 10 * distance)
            self._camera = _look_at(eye, centre)
        else:
            from ..face.own_face import onto_photo

            self._backdrop, fitted = onto_photo(face, settings.onto, (settings.width, settings.height))
            self._projection, self._camera = _fitted_camera(fitted, self._factor, width, height)
        self._lights = [[np.array((1.0, 0.97, 0.92)), KEY_LIGHT, -_look_at(centre + KEY_DIRECTION, centre)[:3, 2]],
                        [np.array((0.85, 0.9, 1.0)), FILL_LIGHT, -_look_at(centre + FILL_DIRECTION, centre)[:3, 2]]]
        self._light_scale = 1.0

    def _program(self, part: _Part):
        """The program that draws ``part`` (pyrender's choice: its lit shader, here
        facesim's, or its unlit one for the photo look), compiled once per set of defines."""
        fragment = "flat.frag" if self._flat else str(self.lit_shader)
        defines = dict(part.defines, INST_M_LOC=part.primitive.instance, USE_METALLIC_MATERIAL=1)
        if not self._flat:  # pyrender's room for four lights of each kind; facesim's two, a constant
            defines.update(MAX_DIRECTIONAL_LIGHTS=4, MAX_SPOT_LIGHTS=4, MAX_POINT_LIGHTS=4,
                           DIRECTIONAL_LIGHTS=len(self._lights))
        key = (fragment, tuple(sorted(defines.items())))
        if key not in self._programs:
            self._programs[key] = self._gl.Program("mesh.vert", fragment, defines)
        return self._programs[key]

    def _lines(self, points: np.ndarray, colour):
        """Line segments (point pairs) in one unlit colour, moved with the head."""
        from OpenGL import GL

        lines = self._gl.Primitive(points, [], mode=GL.GL_LINES)
        self._drawn_parts.append(_Part(lines, self._head, colour, emissive=colour[:3]))
        return lines

    def _add_figure(self, figure, face=None) -> None:
        """One primitive per part of the figure, each over its own vertices, coloured per
        vertex; smooth normals over the whole figure, so seams between parts that share
        vertices (face, scalp, neck) do not show. With ``face`` (the photo look) the parts
        the atlas holds are textured by its baked photo, their vertices split where the
        atlas's islands meet (``_texture_vertices``); of the eyelashes only the upper are
        drawn (``Figure.upper_lashes``), and the other parts' colours are shaded once at rest
        (``PHOTO_AMBIENT``), the whole drawn unlit."""
        gl = self._gl
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
            texture = gl.Texture(image)
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
                part = figure.upper_lashes(part)
            if texture is not None and part.uv is not None:
                rows, uv, local = _texture_vertices(part.triangles, part.uv)
                attribute = np.asarray(uv, dtype=np.float32)
                primitive = gl.Primitive(np.hstack([figure.rest[rows], self._normals[rows], attribute]), [(1, 3), (2, 2)], local)
                drawn = _Part(primitive, self._head, metallic=0.0, texture=texture,
                              defines=dict(NORMAL_LOC=1, TEXCOORD_0_LOC=2, HAS_BASE_COLOR_TEX=1))
            else:
                rows, local = np.unique(part.triangles, return_inverse=True)
                colour = figure.colour[rows].copy()
                if face is not None:
                    colour[:, :3] *= shade[rows, None]
                see_through = bool((colour[:, 3] < 1).any())  # eyelashes fade to their tips
                attribute = np.asarray(colour, dtype=np.float32)
                primitive = gl.Primitive(np.hstack([figure.rest[rows], self._normals[rows], attribute]), [(1, 3), (2, 4)],
                                         local.reshape(-1, 3))
                drawn = _Part(primitive, self._head, metallic=0.0, roughness=part.roughness, blended=see_through,
                              double_sided=see_through, see_through=see_through, defines=dict(NORMAL_LOC=1, COLOR_0_LOC=2))
            self._drawn_parts.append(drawn)
            self._parts.append((primitive, rows, attribute))
        self._vertex_arrays = [np.empty((len(rows), 6 + attribute.shape[1]), dtype=np.float32) for _, rows, attribute in self._parts]

    def _add_eyes_and_mouth(self, rest, faces) -> None:
        """A mask's eyeballs (iris and pupil toward +z, each on a node of its own that the
        gaze turns) and the dark mouth cavity behind its lips: trimesh's icospheres, drawn
        as pyrender drew trimesh's meshes (smooth normals, vertex colours blended)."""
        import trimesh

        gl = self._gl
        eyes, mouth = _openings(rest, faces)
        for loop in eyes:
            centre, radius = eyeball(rest[loop])
            ball = trimesh.creation.icosphere(subdivisions=3, radius=radius)
            angle = np.arccos(np.clip(ball.vertices[:, 2] / radius, -1, 1))
            colours = np.where((angle < 0.2)[:, None], PUPIL, np.where((angle < 0.46)[:, None], IRIS, SCLERA))
            ball.visual.vertex_colors = (np.asarray(colours) * 255).astype(np.uint8)
            colours = ball.visual.vertex_colors / 255.0  # RGBA, as pyrender took trimesh's colours
            primitive = gl.Primitive(np.hstack([ball.vertices, ball.vertex_normals, colours]), [(1, 3), (2, 4)], ball.faces)
            node = _Node(_pose(np.eye(3), centre), self._head)
            self._drawn_parts.append(_Part(primitive, node, metallic=0.2, roughness=0.8, blended=True,
                                           defines=dict(NORMAL_LOC=1, COLOR_0_LOC=2)))
            self._eyes.append((node, centre))
        if mouth is not None:
            points = rest[mouth]
            cavity = trimesh.creation.icosphere(subdivisions=3, radius=1.0)
            # deep and tall enough to fill the opening when the jaw drops (facesim.physics.rig)
            cavity.apply_scale([0.6 * np.ptp(points[:, 0]), 2.4, 1.0])
            cavity.apply_translation(points.mean(axis=0) - np.array([0.0, 0.9, 1.9]))
            primitive = gl.Primitive(np.hstack([cavity.vertices, cavity.vertex_normals]), [(1, 3)], cavity.faces)
            self._drawn_parts.append(_Part(primitive, _Node(np.eye(4), self._head), MOUTH, metallic=0.0, roughness=1.0,
                                           defines=dict(NORMAL_LOC=1)))

    def view(self, yaw: float = 0.0, pitch: float = 0.0, light: float = 1.0) -> None:
        """Turn the camera about the face by yaw and pitch (degrees, added to the preset)
        and scale the lights' intensity: the jitter of a dataset."""
        yaw, pitch = self._yaw + np.radians(yaw), np.radians(pitch)
        direction = np.array([-np.sin(yaw) * np.cos(pitch), np.sin(pitch), np.cos(yaw) * np.cos(pitch)])
        self._camera = _look_at(self._centre + self._distance * direction, self._centre)
        self._light_scale = light

    def pose(self, head_yaw=0.0, head_pitch=0.0, head_roll=0.0, gaze_yaw=0.0, gaze_pitch=0.0, *look) -> None:
        """Turn the head about the neck and the eyes about their centres (degrees, in the
        order of facesim.animation.spec.POSE), each eye also by its own ``look`` (the
        subject's left eye's yaw and pitch, then the right's: facesim.animation.simulate.look_table)."""
        head = rotation(head_yaw, head_pitch, head_roll)
        self._head.pose = _pose(head, self._neck - head @ self._neck)  # about the neck
        for node, centre in self._eyes:  # the eyeball is built at the origin, pupil along +z
            own = (0.0, 0.0) if not look else look[0:2] if centre[0] > 0 else look[2:4]
            node.pose = _pose(rotation(gaze_yaw + own[0], gaze_pitch + own[1]), centre)

    def render(self, positions: np.ndarray, arrows: np.ndarray | None = None, pose=None, jaw=0.0) -> np.ndarray:
        """One frame: positions (n, 3) of the face, optional arrows (n, 3) drawn from
        each vertex (muscle forces), optional head and gaze angles (5,) in degrees, the
        jaw's angle (radians) or its pose (4,): angle and glide (Animation.jaw; a
        figure's teeth and tongue turn and glide with it).
        Returns (height, width, 3) uint8."""
        return self._finished(self._drawn(self._prepared(positions, arrows, pose, jaw)))

    def frames(self, animation, arrows: np.ndarray | None = None, pose=None):
        """Every frame of a facesim.animation.simulate.Animation in order, as ``frame`` draws them,
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

        def prepare(k):  # into slot k mod 2, once the frame is simulated (facesim.animation.simulate: in the background)
            animation.ready(k)
            prepared = self._prepared_frame(animation, k, None if arrows is None else arrows[k], pose, k % 2)
            animation.release(k)  # its positions are in the slot's arrays now: a streamed run may reuse their room
            return prepared

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

    def _prepared(self, positions: np.ndarray, arrows, pose, jaw, slot: int = 0) -> tuple:
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
            scene = self._figure.positions(positions, jaw, tuple(pose[3:5]), pose[5:] if len(pose) > 5 else None)
            uploads = self._figure_arrays(scene, slot)
            positions = scene[self._figure.anchor]
            if self._wire is not None:  # a hair in front of the skin, toward the camera
                uploads.append((self._wire, (positions[self._edges.ravel()] + self._toward_camera).astype(np.float32)))
            angles = pose[:3]
        if self._arrows is not None:
            vectors = np.zeros_like(positions) if arrows is None else arrows
            uploads.append((self._arrows, np.stack([positions, positions + vectors], axis=1).reshape(-1, 3).astype(np.float32)))
        return angles, uploads

    def _drawn(self, prepared: tuple) -> np.ndarray:
        """A prepared frame (``_prepared``) uploaded and drawn: the colour as drawn, its
        alpha where the head is for --onto. Each part as pyrender drew it: the solid parts
        first, the farthest node first (in the order they were added where nodes tie: the
        head's parts all hang from one), then the see-through ones; blended or not, culled
        or double-sided, in polygon lines for a mask's wireframe."""
        from OpenGL import GL

        self._context.make_current()
        angles, uploads = prepared
        self.pose(*angles)
        for primitive, data in uploads:
            primitive.upload(data)
        framebuffer = self._framebuffer
        framebuffer.bind()
        GL.glEnable(GL.GL_DEPTH_TEST)
        GL.glDepthMask(GL.GL_TRUE)
        GL.glDepthFunc(GL.GL_LESS)
        GL.glDepthRange(0.0, 1.0)
        GL.glClearColor(*BACKGROUND)
        GL.glClear(GL.GL_COLOR_BUFFER_BIT | GL.GL_DEPTH_BUFFER_BIT)
        GL.glEnable(GL.GL_MULTISAMPLE)
        GL.glEnable(GL.GL_BLEND)
        GL.glPolygonMode(GL.GL_FRONT_AND_BACK, GL.GL_LINE if self._polygon_lines else GL.GL_FILL)
        view = np.linalg.inv(self._camera)
        eye = self._camera[:3, 3]
        poses = {id(part.node): part.node.world() for part in self._drawn_parts}
        far = {key: -np.linalg.norm(pose[:3, 3] - eye) for key, pose in poses.items()}
        order = sorted(self._drawn_parts, key=lambda part: (part.see_through, far[id(part.node)]))
        for part in order:
            program = self._program(part)
            program.use()
            program.set("V", view)
            program.set("P", self._projection)
            program.set("cam_pos", eye)
            if not self._flat:
                program.set("ambient_light", (0.28, 0.26, 0.26))
                program.set("n_directional_lights", len(self._lights))  # pyrender's shader counts them; facesim's does not
                for k, (colour, intensity, direction) in enumerate(self._lights):
                    program.set(f"directional_lights[{k}].color", colour)
                    program.set(f"directional_lights[{k}].intensity", float(intensity * self._light_scale))
                    program.set(f"directional_lights[{k}].direction", direction)
            program.set("M", poses[id(part.node)])
            if part.texture is not None:
                part.texture.bind(0)
                program.set("material.base_color_texture", 0)
            program.set("material.emissive_factor", part.emissive)
            program.set("material.base_color_factor", part.colour)
            program.set("material.metallic_factor", float(part.metallic))
            program.set("material.roughness_factor", float(part.roughness))
            GL.glBlendFunc(*((GL.GL_SRC_ALPHA, GL.GL_ONE_MINUS_SRC_ALPHA) if part.blended else (GL.GL_ONE, GL.GL_ZERO)))
            if part.double_sided:
                GL.glDisable(GL.GL_CULL_FACE)
            else:
                GL.glEnable(GL.GL_CULL_FACE)
                GL.glCullFace(GL.GL_BACK)
            part.primitive.draw()
        GL.glBindVertexArray(0)
        GL.glUseProgram(0)
        colour = framebuffer.pixels(alpha=self._rgba)
        if self._backdrop is not None:  # --onto: the alpha drawn where the head is, none elsewhere
            colour = np.array(colour)
            colour[:, :, 3] *= framebuffer.covered()
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
        clip = np.c_[points, np.ones(len(points))] @ (self._projection @ np.linalg.inv(self._camera)).T
        ndc = clip[:, :2] / clip[:, 3:4]
        return np.column_stack([(ndc[:, 0] + 1) / 2 * self.settings.width, (1 - ndc[:, 1]) / 2 * self.settings.height])

    def frame(self, animation, k: int, arrows: np.ndarray | None = None, pose=None) -> np.ndarray:
        """Frame ``k`` of a facesim.animation.simulate.Animation: its positions, jaw and pose (or
        ``pose`` instead)."""
        return self._finished(self._drawn(self._prepared_frame(animation, k, arrows, pose)))

    def _prepared_frame(self, animation, k: int, arrows, pose, slot: int = 0) -> tuple:
        """``_prepared`` for frame ``k`` of an animation: its positions, jaw and pose (or
        ``pose`` instead), the arrays written into ``slot``."""
        return self._prepared(animation.positions_at(k), arrows, animation.pose_at(k) if pose is None else pose,
                              animation.jaw_at(k), slot)

    @classmethod
    def of(cls, animation, settings: RenderSettings, backend: str = "auto") -> "FaceRenderer":
        """A renderer of the face (or head) an animation was simulated on."""
        return cls(animation.rest, animation.faces, settings, backend, animation.figure, animation.face)

    def close(self) -> None:
        """Free the renderer's context and what it held (its buffers, programs and
        textures go with it)."""
        if self._context is not None:
            self._context.delete()
            self._context = None

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
