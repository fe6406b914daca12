"""Run by Blender (``blender -b --factory-startup --python blender_still.py -- GLB SECONDS FPS PNG``)
for ``scripts/export_docs.py``: import a facesim GLB as a Blender user would, go to the
clip's frame at SECONDS, and render the face from the front with Cycles on the CPU (a
headless Blender has no viewport to grab) into PNG: docs/export_blender.png."""

import math
import sys

import numpy

numpy.bool = bool  # Debian's Blender 3.4 glTF importer still says np.bool, gone from NumPy 1.24

import bpy  # noqa: E402

glb, seconds, fps, png = sys.argv[sys.argv.index("--") + 1:]
bpy.ops.wm.read_factory_settings(use_empty=True)
scene = bpy.context.scene
scene.render.fps = int(fps)
bpy.ops.import_scene.gltf(filepath=glb)
scene.frame_set(round(float(seconds) * int(fps)))

camera = bpy.data.objects.new("camera", bpy.data.cameras.new("camera"))
camera.data.lens = 85
camera.location = (0.0, -0.75, -0.01)  # in front of the face (Blender's -y is glTF's +z), at eye height
camera.rotation_euler = (math.radians(90), 0.0, 0.0)
scene.collection.objects.link(camera)
scene.camera = camera
for name, energy, place in (("key", 6.0, (0.4, -1.0, 0.6)), ("fill", 2.5, (-0.6, -0.8, 0.1))):
    light = bpy.data.objects.new(name, bpy.data.lights.new(name, "SUN"))
    light.data.energy = energy
    light.rotation_euler = (math.atan2(math.hypot(place[0], place[1]), place[2]), 0.0,
                            math.atan2(place[0], -place[1]))
    scene.collection.objects.link(light)
world = bpy.data.worlds.new("world")
world.color = (0.6, 0.6, 0.62)
scene.world = world
world.use_nodes = True
world.node_tree.nodes["Background"].inputs[0].default_value = (0.6, 0.6, 0.62, 1.0)
world.node_tree.nodes["Background"].inputs[1].default_value = 0.6

scene.render.engine = "CYCLES"
scene.cycles.device = "CPU"
scene.cycles.samples = 32
scene.cycles.use_denoising = False  # Debian builds Blender without OpenImageDenoise
scene.render.resolution_x = scene.render.resolution_y = 512
scene.render.filepath = png
bpy.ops.render.render(write_still=True)
