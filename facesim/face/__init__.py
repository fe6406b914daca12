"""Faces: ICT FaceKit's scanned head and its identities (``head``), meshes read, checked
and written (``loading``), the muscle file placed on a mesh (``muscle_file``), the
material as files give it (``material``), the figure a head is drawn as, following the
simulated skin (``figure``, with its ``colours``), and your own face: landmarks and
meshes from a photo (``photo``), the head fitted to it (``fit``), the photo baked into
its texture (``bake``), a face directory (``own_face``), and other meshes aligned to the
face frame (``align``). Builds on facesim.physics; draws nothing.
"""
