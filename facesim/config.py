"""Project-wide constants: Numba options, numerical tolerances and default paths.

Every kernel takes its Numba options from here and every tolerance the code compares
against lives here, so that a reader can see them in one place and change them once.
"""

from pathlib import Path

#: Options for every ``@njit`` kernel. ``cache=True`` keeps compiled code on disk so that
#: a second process does not compile again.
NUMBA_OPTIONS = dict(cache=True, nogil=True, fastmath=True)

PACKAGE_DIR = Path(__file__).resolve().parent
PROJECT_DIR = PACKAGE_DIR.parent
#: The default face and its muscles (facesim is installed editable from its checkout).
DEFAULT_MESH = PROJECT_DIR / "meshes" / "face.obj"
DEFAULT_MUSCLES = PROJECT_DIR / "meshes" / "face.muscles.yaml"
#: The Hopper face (468 vertices, the scale of the thesis's HIGEM), which also simulates
#: ICT FaceKit's head (facesim.head); the head and its muscles.
HOPPER_MESH = PROJECT_DIR / "meshes" / "face.obj"
HEAD = PROJECT_DIR / "meshes" / "ict" / "head.npz"
HEAD_MUSCLES = PROJECT_DIR / "meshes" / "ict" / "head.muscles.yaml"

#: Below this muscle falloff δ (eq. 3.4) a vertex is outside the region of influence and
#: the flood fill of section 3.3 does not grow through it.
NEGLIGIBLE_DELTA = 1e-6

#: Lengths shorter than this (cm) are treated as zero (degenerate edges, triangles).
LENGTH_EPS = 1e-12

#: A muscle whose insertion lies closer to the midline than this fraction of the
#: face width is taken to be a midline muscle (no ``_l``/``_r`` side).
MIDLINE_FRACTION = 0.02

#: A muscle given as a 3D point is snapped to the nearest vertex; farther than this
#: fraction of the face's size (bounding-box diagonal) from every vertex is an error.
SNAP_FRACTION = 0.03
