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

from concurrent.futures import ThreadPoolExecutor

import numpy as np

from ..errors import RenderError
from ..face.colours import IRIS, MOUTH, PUPIL, SCLERA, SKIN
from ..geometry import _vertex_normals, rotation
from ..physics.mesh import FaceMesh
from ..physics.rig import eyeball
from .backend import (
    _collection_paused,
    _colour_only,
    _in_own_context,
    _lit_shader,
    _share_egl_display,
    _single_sample,
    _stable_draw_order,
    backend_available,
    offscreen_pyrender,
    use_backend,
)
from .camera import _fitted_camera, _look_at, _pose
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


def _texture_vertices(triangles: np.ndarray, uv: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """A textured part's vertices, one per (figure vertex, texture coordinate) pair: a
    vertex where the atlas's islands meet has several. Returns (m,) their figure rows,
    (m, 2) their UVs and the triangles (t, 3) over them."""
    corners = np.column_stack([triangles.reshape(-1).astype(np.float64), uv.reshape(-1, 2)])
    unique, local = np.unique(corners, axis=0, return_inverse=True)
    return unique[:, 0].astype(np.int64), unique[:, 1:], local.reshape(-1, 3)


class FaceRenderer:
    """A pyrender scene of one face, rendered offscreen frame after frame."""

    def __init__(self, rest: np.ndarray, faces: np.ndarray, settings: RenderSettings = RenderSettings(), backend: str = "auto",
                 figure=None, face=None):
        """A face mesh ``rest``/``faces`` (a mask, drawn with eyeballs and a mouth cavity
        behind its openings) or, with ``figure`` (facesim.face.figure), a whole head driven
        by its simulation mesh ``rest``; ``face`` (facesim.face.own_face.FaceDirectory), the
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

    def _lines(self, scene, points: np.ndarray, colour):
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
        atlas's islands meet (``_texture_vertices``); of the eyelashes only the upper are
        drawn (``Figure.upper_lashes``), and the other parts' colours are shaded once at rest
        (``PHOTO_AMBIENT``), the whole drawn unlit."""
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
                part = figure.upper_lashes(part)
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
            # deep and tall enough to fill the opening when the jaw drops (facesim.physics.rig)
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

    def pose(self, head_yaw=0.0, head_pitch=0.0, head_roll=0.0, gaze_yaw=0.0, gaze_pitch=0.0, *look) -> None:
        """Turn the head about the neck and the eyes about their centres (degrees, in the
        order of facesim.animation.spec.POSE), each eye also by its own ``look`` (the
        subject's left eye's yaw and pitch, then the right's: facesim.animation.simulate.look_table)."""
        head = rotation(head_yaw, head_pitch, head_roll)
        self._scene.set_pose(self._head, _pose(head, self._neck - head @ self._neck))  # about the neck
        for node, centre in self._eyes:  # the eyeball is built at the origin, pupil along +z
            own = (0.0, 0.0) if not look else look[0:2] if centre[0] > 0 else look[2:4]
            self._scene.set_pose(node, _pose(rotation(gaze_yaw + own[0], gaze_pitch + own[1]), centre))

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
