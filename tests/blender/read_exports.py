"""Run by Blender (``blender -b --factory-startup --python read_exports.py -- GLB PC2 OUT FPS``)
for tests/test_export.py: import facesim's GLB and its point cache as a Blender user would,
and write what Blender makes of them to OUT (an NPZ): the GLB's shape keys, its actions'
frame ranges, the face's evaluated vertices at each frame of the clip (world coordinates,
and each one's rest position, by which the test finds ICT's vertex), and the OBJ with
the PC2's Mesh Cache modifier evaluated at each frame."""

import sys

import numpy

numpy.bool = bool  # Debian's Blender 3.4 glTF importer still says np.bool, gone from NumPy 1.24

import bpy  # noqa: E402

glb, pc2, out, fps = sys.argv[sys.argv.index("--") + 1:]
fps = int(fps)
scene = bpy.context.scene
scene.render.fps = fps


def evaluated(obj):
    depsgraph = bpy.context.evaluated_depsgraph_get()
    mesh = obj.evaluated_get(depsgraph).to_mesh()
    x = numpy.empty(len(mesh.vertices) * 3)
    mesh.vertices.foreach_get("co", x)
    obj.evaluated_get(depsgraph).to_mesh_clear()
    x = x.reshape(-1, 3)
    m = numpy.array(obj.matrix_world)
    return x @ m[:3, :3].T + m[:3, 3]


bpy.ops.wm.read_factory_settings(use_empty=True)
scene = bpy.context.scene
scene.render.fps = fps
bpy.ops.import_scene.gltf(filepath=glb)
face = next(o for o in scene.objects if o.type == "MESH")
keys = face.data.shape_keys
names = [k.name for k in keys.key_blocks]
rest = numpy.empty(len(face.data.vertices) * 3)
keys.key_blocks[0].data.foreach_get("co", rest)
action = keys.animation_data.action
start, end = action.frame_range
frames = []
for f in range(int(round(start)), int(round(end)) + 1):
    scene.frame_set(f)
    frames.append(evaluated(face))
glb_result = dict(names=numpy.array(names), key_start=start, key_end=end, glb_rest=rest.reshape(-1, 3),
                  glb_frames=numpy.array(frames), glb_matrix=numpy.array(face.matrix_world))

bpy.ops.wm.read_factory_settings(use_empty=True)
scene = bpy.context.scene
scene.render.fps = fps
bpy.ops.wm.obj_import(filepath=pc2[:-4] + ".obj", forward_axis="Y", up_axis="Z")  # the file's own axes
mesh = next(o for o in scene.objects if o.type == "MESH")
cache = mesh.modifiers.new("facesim", "MESH_CACHE")
cache.cache_format = "PC2"
cache.filepath = pc2
cached = []
for f in range(0, int(round(end)) + 1):
    scene.frame_set(f)
    cached.append(evaluated(mesh))
numpy.savez(out, obj_count=len(mesh.data.vertices), pc2_frames=numpy.array(cached), **glb_result)
