"""What a first run compiles (issue 45): the kernels facesim ships compiled are this code's,
a new user's first render (and first photo's commands) loads every kernel it runs from
them and compiles none, and
with no compiled kernels at all a render compiles only the kernels it runs: the serial
twins of the physics for the head's small skin (facesim.physics.twins), no parallel
variant and nothing of the photo look. Asserted from Numba's dispatcher statistics,
not from timings.

And what a change compiles: a force term is one kernel and one line (gravity added to a
copy of the package exactly so, a module of its own in facesim/physics with its kernel
and a line in solver._forces, and the face sags under it), and a changed kernel is
compiled again in the kernels that call it. The copy with gravity is the package the
empty-cache render compiles: one compile of the physics (a minute) serves both."""

import json
import os
import platform
import shutil
import subprocess
import sys
import textwrap

import numpy as np
import pytest

from facesim.config import PROJECT_DIR, SHIPPED_KERNELS, shipped_kernels_key

#: Run in a fresh process: a render as `facesim render` does it, then every facesim
#: kernel's cache hits and misses (Numba's dispatcher statistics), by name.
RENDER_AND_COUNT = """
import json, sys
from facesim.cli import app
try:
    app(sys.argv[1:], prog_name="facesim")
except SystemExit as exit:
    assert not exit.code, exit.code
from numba.core.registry import CPUDispatcher
from facesim.physics import twins
kernels = {id(k): k for k in twins._twins.values()}
for name, module in list(sys.modules.items()):
    if name.startswith("facesim"):
        kernels.update((id(k), k) for k in vars(module).values() if isinstance(k, CPUDispatcher))
counts = {}
for kernel in kernels.values():
    name = kernel.py_func.__module__ + "." + kernel.py_func.__qualname__
    counts[name] = [sum(kernel.stats.cache_hits.values()), sum(kernel.stats.cache_misses.values()),
                    bool(kernel.targetoptions.get("parallel"))]
print(json.dumps(counts))
"""
GRAVITY = '''"""A toy term: gravity."""

from numba import njit

from ..config import NUMBA_OPTIONS


@njit(**NUMBA_OPTIONS)
def _gravity_forces(model, forces):
    """A toy term: a weight on every vertex, m g downward (g = 100 in facesim's units)."""
    for i in range(forces.force.shape[0]):
        forces.force[i, 1] -= model.mass * 100.0
'''
LINE = "    gravity._gravity_forces(model, forces)  # a toy term\n"
TERMS = "from . import (\n"
ANCHOR = "    muscle_forces._muscle_forces(model, xp, control, work, forces)  # eq. 3.1-3.4, 3.21-3.25\n"

SAG = textwrap.dedent("""
    import numpy as np
    from facesim.config import HOPPER_MESH, HOPPER_MUSCLES
    from facesim.animation.simulate import simulate
    from facesim.animation.spec import load_spec
    spec = load_spec("{spec}").with_overrides(mesh=HOPPER_MESH, muscles=HOPPER_MUSCLES)
    animation = simulate(spec)
    free = ~animation.model.pinned
    print(float((animation.positions[-1] - animation.rest)[free, 1].mean()))
""")


#: A face at rest: nothing contracts.
STILL = PROJECT_DIR / "tests" / "data" / "still.yaml"


def sag(package_root, spec, env=None):
    """Mean vertical displacement (cm) of the free vertices at the last frame of ``spec``,
    simulated by the facesim found under ``package_root``, in the environment ``env``
    (default: this one, the suite's compiled kernels)."""
    env = dict(os.environ if env is None else env, PYTHONPATH=str(package_root))
    result = subprocess.run([sys.executable, "-c", SAG.format(spec=spec)], capture_output=True, text=True, env=env,
                            cwd=package_root, timeout=600)
    assert result.returncode == 0, result.stderr[-2000:]
    return float(result.stdout.split()[-1])


def package_copy(tmp_path):
    """A copy of facesim under ``tmp_path`` (its data linked, not copied), to change."""
    copy = tmp_path / "facesim"
    shutil.copytree(PROJECT_DIR / "facesim", copy, ignore=shutil.ignore_patterns("__pycache__"))
    for data in ("meshes", "expressions"):
        (copy / data).symlink_to(PROJECT_DIR / data)
    return copy


SHIPPABLE = platform.machine() == "x86_64" and sys.version_info[:2] == (3, 11)


def fresh_env(home, shipped: bool) -> dict:
    """This environment as a new user's: ``home`` new (empty caches, Numba's in it), the
    CPU not named, with or without the shipped kernels."""
    env = {k: v for k, v in os.environ.items() if k not in ("NUMBA_CACHE_DIR", "FACESIM_CACHE", "NUMBA_CPU_NAME",
                                                              "NUMBA_CPU_FEATURES")}
    env.update(HOME=str(home), XDG_CACHE_HOME=str(home / ".cache"), FACESIM_SHIPPED_KERNELS="1" if shipped else "0")
    return env


def render_counts(tmp_path, shipped: bool, spec: str = "expressions/happy.yaml", *options, package=None) -> dict:
    """A render of ``spec`` on the head (or as ``options`` say) in a fresh process with
    empty caches (a new user's home), with or without the shipped kernels, by the facesim
    under ``package`` (default: this one): each kernel's [hits, misses, parallel]."""
    home = tmp_path / ("shipped" if shipped else "none")
    env = fresh_env(home, shipped)
    if package is not None:
        env["PYTHONPATH"] = str(package)
    return command_counts(env, package or PROJECT_DIR, "render", PROJECT_DIR / spec, "-o", home / "out.mp4",
                          "--size", "64x64", *options)


def command_counts(env: dict, cwd, *args) -> dict:
    """A facesim command (``args``) in a fresh process in ``env``: each kernel's [hits,
    misses, parallel] (``RENDER_AND_COUNT``)."""
    result = subprocess.run([sys.executable, "-c", RENDER_AND_COUNT, *map(str, args)],
                            capture_output=True, text=True, env=env, cwd=cwd, timeout=600)
    assert result.returncode == 0, result.stderr[-2000:]
    return json.loads(result.stdout.splitlines()[-1])


def compiled(counts: dict) -> set:
    """The kernels a run compiled (a cache miss), by name, from ``render_counts``."""
    return {name for name, (hits, misses, _) in counts.items() if misses}


@pytest.mark.skipif(not SHIPPABLE, reason="the kernels ship compiled for x86-64 and Python 3.11")
def test_the_shipped_kernels_are_compiled_from_this_code():
    """facesim/compiled holds kernels of this very code, Numba, Python and machine, for
    the CPU's baseline: any edit to a file with kernels needs `make kernels`
    (scripts/build_kernels.py), or a new user's first render compiles for a minute."""
    shipped = json.loads((SHIPPED_KERNELS / "kernels.json").read_text())
    assert shipped == shipped_kernels_key(), (
        f"facesim/compiled/kernels.json is for {shipped}, this code is {shipped_kernels_key()}: run `make kernels`")
    assert (SHIPPED_KERNELS / "kernels.tar.xz").stat().st_size > 100_000


@pytest.mark.skipif(not SHIPPABLE, reason="the kernels ship compiled for x86-64 and Python 3.11")
def test_a_new_users_first_render_loads_every_kernel_it_runs_and_compiles_none(tmp_path):
    counts = render_counts(tmp_path, shipped=True)
    loaded = {name for name, (hits, misses, _) in counts.items() if hits}
    assert not compiled(counts)  # nothing compiled
    assert "facesim.physics.solver._simulate__serial" in loaded and "facesim.geometry._vertex_normals" in loaded
    # the head's 468-vertex skin runs the twins: no parallel kernel of the physics is touched
    assert not {name for name in loaded if name.startswith("facesim.physics") and counts[name][2]}
    assert (tmp_path / "shipped" / "out.mp4").stat().st_size > 0


@pytest.mark.skipif(not SHIPPABLE, reason="the kernels ship compiled for x86-64 and Python 3.11")
def test_the_shipped_kernels_join_a_kernel_folder_that_is_there_already(tmp_path):
    """This code's kernel folder made before its kernels were built (a developer's run
    between an edit and `make kernels`) was left as it was, and every run after, a fresh
    clone's suite on that machine included, compiled what it lacked: the shipped kernels
    are added to it, nothing in it replaced."""
    from facesim.config import CODE_DIGEST

    folder = tmp_path / "shipped" / ".cache" / "facesim" / f"numba-{CODE_DIGEST[:16]}"
    (folder / "physics").mkdir(parents=True)
    (folder / "physics" / "notes.txt").write_text("mine")
    counts = render_counts(tmp_path, shipped=True)
    assert not compiled(counts)  # nothing compiled
    assert counts["facesim.physics.solver._simulate__serial"][0] >= 1
    assert (folder / "physics" / "notes.txt").read_text() == "mine" and (folder / "shipped.json").is_file()


@pytest.mark.skipif(not SHIPPABLE, reason="the kernels ship compiled for x86-64 and Python 3.11")
def test_a_new_users_first_words_over_an_expression_compile_nothing(tmp_path):
    """Words said over a smile: the jaw carries the skin as the smile shapes it, a rest
    shape rewritten each frame (facesim.physics.run). Handed to the kernels writable, it
    was a new type to Numba, and a new machine's first such render compiled every kernel
    again (47-60 s in the suite); read-only, as the model's own arrays, it loads them."""
    spec = tmp_path / "smiling_words.yaml"
    spec.write_text("name: smiling words\ninclude: [{spec: happy}]\nspeech: {text: Bob made a map.}\n")
    counts = render_counts(tmp_path, True, str(spec))
    assert not compiled(counts)  # nothing compiled
    assert counts["facesim.physics.solver._simulate__serial"][0] >= 1


@pytest.mark.skipif(not SHIPPABLE, reason="the kernels ship compiled for x86-64 and Python 3.11")
def test_a_new_users_first_photo_commands_compile_nothing(tmp_path):
    """The README's photo commands on a new machine: a face fitted to a photo and baked
    from it (the back-projection's kernels), drawn --onto the photo (the filters on frames
    with alpha) and a frame supersampled load their kernels from the shipped ones: they
    compiled for 3-4, about 2, and 0.4 s."""
    pytest.importorskip("mediapipe")
    import imageio.v3 as iio
    from skimage import data

    photo = tmp_path / "astronaut.png"
    iio.imwrite(photo, data.astronaut())
    env = fresh_env(tmp_path / "home", shipped=True)
    face = command_counts(env, PROJECT_DIR, "face", "from-photo", photo, "-o", tmp_path / "face")
    onto = command_counts(env, PROJECT_DIR, "render", "expressions/happy.yaml", "--face", tmp_path / "face", "--onto",
                          photo, "-o", tmp_path / "onto.png", "--frame", "34")
    supersampled = command_counts(env, PROJECT_DIR, "render", "expressions/surprise.yaml", "--supersample",
                                  "-o", tmp_path / "supersampled.png")
    assert not compiled(face) | compiled(onto) | compiled(supersampled)
    assert face["facesim.face.bake._bake"][0] >= 1 and onto["facesim.renderer.filters._smooth_edges"][0] >= 1
    assert supersampled["facesim.renderer.filters._downsample"][0] >= 1


@pytest.mark.skipif(not SHIPPABLE, reason="the kernels ship compiled for x86-64 and Python 3.11")
def test_a_large_meshs_first_render_loads_the_parallel_kernels_and_compiles_none(tmp_path):
    """A mesh of at least PARALLEL_FROM vertices (the Hopper face subdivided twice, 6,990)
    runs the physics' parallel kernels, which ship compiled too: its first render on a
    new machine compiled them for about 50 s."""
    from test_own_face import subdivision

    mesh, muscles = subdivision(tmp_path, 2)
    counts = render_counts(tmp_path, True, "expressions/happy.yaml", "--mesh", mesh, "--muscles", muscles)
    assert not compiled(counts)  # nothing compiled
    assert counts["facesim.physics.solver._simulate"][:2] == [1, 0]  # the variant that calls the parallel kernels
    assert "facesim.physics.muscle_forces._muscle_frame" in {
        name for name, (hits, _, parallel) in counts.items() if hits and parallel}
    serial = counts.get("facesim.physics.solver._simulate__serial", [0])
    assert serial[0] == 0  # the head's serial twin, not run


@pytest.fixture(scope="module")
def compiled_copy(tmp_path_factory):
    """A copy of the package with gravity added as one kernel and one line, compiled from
    nothing, once for the module's tests (a compile of the physics takes a minute): a
    blink rendered on the head in a fresh process with an empty cache and no shipped
    kernels (its kernels' statistics), then in another process, loading what that one
    compiled, the still spec's sag on the Hopper face."""
    root = tmp_path_factory.mktemp("copy")
    copy = package_copy(root)
    (copy / "physics" / "gravity.py").write_text(GRAVITY)
    solver = (copy / "physics" / "solver.py").read_text()
    assert solver.count(ANCHOR) == 1 and solver.count(TERMS) == 1
    (copy / "physics" / "solver.py").write_text(solver.replace(ANCHOR, ANCHOR + LINE).replace(TERMS, TERMS + "    gravity,\n"))
    counts = render_counts(root, False, "expressions/blink.yaml", package=root)
    return counts, sag(root, STILL, env=fresh_env(root / "none", shipped=False))


@pytest.mark.heavy(110)
def test_with_no_compiled_kernels_a_render_compiles_only_the_kernels_it_runs(compiled_copy):
    """An empty cache and no shipped kernels (another machine, another Python): the
    render compiles the kernels it runs and no other: the physics' serial twins, never
    their parallel kernels; nothing of the photo look or of a face from a photo; the
    same kernels the shipped ones hand a new user. (The package compiled is the copy
    with gravity: its term compiled with the solver that calls it.)"""
    counts, _ = compiled_copy
    compiled_now = compiled(counts)
    assert not {name for name, (hits, misses, _) in counts.items() if hits}
    physics = {name for name in compiled_now if name.startswith("facesim.physics")}
    assert "facesim.physics.solver._simulate__serial" in physics and "facesim.physics.gravity._gravity_forces" in physics
    assert not {name for name in physics if counts[name][2]}  # no parallel variant
    assert "facesim.physics.solver._simulate" not in counts or counts["facesim.physics.solver._simulate"][1] == 0
    assert not {name for name in compiled_now if name.startswith("facesim.face.bake")}
    # every kernel compiled is one the run called: a kernel called by another is compiled
    # with it (Numba's statistics count it), and none is compiled ahead (no signatures)
    never_called = {name for name, (hits, misses, _) in counts.items() if not hits and not misses}
    assert "facesim.physics.repulsion._edge_repulsion_forces" in never_called  # the parallel kernel, untouched


def test_a_force_term_is_one_kernel_and_one_line(compiled_copy):
    """Gravity added to a copy of the package as one kernel and one line (its module,
    named among the solver's terms): the face sags under its weight, where the package
    without it holds the same spec at rest."""
    _, with_gravity = compiled_copy
    without = sag(PROJECT_DIR, STILL)
    assert abs(without) < 1e-9  # nothing moves a face at rest
    # a weight of 100 against the tissue springs alone (k = 300 per vertex) would sag 0.33
    # cm; the skin's springs and pinned rim hold it to less, but it sags
    assert -0.34 < with_gravity < -0.02
    assert np.isfinite(with_gravity)


#: Two kernels declared as facesim's are (their options from facesim.config, which keys
#: their cache by facesim's code when a module first asks for them).
CALLEE = "from numba import njit\n\nfrom ...config import NUMBA_OPTIONS\n\n\n@njit(**NUMBA_OPTIONS)\ndef weight():\n    return {}\n"
CALLER = ("from numba import njit\n\nfrom ...config import NUMBA_OPTIONS\nfrom .callee import weight\n\n\n"
          "@njit(**NUMBA_OPTIONS)\ndef total():\n    return 2.0 * weight()\n")


def test_a_changed_kernel_is_compiled_again_in_the_kernels_that_call_it(tmp_path):
    """A compiled kernel carries the kernels it calls inside it (the solver carries every
    force term): when only a callee's file changes, the caller, its own file untouched,
    is compiled again from the same cache instead of loaded stale. Numba alone keys a
    kernel by its own file and loaded the stale caller (facesim.config._key_numba_cache;
    the solver kept a changed term's old code until it was keyed by all of facesim's)."""
    copy = package_copy(tmp_path)
    toy = copy / "physics" / "toy"
    toy.mkdir()
    (toy / "__init__.py").write_text("")
    (toy / "caller.py").write_text(CALLER)
    # no bytecode cache: callee.py rewritten within the second it was first imported, at its
    # old size, passes Python's check of a .pyc (whole seconds and size) and its old code
    # ran (CI: totals [2.0, 2.0]); what is under test is Numba's cache, not Python's
    env = dict(os.environ, PYTHONPATH=str(tmp_path), NUMBA_CACHE_DIR=str(tmp_path / "cache"), PYTHONDONTWRITEBYTECODE="1")
    command = [sys.executable, "-c", "from facesim.physics.toy.caller import total; print(total())"]

    totals = []
    for weight in ("1.0", "5.0"):
        (toy / "callee.py").write_text(CALLEE.format(weight))
        result = subprocess.run(command, capture_output=True, text=True, env=env, cwd=tmp_path, timeout=300)
        assert result.returncode == 0, result.stderr[-2000:]
        totals.append(float(result.stdout.split()[-1]))
    assert totals == [2.0, 10.0]
    assert any((tmp_path / "cache").rglob("caller.total-*.nbi"))  # the caller was cached, in the cache given


def test_a_command_that_runs_no_kernel_does_not_import_numba(tmp_path):
    """`facesim --help` and a bad spec's one-line error import no Numba (0.2 s of their
    0.36-0.44 s): facesim sets Numba up when a module with kernels first asks for its
    options (facesim.config.__getattr__), and then for the CPU's baseline and facesim's
    own cache, as before any kernel is decorated."""
    bad = tmp_path / "bad.yaml"
    bad.write_text("frames: -3\n")
    code = textwrap.dedent("""
        import sys
        from facesim.cli import app
        for argv in (["--help"], ["render", sys.argv[1]]):
            try:
                app(argv, prog_name="facesim")
            except SystemExit as exit:
                print("exit", exit.code)
        print("numba imported:", "numba" in sys.modules)
        import facesim.physics.springs, numba
        print("compiles for:", numba.config.CPU_NAME)
    """)
    env = {k: v for k, v in os.environ.items() if k not in ("NUMBA_CPU_NAME", "NUMBA_CPU_FEATURES")}
    result = subprocess.run([sys.executable, "-c", code, str(bad)], capture_output=True, text=True, env=env, timeout=120)
    assert result.returncode == 0, result.stderr[-2000:]
    lines = result.stdout.splitlines()
    assert "exit 0" in lines and "exit 2" in lines and "frames" in result.stderr  # the help, then the spec's error
    assert "numba imported: False" in lines and lines[-1] == "compiles for: generic"
