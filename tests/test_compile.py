"""What a first run compiles (issue 45): the kernels facesim ships compiled are this code's,
a new user's first render loads every kernel it runs from them and compiles none, and
with no compiled kernels at all a render compiles only the kernels it runs: the serial
twins of the physics for the head's small skin (facesim.physics.twins), no parallel
variant and nothing of the photo look. Asserted from Numba's dispatcher statistics,
not from timings."""

import json
import os
import platform
import subprocess
import sys

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
SHIPPABLE = platform.machine() == "x86_64" and sys.version_info[:2] == (3, 11)


def render_counts(tmp_path, shipped: bool, spec: str = "expressions/happy.yaml", *options) -> dict:
    """A render of ``spec`` on the head (or as ``options`` say) in a fresh process with
    empty caches (a new user's home), with or without the shipped kernels: each kernel's
    [hits, misses, parallel]."""
    home = tmp_path / ("shipped" if shipped else "none")
    env = {k: v for k, v in os.environ.items() if k not in ("NUMBA_CACHE_DIR", "FACESIM_CACHE", "NUMBA_CPU_NAME",
                                                              "NUMBA_CPU_FEATURES")}
    env.update(HOME=str(home), XDG_CACHE_HOME=str(home / ".cache"), FACESIM_SHIPPED_KERNELS="1" if shipped else "0")
    result = subprocess.run([sys.executable, "-c", RENDER_AND_COUNT, "render", spec, "-o", str(home / "out.mp4"),
                             "--size", "64x64", *map(str, options)],
                            capture_output=True, text=True, env=env, cwd=PROJECT_DIR, timeout=600)
    assert result.returncode == 0, result.stderr[-2000:]
    return json.loads(result.stdout.splitlines()[-1])


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
    assert not {name for name, (hits, misses, _) in counts.items() if misses}  # nothing compiled
    assert "facesim.physics.solver._simulate__serial" in loaded and "facesim.geometry._vertex_normals" in loaded
    # the head's 468-vertex skin runs the twins: no parallel kernel of the physics is touched
    assert not {name for name in loaded if name.startswith("facesim.physics") and counts[name][2]}
    assert (tmp_path / "shipped" / "out.mp4").stat().st_size > 0


@pytest.mark.skipif(not SHIPPABLE, reason="the kernels ship compiled for x86-64 and Python 3.11")
def test_a_large_meshs_first_render_loads_the_parallel_kernels_and_compiles_none(tmp_path):
    """A mesh of at least PARALLEL_FROM vertices (the Hopper face subdivided twice, 6,990)
    runs the physics' parallel kernels, which ship compiled too: its first render on a
    new machine compiled them for about 50 s."""
    from test_own_face import subdivision

    mesh, muscles = subdivision(tmp_path, 2)
    counts = render_counts(tmp_path, True, "expressions/happy.yaml", "--mesh", mesh, "--muscles", muscles)
    assert not {name for name, (hits, misses, _) in counts.items() if misses}  # nothing compiled
    assert counts["facesim.physics.solver._simulate"][:2] == [1, 0]  # the variant that calls the parallel kernels
    assert "facesim.physics.muscle_forces._muscle_frame" in {
        name for name, (hits, _, parallel) in counts.items() if hits and parallel}
    serial = counts.get("facesim.physics.solver._simulate__serial", [0])
    assert serial[0] == 0  # the head's serial twin, not run


@pytest.mark.heavy(70)
def test_with_no_compiled_kernels_a_render_compiles_only_the_kernels_it_runs(tmp_path):
    """An empty cache and no shipped kernels (another machine, another Python): the
    render compiles the kernels it runs and no other: the physics' serial twins, never
    their parallel kernels; nothing of the photo look or of a face from a photo; the
    same kernels the shipped ones hand a new user."""
    counts = render_counts(tmp_path, shipped=False, spec="expressions/blink.yaml")
    compiled = {name for name, (hits, misses, _) in counts.items() if misses}
    assert not {name for name, (hits, misses, _) in counts.items() if hits}
    physics = {name for name in compiled if name.startswith("facesim.physics")}
    assert "facesim.physics.solver._simulate__serial" in physics
    assert not {name for name in physics if counts[name][2]}  # no parallel variant
    assert "facesim.physics.solver._simulate" not in counts or counts["facesim.physics.solver._simulate"][1] == 0
    assert not {name for name in compiled if name.startswith("facesim.face.bake")}
    # every kernel compiled is one the run called: a kernel called by another is compiled
    # with it (Numba's statistics count it), and none is compiled ahead (no signatures)
    never_called = {name for name, (hits, misses, _) in counts.items() if not hits and not misses}
    assert "facesim.physics.repulsion._edge_repulsion_forces" in never_called  # the parallel kernel, untouched
