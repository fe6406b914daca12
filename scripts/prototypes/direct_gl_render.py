"""The prototype renderer (direct_gl.py) in `facesim ARGS`: python direct_gl_render.py render happy -o out.mp4"""
import atexit
import sys

atexit.register(lambda: print('loaded:', [m for m in ('pyrender','trimesh','networkx','scipy','scipy.spatial','scipy.sparse','scipy.sparse.csgraph','scipy.optimize','numba') if m in sys.modules], file=sys.stderr))
sys.path.insert(0, str(__import__('pathlib').Path(__file__).parent))
import direct_gl as direct

direct.patch()
from facesim.cli import main

sys.argv = ['facesim'] + sys.argv[1:]
main()
