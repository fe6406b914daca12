"""Project-wide constants: Numba options, numerical tolerances and default paths.

Every kernel takes its Numba options from here and every tolerance the code compares
against lives here, so that a reader can see them in one place and change them once.
"""

import hashlib
import os
import threading
from pathlib import Path

#: facesim's version (pyproject.toml reads it from here).
VERSION = "0.1.0"

#: Options for every ``@njit`` kernel. ``cache=True`` keeps compiled code on disk so that
#: a second process does not compile again. ``error_model="numpy"``: a division by zero
#: gives inf or NaN, which the simulation reports with its frame (``physics.numerics._not_finite``
#: reads the bits, which ``fastmath`` cannot fold away), instead of raising
#: ZeroDivisionError out of a kernel. (Reached as ``NUMBA_OPTIONS``: see ``__getattr__``.)
_NUMBA_OPTIONS = dict(cache=True, nogil=True, fastmath=True, error_model="numpy")
#: The kernels whose loops run on several cores (``prange``): per vertex, per link in
#: ``CHUNKS`` fixed slices of the springs, pairs and hinges, each slice scattering into
#: its own buffer and the buffers summed per vertex in slice order (facesim.physics.numerics), so
#: a run gives the same bits on one thread as on four. (Reached as ``PARALLEL_OPTIONS``.)
_PARALLEL_OPTIONS = dict(_NUMBA_OPTIONS, parallel=True)
CHUNKS = 2
#: The smallest simulated mesh given every core (``numba.set_num_threads``); a smaller one
#: runs its parallel loops on one thread, where a parallel region's start (about 1.5 µs
#: on two threads against 0.5 on one, measured) costs more than its share of the work
#: saves: a 100 µs step of the 468-vertex faces starts 10 to 25 (one per parallel loop,
#: one per active muscle).
PARALLEL_FROM = 4000
#: How long libgomp's threads spin for work after a parallel loop before they sleep
#: (``GOMP_SPINCOUNT``, read when Numba first loads OpenMP), unless the user set it or
#: ``OMP_WAIT_POLICY``. libgomp's default, 300,000 spins, kept a core busy between a
#: render's parallel loops (the head's skin weights, the edge filter), a core that
#: llvmpipe's threads and the simulation wanted: the warm `facesim render
#: expressions/happy.yaml`, 6 alternated runs each, 2.22 -> 2.08 s median wall and 2.92 ->
#: 2.50 s of CPU. Sleeping at once (``OMP_WAIT_POLICY=passive``) slowed the 27,614-vertex
#: face's parallel step (2 threads: 0.75 -> 0.87-0.95 s), this count did not (0.60 s).
OPENMP_SPIN = 10_000

PACKAGE_DIR = Path(__file__).resolve().parent
PROJECT_DIR = PACKAGE_DIR.parent


def _code_digest() -> str:
    """A hash of the code facesim's compiled kernels are made of, and the package's name:
    what the kernels and the implicit step's cached factors (facesim.cache) are keyed by.
    The code: every .py file with a kernel (``njit``), this one and physics/layout.py,
    whose constants the kernels read as they compile; the rest (the command line, the
    specs, the writers, facesim.timings' use of Numba's events) cannot change a
    compiled kernel, and keying on it made every edit there compile everything again, a
    minute and more. The package's name too: a compiled kernel names the module
    it was compiled in, and the same code imported under another name (a vendored copy)
    cannot load it."""
    digest = hashlib.sha1(__name__.rpartition(".")[0].encode() + b"\0")
    for path in sorted(PACKAGE_DIR.rglob("*.py")):
        code = path.read_bytes()
        if path.relative_to(PACKAGE_DIR).as_posix() in ("config.py", "physics/layout.py") or b"njit" in code:
            digest.update(path.relative_to(PACKAGE_DIR).as_posix().encode() + b"\0" + code)
    return digest.hexdigest()


CODE_DIGEST = _code_digest()


def _portable_target() -> None:
    """Compile facesim's kernels for x86-64's (or the machine's) baseline, not for this
    CPU, so that kernels compiled on one machine run on every other: the ones that ship
    compiled (``_install_shipped_kernels``) and a cache shared over a network. Unless
    the user chose (``NUMBA_CPU_NAME``), ``NUMBA_CPU_NAME=generic`` is set for this
    process and its children, before Numba compiles anything here; what it costs, the
    baseline's instructions against the host's (no AVX or FMA), was 12% of the
    simulation's time on the head (19.7 against 22.2 ms for happy, medians of 7, measured
    on 2026-12-04). Numba keys every compiled kernel by its CPU, so kernels of either
    kind are never mixed up."""
    import numba
    from numba.core.registry import cpu_target

    if "NUMBA_CPU_NAME" in os.environ or "_toplevel_target_context" in vars(cpu_target):
        return  # the user's choice, or Numba already compiled in this process for its CPU
    os.environ["NUMBA_CPU_NAME"] = "generic"  # and NUMBA_CPU_FEATURES="" with it (Numba)
    numba.config.reload_config()


def _key_numba_cache() -> str:
    """Keep facesim's compiled kernels in a directory named by a hash of facesim's code,
    wherever facesim is installed; returns that directory.

    Numba's cache knows a kernel is stale only when the kernel's own file changes: a
    kernel of facesim.physics.solver compiled with facesim.physics' callees inlined is loaded
    again after kernels.py changes, and runs the old code (measured on 2026-12-02, a
    ``git pull`` over an editable install would do the same). And Numba files a kernel
    under a hash of its file's directory, so the same code in a second checkout, a wheel
    in a virtual environment or a clone elsewhere compiled everything again (about a
    minute). So facesim's kernels are found by ``CodeKeyedLocator``, put first among
    Numba's cache locators: under ``$NUMBA_CACHE_DIR`` if set, else facesim's cache
    directory (facesim.cache), in ``numba-<hash of facesim's .py files and the
    package's name>``, the same for every copy of the same code. A kernel's entry is
    fresh while that hash is the same (its stamp; Numba's own, the file's modification
    time, made every clone and checkout compile again), and Numba keys each entry by its
    CPU and Numba version. Runs before any facesim kernel is decorated: every module
    that compiles one takes its options from here. Other packages' kernels keep Numba's
    own locators."""
    import numba
    from numba.core import caching

    from .cache import directory

    # fixed when Numba is set up: a kernel made later in the process (a serial twin,
    # facesim.physics.twins) is kept beside the others whatever FACESIM_CACHE says by then
    # (a test that points it elsewhere for its own files had a twin compiled there, 47-60 s)
    root = os.path.join(numba.config.CACHE_DIR or os.fspath(directory()), f"numba-{CODE_DIGEST[:16]}")
    provided = getattr(caching, "UserProvidedCacheLocator", None) or caching._UserProvidedCacheLocator

    class CodeKeyedLocator(provided):
        def __init__(self, py_func, py_file):
            super().__init__(py_func, py_file)
            # one folder per subpackage: a file's kernels are indexed by its name alone
            self._cache_path = os.path.join(root, Path(py_file).resolve().parent.relative_to(PACKAGE_DIR))

        def get_source_stamp(self):
            return CODE_DIGEST

        @classmethod
        def from_function(cls, py_func, py_file):
            if not Path(py_file).resolve().is_relative_to(PACKAGE_DIR):
                return None
            # Numba's own steps past its CACHE_DIR test: the file exists, the folder is
            # writable (else the next locator, or no cache)
            return super(provided, cls).from_function(py_func, py_file)

    implementation = getattr(caching, "CacheImpl", None) or caching._CacheImpl
    implementation._locator_classes = [CodeKeyedLocator] + [
        c for c in implementation._locator_classes if c.__name__ != "CodeKeyedLocator"]
    return root


#: The kernels compiled ahead, shipped inside the package (scripts/build_kernels.py):
#: ``kernels.tar.xz`` holds a Numba cache folder (``_key_numba_cache``) and
#: ``kernels.json`` what it was compiled from and for.
SHIPPED_KERNELS = PACKAGE_DIR / "compiled"


def shipped_kernels_key() -> dict:
    """What shipped kernels must have been compiled from and for to be loaded here:
    this code, this Numba, this Python and machine, the baseline CPU."""
    import platform
    import sys

    import numba

    _portable_target()  # the CPU this process compiles for, whether or not a kernel module was imported yet

    return dict(code=CODE_DIGEST, numba=numba.__version__, python=f"py{sys.version_info[0]}{sys.version_info[1]}",
                machine=platform.machine(), cpu=numba.config.CPU_NAME)


#: Written into facesim's kernel folder once the shipped kernels are in it.
SHIPPED_MARK = "shipped.json"


def _install_shipped_kernels(folder: str) -> None:
    """Put the kernels that ship compiled where Numba looks for facesim's (``folder``)
    the first time this code runs, when they were compiled from this code for this
    Numba, Python and machine: a new user's first render loads them instead of
    compiling about a minute (scripts/build_kernels.py). A kernel they lack (a large
    mesh's parallel ones) compiles as before and joins them. Unpacked beside the folder
    and renamed into place; into a folder that is there already, without
    ``SHIPPED_MARK`` (this code run before its kernels were built, as a developer does
    between an edit and `make kernels`), the files it lacks are added, none replaced:
    kept out of such a folder, a fresh clone's suite compiled the kernels the folder
    lacked (its benchmark test 108 s against 52, 2026-12-07). Any failure (a read-only
    cache, a damaged archive) leaves Numba to compile, as without them."""
    archive, stamp = SHIPPED_KERNELS / "kernels.tar.xz", SHIPPED_KERNELS / "kernels.json"
    if (os.environ.get("FACESIM_SHIPPED_KERNELS") == "0" or not stamp.is_file()
            or os.path.exists(os.path.join(folder, SHIPPED_MARK))):
        return
    import contextlib
    import json
    import shutil
    import tarfile
    import tempfile

    try:
        if json.loads(stamp.read_text()) != shipped_kernels_key():
            return
        os.makedirs(os.path.dirname(folder), exist_ok=True)
        unpacked = tempfile.mkdtemp(prefix=f".{os.path.basename(folder)}.", dir=os.path.dirname(folder))
    except (OSError, ValueError):
        return
    try:
        with tarfile.open(archive) as tar:
            tar.extractall(unpacked, filter="data")
        with open(os.path.join(unpacked, SHIPPED_MARK), "w") as mark:
            mark.write(stamp.read_text())
        try:
            os.rename(unpacked, folder)  # fails if the folder is there: another process's copy, or an older one
        except OSError:
            for directory, _, files in os.walk(unpacked, topdown=False):  # the top, with the mark, last
                target = os.path.join(folder, os.path.relpath(directory, unpacked))
                os.makedirs(target, exist_ok=True)
                for name in sorted(files, key=lambda name: name == SHIPPED_MARK):
                    with contextlib.suppress(FileExistsError):  # a link never replaces a file
                        os.link(os.path.join(directory, name), os.path.join(target, name))
    except (OSError, tarfile.TarError):
        pass
    finally:
        with contextlib.suppress(OSError):
            shutil.rmtree(unpacked)


def _prefer_openmp() -> None:
    """Numba's parallel loops on OpenMP before TBB, unless the user chose a layer
    (``NUMBA_THREADING_LAYER`` or ``_PRIORITY``). Numba tries TBB first, and where the
    ``tbb`` package is installed its pool writes "Unable to join threads to shut down
    before fork()" on stdout each time a process forks, which every MP4 (ffmpeg started
    by imageio-ffmpeg) does. OpenMP, which Debian's libgomp provides, writes nothing.
    And its threads spin ``OPENMP_SPIN`` times between loops, unless the user chose."""
    import numba

    if not ({"NUMBA_THREADING_LAYER", "NUMBA_THREADING_LAYER_PRIORITY"} & set(os.environ)):
        numba.config.THREADING_LAYER_PRIORITY = ["omp", "tbb", "workqueue"]
    if not ({"OMP_WAIT_POLICY", "GOMP_SPINCOUNT"} & set(os.environ)):
        os.environ["GOMP_SPINCOUNT"] = str(OPENMP_SPIN)


_numba_ready = threading.Lock()
_numba_prepared = False


def prepare_numba() -> None:
    """Set Numba up for facesim, once per process, before it compiles, loads or runs
    anything of facesim's: the CPU's baseline (``_portable_target``), facesim's own cache
    folder (``_key_numba_cache``) with the kernels that ship compiled in it
    (``_install_shipped_kernels``), OpenMP's threads before TBB's (``_prefer_openmp``:
    before the first parallel loop or ``numba.set_num_threads`` starts the threads).
    Called for a module's kernels by ``__getattr__``, and by facesim.workers."""
    global _numba_prepared
    with _numba_ready:
        if not _numba_prepared:
            _portable_target()
            _install_shipped_kernels(_key_numba_cache())
            _prefer_openmp()
            _numba_prepared = True


def __getattr__(name: str):
    """``NUMBA_OPTIONS`` and ``PARALLEL_OPTIONS``, after ``prepare_numba``: Numba is set up
    the first time a module asks for its kernels' options, so a process that runs no
    kernel never imports it. `facesim --help` and a bad spec's error line took 0.36 and
    0.44 s, 0.2 s of it importing Numba; 0.14 and 0.25 s without (2026-12-07)."""
    options = {"NUMBA_OPTIONS": _NUMBA_OPTIONS, "PARALLEL_OPTIONS": _PARALLEL_OPTIONS}
    if name not in options:
        raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
    prepare_numba()
    return options[name]


def _data(name: str) -> Path:
    """A data directory shipped with facesim: inside the package when installed from a
    wheel (pyproject.toml maps meshes/ and expressions/ there), beside it in a checkout."""
    installed = PACKAGE_DIR / name
    return installed if installed.is_dir() else PROJECT_DIR / name


MESHES = _data("meshes")
#: The library of expression specs (happy, surprise, ...), found by name from any spec.
LIBRARY = _data("expressions")
#: The default face: ICT FaceKit's head (facesim.face.head), simulated through the Hopper face.
HEAD = MESHES / "ict" / "head.npz"
HEAD_MUSCLES = MESHES / "ict" / "head.muscles.yaml"
#: The Hopper face (468 vertices, the scale of the thesis's HIGEM): the thesis's timing
#: tables, the simulation mesh of the head, and the frame `facesim mesh align` fits to.
HOPPER_MESH = MESHES / "face.obj"
HOPPER_MUSCLES = MESHES / "face.muscles.yaml"
DEFAULT_MESH, DEFAULT_MUSCLES = HEAD, HEAD_MUSCLES


#: Muscle files by name, for ``muscles:`` in a spec and ``--muscles``: the head's,
#: calibrated against ICT FaceKit's scanned shapes (REALISM.md), which every face takes by
#: default (its points are MediaPipe landmark indices: the head, the Hopper face, any mesh
#: from `facesim mesh from-photo`; `facesim mesh align` carries it to other topologies by
#: position), and the thesis's muscle list and forces, for its tables (chapter 4).
MUSCLE_PRESETS = {"head": HEAD_MUSCLES, "thesis": HOPPER_MUSCLES}


def muscles_file(name: str | Path | None) -> Path:
    """The muscle file a spec or ``--muscles`` names: a preset (MUSCLE_PRESETS), a path,
    or, for none, the head's calibrated file."""
    if name is None:
        return DEFAULT_MUSCLES
    return MUSCLE_PRESETS.get(str(name), Path(name))


#: Below this muscle falloff δ (eq. 3.4) a vertex is outside the region of influence and
#: the flood fill of section 3.3 does not grow through it.
NEGLIGIBLE_DELTA = 1e-6

#: Lengths shorter than this (cm) are treated as zero (degenerate edges, triangles).
LENGTH_EPS = 1e-12
#: A triangle with less area than this fraction of its mesh's squared size has none
#: (``facesim mesh info`` and the check before every simulation refuse it).
DEGENERATE_AREA = 1e-10

#: A muscle whose insertion lies closer to the midline than this fraction of the
#: face width is taken to be a midline muscle (no ``_l``/``_r`` side).
MIDLINE_FRACTION = 0.02

#: A muscle given as a 3D point is snapped to the nearest vertex; farther than this
#: fraction of the face's size (bounding-box diagonal) from every vertex is an error.
SNAP_FRACTION = 0.03
