"""The head as a glTF 2.0 binary (GLB) that Blender, three.js, Unity and Unreal load: a
rig of ARKit's 52 morph targets baked by facesim's physics (facesim.animation.blendshapes),
a skeleton for what is rigid, and optionally a clip that plays an animation on it.

Layout (glTF 2.0, Khronos; units metres, +y up, the face toward +z, as ICT's head is in
cm): one mesh whose primitives are the head's drawn parts (ICT's materials: skin, back
of the head, gums and tongue, teeth, scleras, irises, lashes), all sharing one set of
vertex attributes in ICT FaceKit's vertex order (26,719 vertices: a point of the GLB's
POSITION is the same vertex as in ICT's OBJ and in facesim's NPZ), with the figure's
colour per vertex (COLOR_0, linear) and a metallic-roughness material per part. Each of
the 52 morph targets holds position and normal offsets as sparse accessors over the
vertices its shape moves (``MOVED``; a target's normals where they turn by more than
``TURNED``), named in ``mesh.extras.targetNames`` (Apple's spelling), the convention
three.js and Blender's importer read.

The skeleton: ``neck`` (the root, at the head's pivot, facesim.face.figure.HEAD_NECK),
``head`` (every vertex, turned about the neck by the head's pose), ``jaw`` (at the
mandible's hinge: the lower teeth, gums, tongue and floor of the mouth, with the figure's
own jaw weights, so a turned jaw joint moves them as facesim's jaw does) and ``eye_L``,
``eye_R`` (each eyeball about its centre: gaze). The targets carry the jaw's motion
(``jawOpen`` opens the teeth too, for an engine that drives shapes alone); the jaw joint
is for a user who wants to drive it as a bone.

A face directory's rig (``face``: facesim face from-photo) is the same head in its
identity, with the photo baked into the directory's atlas (head.png, embedded) as the base
colour of the parts the atlas holds (skin, back of the head, scleras, irises), drawn as
facesim's photo look draws them: unlit (``UNLIT``), of the eyelashes only the upper
(facesim.face.figure.Figure.upper_lashes). glTF keeps one texture coordinate per vertex, so a vertex where the atlas's
islands meet is split (``texture_seams``): the first 26,719 vertices are still ICT's, in its
order, and each one after is a copy of ICT's vertex ``mesh.extras.seams[i]``.

A clip (``Clip``): morph weights per frame (facesim's simulated frames fitted onto the
targets: facesim.animation.blendshapes.fit_weights) and the head's and eyes' rotations,
LINEAR samplers at the clip's frame times.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..animation.blendshapes import CORRECTIVE

#: ICT's centimetres to glTF's metres.
METRES = 0.01
#: A target holds the vertices its shape moves at least this far (cm), as sparse
#: accessors: 0.01 mm, a fiftieth of a pixel on a 512² face.
MOVED = 1e-3
#: ... and the normals that turn by more than this (unit vector difference, about 0.3°).
TURNED = 5e-3
#: The photo's parts are drawn unlit, as facesim's photo look draws them: the photo
#: carries its own light (lit again, the face darkened and its shading doubled in three.js).
UNLIT = "KHR_materials_unlit"
#: A clip's correctives are stored as normalised 16-bit integers (steps of 1/32767 m, 0.03
#: mm: facesim.animation.blendshapes.CORRECTIVE_STEP), and their targets over the same
#: vertices (a component and its opposite) share one list of indices: a 35-frame clip adds
#: less to the rig than its correctives as floats did.
QUANTIZED = "KHR_mesh_quantization"
#: The skeleton's joints, parents first.
JOINTS = ("neck", "head", "jaw", "eye_L", "eye_R")
_PARENT = {"head": "neck", "jaw": "head", "eye_L": "head", "eye_R": "head"}

_FLOAT, _UBYTE, _SHORT, _USHORT, _UINT = 5126, 5121, 5122, 5123, 5125
_ARRAY, _ELEMENTS = 34962, 34963
_LINEAR, _CLAMP = 9729, 33071


@dataclass(frozen=True)
class Clip:
    """An animation for the rig: ``weights`` (frames, 52) in [0, 1], ``head`` (frames, 3)
    the head's yaw, pitch and roll and ``eyes`` (frames, 2, 2) each eye's yaw and pitch
    (degrees, facesim.animation.spec.POSE; the subject's left eye first), at ``fps``."""

    name: str
    weights: np.ndarray
    head: np.ndarray
    eyes: np.ndarray
    fps: float


def srgb_to_linear(c: np.ndarray) -> np.ndarray:
    """sRGB-encoded colour (0-1, as facesim's colours are given) to linear, as glTF's COLOR_0 is."""
    c = np.clip(c, 0.0, 1.0)
    return np.where(c <= 0.04045, c / 12.92, ((c + 0.055) / 1.055) ** 2.4)


def _quaternions(matrices: np.ndarray) -> np.ndarray:
    """(k, 4) glTF's unit quaternions (x, y, z, w) of rotation matrices (k, 3, 3)."""
    from scipy.spatial.transform import Rotation

    return Rotation.from_matrix(matrices).as_quat().astype(np.float32)


class _Binary:
    """The GLB's one buffer, its views and accessors, gathered as they are added."""

    def __init__(self):
        from pygltflib import GLTF2

        self.chunks: list[bytes] = []
        self.length = 0
        self.gltf = GLTF2()
        self._indices: dict[bytes, int] = {}  # sparse accessors over the same rows share their indices

    def view(self, data: np.ndarray, target: int | None = None) -> int:
        from pygltflib import BufferView

        raw = np.ascontiguousarray(data).tobytes()
        pad = (-self.length) % 4
        self.chunks.append(b"\0" * pad + raw)
        self.length += pad
        self.gltf.bufferViews.append(BufferView(buffer=0, byteOffset=self.length, byteLength=len(raw), target=target))
        self.length += len(raw)
        return len(self.gltf.bufferViews) - 1

    def accessor(self, data: np.ndarray, kind: str, component: int, target: int | None = None, bounds: bool = False,
                 normalized: bool = False) -> int:
        from pygltflib import Accessor

        flat = data.reshape(len(data), -1)
        extra = dict(min=flat.min(axis=0).tolist(), max=flat.max(axis=0).tolist()) if bounds else {}
        self.gltf.accessors.append(Accessor(bufferView=self.view(data, target), componentType=component, count=len(data),
                                            type=kind, normalized=normalized or None, **extra))
        return len(self.gltf.accessors) - 1

    def sparse(self, count: int, rows: np.ndarray, values: np.ndarray, bounds: bool, quantized: bool = False) -> int:
        """A VEC3 accessor of ``count`` zeros but ``values`` at ``rows`` (glTF's sparse
        storage): floats or, ``quantized``, normalised 16-bit integers (KHR_mesh_quantization:
        steps of 1/32767, ``values`` already on them)."""
        from pygltflib import Accessor, AccessorSparseIndices, AccessorSparseValues, Sparse

        stored = np.rint(values * 32767).astype(np.int16) if quantized else values.astype(np.float32)
        extra = {}
        if bounds:  # over the whole accessor, its zeros included
            low = np.minimum(stored.min(axis=0, initial=0), 0) if len(rows) < count else stored.min(axis=0)
            high = np.maximum(stored.max(axis=0, initial=0), 0) if len(rows) < count else stored.max(axis=0)
            extra = dict(min=low.tolist(), max=high.tolist())
        sparse = None
        if len(rows):
            small = count < 65536
            key = rows.astype(np.uint32).tobytes()
            if key not in self._indices:
                self._indices[key] = self.view(rows.astype(np.uint16 if small else np.uint32))
            indices = AccessorSparseIndices(bufferView=self._indices[key], componentType=_USHORT if small else _UINT)
            sparse = Sparse(count=len(rows), indices=indices, values=AccessorSparseValues(bufferView=self.view(stored)))
        self.gltf.accessors.append(Accessor(byteOffset=None, componentType=_SHORT if quantized else _FLOAT, count=count,
                                            type="VEC3", sparse=sparse, normalized=quantized or None, **extra))
        return len(self.gltf.accessors) - 1

    def glb(self) -> bytes:
        from pygltflib import Buffer

        blob = b"".join(self.chunks)
        blob += b"\0" * ((-len(blob)) % 4)
        self.gltf.buffers = [Buffer(byteLength=len(blob))]
        self.gltf.set_binary_blob(blob)
        return b"".join(self.gltf.save_to_bytes())


def _skin_weights(figure, n: int) -> tuple[np.ndarray, np.ndarray]:
    """(n, 4) joints and weights: every vertex on ``head``, the mandible's on ``jaw`` by the
    figure's jaw weight, each eyeball on its eye."""
    joints = np.zeros((n, 4), dtype=np.uint8)
    weights = np.zeros((n, 4), dtype=np.float32)
    joints[:, 0], weights[:, 0] = JOINTS.index("head"), 1.0
    rows, w = figure.jaw_rows, figure.jaw_weight.astype(np.float32)
    joints[rows, 0], joints[rows, 1] = JOINTS.index("jaw"), JOINTS.index("head")
    weights[rows, 0], weights[rows, 1] = w, 1.0 - w
    for (rows, centre), name in zip(figure.eyes, ("eye_L", "eye_R")):  # the figure's eyes: the subject's left first
        joints[rows, 0], weights[rows, :] = JOINTS.index(name), (1.0, 0.0, 0.0, 0.0)
    joints[weights == 0] = 0
    return joints, weights


def texture_seams(figure, n: int) -> tuple[np.ndarray, np.ndarray, dict[str, np.ndarray]]:
    """The vertices of a textured rig: (n + e,) ``source``, the ICT vertex each is (ICT's
    ``n`` first, as themselves), (n + e, 2) their texture coordinates in glTF's convention
    (v down; the atlas's is up, as OBJ's) and, per textured part, its triangles over them.
    An ICT vertex keeps its own row for the first coordinate it takes in the atlas and is
    copied for each further one (where the atlas's islands meet), and for every one if an
    untextured part also draws it (its colour there is not the texture's)."""
    textured = [p for p in figure.parts if p.uv is not None]
    plain = np.zeros(n, dtype=bool)
    for part in figure.parts:
        if part.uv is None:
            plain[part.triangles.ravel()] = True
    corners = np.column_stack([np.concatenate([p.triangles.ravel() for p in textured]).astype(np.float64),
                               np.concatenate([p.uv.reshape(-1, 2) for p in textured])])
    pairs, corner_row = np.unique(corners, axis=0, return_inverse=True)  # sorted by vertex, then coordinate
    vertex = pairs[:, 0].astype(np.int64)
    own = np.r_[True, vertex[1:] != vertex[:-1]] & ~plain[vertex]
    row = np.where(own, vertex, n + np.cumsum(~own) - 1)
    source = np.concatenate([np.arange(n), vertex[~own]])
    uv = np.zeros((len(source), 2))  # an untextured vertex's is unused
    uv[row] = np.column_stack([pairs[:, 1], 1.0 - pairs[:, 2]])
    triangles, start = {}, 0
    for part in textured:
        count = part.triangles.size
        triangles[part.name] = row[corner_row.ravel()[start:start + count]].reshape(-1, 3)
        start += count
    return source, uv, triangles


def _joint_positions(figure) -> dict[str, np.ndarray]:
    """Each joint's place in the head's frame (cm)."""
    (_, left), (_, right) = figure.eyes
    return {"neck": figure.neck, "head": figure.neck, "jaw": figure.jaw_hinge, "eye_L": left, "eye_R": right}


def rig_glb(shapes, figure, clip: Clip | None = None, name: str = "facesim head", texture: Path | None = None) -> bytes:
    """The GLB's bytes: the rig of ``shapes`` (facesim.animation.blendshapes.Shapes) on the
    head ``figure`` (facesim.face.figure.Figure), with ``clip`` if given and, with a face
    directory's ``texture`` (its atlas, a PNG), the photo on the parts it holds (module
    docstring)."""
    import pygltflib as g

    from ..physics.model import vertex_normals

    out = _Binary()
    gltf = out.gltf
    gltf.asset = g.Asset(version="2.0", generator="facesim")
    rest = shapes.rest
    n = len(rest)
    drawn = figure.triangles
    normals = vertex_normals(rest, drawn)
    unused = ~np.isfinite(normals).all(axis=1) | (np.linalg.norm(normals, axis=1) < 0.5)
    normals[unused] = (0.0, 0.0, 1.0)  # vertices no drawn part uses (ICT's hidden shells) keep a valid normal
    colour = np.array(figure.colour, dtype=np.float64)
    colour[:, :3] = srgb_to_linear(colour[:, :3])
    source, uv, textured = np.arange(n), None, {}
    if texture is not None:
        source, uv, textured = texture_seams(figure, n)
        colour = colour[source]
        colour[np.unique(np.concatenate(list(textured.values())))] = 1.0  # COLOR_0 multiplies the texture
    count = len(source)
    joints, skin = _skin_weights(figure, n)
    attributes = g.Attributes(
        POSITION=out.accessor((rest[source] * METRES).astype(np.float32), "VEC3", _FLOAT, _ARRAY, bounds=True),
        NORMAL=out.accessor(normals[source].astype(np.float32), "VEC3", _FLOAT, _ARRAY),
        COLOR_0=out.accessor(np.rint(colour * 255).astype(np.uint8), "VEC4", _UBYTE, _ARRAY, normalized=True),
        JOINTS_0=out.accessor(joints[source], "VEC4", _UBYTE, _ARRAY),
        WEIGHTS_0=out.accessor(skin[source], "VEC4", _FLOAT, _ARRAY),
        TEXCOORD_0=None if uv is None else out.accessor(uv.astype(np.float32), "VEC2", _FLOAT, _ARRAY),
    )
    targets = []
    for k in range(len(shapes.names)):
        delta = shapes.deltas[k].astype(np.float64)[source]
        moved = np.flatnonzero(np.linalg.norm(delta, axis=1) >= MOVED)
        turn, turned = np.zeros((0, 3)), np.zeros(0, dtype=np.int64)
        corrective = shapes.names[k].startswith(CORRECTIVE)
        if not corrective:  # a clip's correctives are fractions of a millimetre: no turn
            turn = vertex_normals(rest + shapes.deltas[k], drawn)
            turn[unused] = normals[unused]
            turn = (turn - normals)[source]
            turned = np.flatnonzero(np.linalg.norm(turn, axis=1) > TURNED)
        targets.append(g.Attributes(POSITION=out.sparse(count, moved, delta[moved] * METRES, bounds=True, quantized=corrective),
                                  NORMAL=out.sparse(count, turned, turn[turned], bounds=False)))
    photo = None
    if texture is not None:
        gltf.images.append(g.Image(bufferView=out.view(np.frombuffer(Path(texture).read_bytes(), np.uint8)),
                                   mimeType="image/png", name="the photo, baked"))
        gltf.samplers.append(g.Sampler(magFilter=_LINEAR, minFilter=_LINEAR, wrapS=_CLAMP, wrapT=_CLAMP))
        gltf.textures.append(g.Texture(sampler=0, source=0))
        photo = g.TextureInfo(index=0)
        gltf.extensionsUsed.append(UNLIT)
    small = count < 65535
    primitives = []
    for part in figure.parts:
        if texture is not None and part.name == "M_EyeLashes":
            part = figure.upper_lashes(part)  # as facesim's photo look draws them
        see_through = part.name == "M_EyeLashes"
        on_photo = part.name in textured
        gltf.materials.append(g.Material(
            name=part.name, doubleSided=see_through, alphaMode="BLEND" if see_through else None,
            pbrMetallicRoughness=g.PbrMetallicRoughness(baseColorFactor=[1.0, 1.0, 1.0, 1.0], metallicFactor=0.0,
                                                      roughnessFactor=float(part.roughness),
                                                      baseColorTexture=photo if on_photo else None),
            extensions={UNLIT: {}} if on_photo else {}))
        triangles = textured[part.name] if on_photo else part.triangles
        indices = out.accessor(triangles.astype(np.uint16 if small else np.uint32).ravel(), "SCALAR",
                               _USHORT if small else _UINT, _ELEMENTS)
        primitives.append(g.Primitive(attributes=attributes, indices=indices, material=len(gltf.materials) - 1,
                                    targets=targets))
    if any(n.startswith(CORRECTIVE) for n in shapes.names):
        gltf.extensionsUsed.append(QUANTIZED)
        gltf.extensionsRequired.append(QUANTIZED)
    extras = {"targetNames": list(shapes.names)}
    if texture is not None:
        extras["seams"] = source[n:].tolist()
    gltf.meshes.append(g.Mesh(name=name, primitives=primitives, weights=[0.0] * len(shapes.names), extras=extras))

    places = _joint_positions(figure)
    for joint in JOINTS:
        parent = _PARENT.get(joint)
        local = places[joint] - (places[parent] if parent else 0.0)
        gltf.nodes.append(g.Node(name=joint, translation=(local * METRES).tolist()))
    for joint, parent in _PARENT.items():
        gltf.nodes[JOINTS.index(parent)].children.append(JOINTS.index(joint))
    bind = np.tile(np.eye(4, dtype=np.float32), (len(JOINTS), 1, 1))
    bind[:, 3, :3] = -np.array([places[j] for j in JOINTS]) * METRES  # column-major: the translation is the 4th column
    gltf.skins.append(g.Skin(name="facesim skeleton", joints=list(range(len(JOINTS))), skeleton=0,
                           inverseBindMatrices=out.accessor(bind.reshape(-1, 16), "MAT4", _FLOAT)))
    gltf.nodes.append(g.Node(name=name, mesh=0, skin=0))
    gltf.scenes.append(g.Scene(name=name, nodes=[0, len(gltf.nodes) - 1]))
    gltf.scene = 0

    if clip is not None:
        from ..geometry import rotation

        frames = len(clip.weights)
        times = out.accessor((np.arange(frames) / clip.fps).astype(np.float32), "SCALAR", _FLOAT, bounds=True)
        samplers = [g.AnimationSampler(input=times, interpolation="LINEAR",
                                     output=out.accessor(np.clip(clip.weights, 0, 1).astype(np.float32).reshape(-1, 1),
                                                         "SCALAR", _FLOAT))]
        channels = [g.AnimationChannel(sampler=0, target=g.AnimationChannelTarget(node=len(gltf.nodes) - 1, path="weights"))]
        turns = {"head": [rotation(*angles) for angles in clip.head],
                 "eye_L": [rotation(*angles) for angles in clip.eyes[:, 0]],
                 "eye_R": [rotation(*angles) for angles in clip.eyes[:, 1]]}
        for joint, matrices in turns.items():
            samplers.append(g.AnimationSampler(input=times, interpolation="LINEAR",
                                             output=out.accessor(_quaternions(np.array(matrices)), "VEC4", _FLOAT)))
            channels.append(g.AnimationChannel(sampler=len(samplers) - 1,
                                             target=g.AnimationChannelTarget(node=JOINTS.index(joint), path="rotation")))
        gltf.animations.append(g.Animation(name=clip.name, samplers=samplers, channels=channels))
    return out.glb()
