"""Offscreen rendering with OpenGL on a machine with no display and no GPU (OSMesa or
Mesa's software EGL): what a render is asked for (``settings``), the GL platform and the
lit shader (``backend``), the context, framebuffer, programs and buffers (``gl``, PyOpenGL
alone), cameras (``camera``), the frame's CPU-side filters (``filters``), and
``FaceRenderer`` (``scene``), which takes arrays (positions, a head's figure, poses) and
returns images. It imports no kernel of the physics.
"""
