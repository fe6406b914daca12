"""facesim benchmarks: the thesis's timing tables side by side with facesim's, and the
performance targets. Prints every table and writes BENCHMARKS.md and docs/scaling.png.

    python scripts/bench.py            # the full run (`make bench`, a few minutes)
    python scripts/bench.py --quick    # tiny sizes and few repeats (the smoke test)

Times are medians over repeated warm runs unless a table says otherwise; Numba's
compilation is kept out of them and measured on its own. Ratios are measured side by
side in the same run: this machine is shared and noisy.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import re
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT / "tests"))

from conftest import held_apex  # noqa: E402  (tests/: the solvers' comparison the tests make)

import facesim  # noqa: E402
from facesim.animation.simulate import model_for  # noqa: E402
from facesim.animation.spec import activation_table  # noqa: E402
from facesim.config import HOPPER_MESH, HOPPER_MUSCLES  # noqa: E402
from facesim.face.loading import load_mesh  # noqa: E402
from facesim.face.material import MaterialSpec, face_model  # noqa: E402
from facesim.face.muscle_file import MuscleFile, muscles_as_points, resolve_muscles  # noqa: E402
from facesim.physics.mesh import subdivide  # noqa: E402
from facesim.physics.run import run  # noqa: E402
from facesim.schema import load_model  # noqa: E402

EXPRESSIONS = ROOT / "expressions"
#: The thesis's tables run on the Hopper face (468 vertices, the scale of its 612-node
#: HIGEM); the default head has its own section.
THESIS_FACE = f".with_overrides(mesh={str(HOPPER_MESH)!r})"


def solved_by(name: str, **material):
    """An expression of the library on the default head, with material fields changed."""
    spec = facesim.load_spec(EXPRESSIONS / f"{name}.yaml")
    return spec.with_overrides(material=MaterialSpec.model_validate({**spec.material.model_dump(exclude_unset=True), **material}))


def thesis_spec(name: str, solver: str = "quasi-implicit", **changes):
    """An expression of the library on the Hopper face, in the thesis's model (the
    ``thesis`` material preset: no bending, the hypodermis kept), by the thesis's update unless
    ``solver`` says otherwise."""
    spec = facesim.load_spec(EXPRESSIONS / f"{name}.yaml")
    material = MaterialSpec.model_validate({**spec.material.model_dump(exclude_unset=True), "preset": "thesis", "solver": solver})
    return spec.with_overrides(material=material, mesh=HOPPER_MESH, **{"muscles": "thesis", **changes})


#: Thesis Table 3.1: activated muscles, elapsed seconds for 35 frames, frames per second.
THESIS_31 = {
    "happy": (6, 8.078, 4.33), "sad": (10, 9.753, 3.59), "angry": (7, 6.823, 5.13), "fear": (12, 9.987, 3.50),
    "disgust": (5, 3.873, 9.03), "surprise": (10, 5.615, 6.23), "disgusted_anger": (9, 8.298, 4.22),
    "happy_surprise": (12, 11.691, 2.99),
}
#: Thesis Table 3.2: min, max, average, average deviation, standard deviation (s).
THESIS_32 = {
    "happy": (7.772, 8.134, 7.982, 0.118, 0.134), "sad": (9.705, 9.915, 9.799, 0.063, 0.073),
    "angry": (6.689, 6.851, 6.789, 0.043, 0.053), "fear": (9.847, 10.252, 10.100, 0.100, 0.127),
    "disgust": (3.791, 3.956, 3.884, 0.038, 0.050), "surprise": (5.615, 5.734, 5.692, 0.026, 0.034),
}
#: Thesis Table 3.3: (frames, dt) -> elapsed seconds for happy.
THESIS_33 = {(140, 0.0025): 31.399, (35, 0.01): 8.078, (17, 0.015): 3.754}


def timed(fn, repeats: int) -> list[float]:
    out = []
    for _ in range(repeats):
        start = time.perf_counter()
        fn()
        out.append(time.perf_counter() - start)
    return out


def median(values) -> float:
    return statistics.median(values)


def table(headers: list[str], rows: list[list]) -> str:
    lines = ["| " + " | ".join(headers) + " |", "|" + "|".join("---" for _ in headers) + "|"]
    lines += ["| " + " | ".join(str(c) for c in row) + " |" for row in rows]
    return "\n".join(lines)


def python_json(code: str, env: dict | None = None) -> dict:
    """Run code in a fresh interpreter that prints one JSON object last."""
    result = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, env={**os.environ, **(env or {})},
                            cwd=ROOT, timeout=1200)
    if result.returncode != 0:
        raise RuntimeError(result.stderr[-2000:])
    return json.loads(result.stdout.strip().splitlines()[-1])


def machine() -> str:
    cpu = "unknown CPU"
    if Path("/proc/cpuinfo").exists():
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                cpu = line.split(":", 1)[1].strip()
                break
    import numba
    import scipy

    versions = {"python": platform.python_version(), "numpy": np.__version__, "numba": numba.__version__, "scipy": scipy.__version__}
    for name in ("PyOpenGL", "imageio-ffmpeg"):
        try:
            from importlib.metadata import version

            versions[name] = version(name)
        except Exception:
            pass
    return f"{cpu}, {os.cpu_count()} cores, {platform.system()} {platform.release()}; " + ", ".join(f"{k} {v}" for k, v in versions.items())


# --- the thesis's tables -------------------------------------------------------------

def simulate_seconds(name: str, repeats: int, **changes) -> list[float]:
    spec = thesis_spec(name, **changes)
    model = model_for(spec)
    table_ = activation_table(spec, model.muscles)
    run(model, table_, spec.dt)  # warm: compiled and cached
    return timed(lambda: run(model, table_, spec.dt), repeats)


RENDER_CODE = """
import json, os, sys, time, statistics
import numpy as np, facesim
from facesim.renderer.scene import FaceRenderer
from facesim.renderer.settings import RenderSettings
from facesim.export.output import write_frames
names, size, repeats, backend = {names!r}, {size}, {repeats}, {backend!r}
out = {{}}
renderer = None
for name in names:
    a = facesim.simulate(facesim.load_spec(f"expressions/{{name}}.yaml"){face})
    renderer = renderer or FaceRenderer(a.rest, a.faces, RenderSettings(size, size), backend)
    renderer.render(a.positions[0])
    render, encode = [], []
    for _ in range(repeats):
        t = time.perf_counter(); frames = np.stack(list(renderer.frames(a))); render.append(time.perf_counter() - t)
        t = time.perf_counter(); write_frames(frames, __import__("pathlib").Path("/tmp/facesim-bench.mp4"), "mp4", 25); encode.append(time.perf_counter() - t)
    out[name] = dict(render=statistics.median(render), encode=statistics.median(encode))
print(json.dumps(out))
"""


def table_31(repeats: int, size: int, render_repeats: int) -> tuple[str, dict]:
    names = list(THESIS_31)
    render = python_json(RENDER_CODE.format(names=names, size=size, repeats=render_repeats, backend="auto",
                                            face=THESIS_FACE))
    rows, figures = [], {}
    for name in names:
        muscles, thesis_s, thesis_fps = THESIS_31[name]
        spec = thesis_spec(name)
        sim = median(simulate_seconds(name, repeats))
        r = render[name]
        end_to_end = sim + r["render"] + r["encode"]
        fps = spec.frames / end_to_end
        figures[name] = dict(sim=sim, render=r["render"], encode=r["encode"], fps=fps)
        rows.append([name.replace("_", " "), f"{len(spec.activations)} ({muscles})", f"{sim * 1e3:.2f}",
                     f"{r['render'] * 1e3:.0f}", f"{r['encode'] * 1e3:.0f}", f"{fps:.1f}", f"{thesis_s:.3f}",
                     f"{thesis_fps:.2f}", f"{thesis_s / sim:,.0f}x", f"{fps / thesis_fps:.1f}x"])
    text = table(["expression", "muscles (thesis)", "simulation, 35 frames (ms)", f"render {size}² (ms)",
                  "MP4 encode (ms)", "end-to-end fps", "thesis elapsed (s)", "thesis fps", "simulation speed-up",
                  "fps ratio"], rows)
    return text, figures


def table_32(runs: int) -> str:
    rows = []
    for name, thesis in THESIS_32.items():
        t = np.array(simulate_seconds(name, runs)) * 1e3
        rows.append([name, f"{t.min():.2f}", f"{t.max():.2f}", f"{t.mean():.2f}", f"{np.abs(t - t.mean()).mean():.3f}",
                     f"{t.std(ddof=1):.3f}", " / ".join(f"{v:.3f}" for v in thesis)])
    return table(["expression", "min (ms)", "max (ms)", "average (ms)", "average deviation (ms)",
                  "standard deviation (ms)", "thesis min / max / avg / avg dev / std (s)"], rows)


def table_33(repeats: int) -> str:
    rows = []
    for (frames, dt), thesis in THESIS_33.items():
        t = median(simulate_seconds("happy", repeats, frames=frames, dt=dt))
        rows.append([frames, dt, f"{t * 1e3:.2f}", f"{thesis:.3f}", f"{thesis / t:,.0f}x"])
    return table(["frames", "Δt (s)", "simulation (ms)", "thesis (s)", "speed-up"], rows)


# --- side by side: the two solvers, Numba against NumPy, compilation -----------------

def solvers(repeats: int, names: list[str]) -> tuple[str, dict]:
    """happy by each solver on the thesis's model (the Hopper face), and on the default
    head with and without the skin's bending; how far apart the held apexes are."""
    figures = {}

    def warm_ms(spec, stop_on_inversion=True):
        model = model_for(spec)
        table_ = activation_table(spec, model.muscles)
        run(model, table_, spec.dt, stop_on_inversion)
        return median(timed(lambda: run(model, table_, spec.dt, stop_on_inversion), 3 * repeats)) * 1e3, model.material.substeps

    (slow, slow_steps), (fast, fast_steps) = (warm_ms(thesis_spec("happy", solver)) for solver in ("quasi-implicit", "implicit"))
    figures["the Hopper face"] = dict(quasi=slow, implicit=fast)
    text = table(["happy, 35 frames, warm, the thesis's model", "quasi-implicit, ms (steps per frame)",
                  "implicit, ms (steps per frame)", "ratio"],
                 [["the Hopper face", f"{slow:.2f} ({slow_steps})", f"{fast:.2f} ({fast_steps})", f"{slow / fast:.2f}x"]])
    # without bending the calibrated smile folds at frame 4: timed all the same (the same steps), not stopped
    (flat, _), (bent, _) = (warm_ms(solved_by("happy", bending=kb), stop_on_inversion=False) for kb in (0.0, MaterialSpec().bending))
    figures["the default head"] = dict(implicit=bent, no_bending=flat)
    text += "\n\n" + table(["happy, 35 frames, warm, implicit, one step per frame", "without bending (folds at frame 4), ms",
                              f"with bending (k_b = {MaterialSpec().bending:g}, the default), ms", "ratio"],
                             [["the default head", f"{flat:.2f}", f"{bent:.2f}", f"{bent / flat:.2f}x"]])
    apex_rows = []
    for face, label, reference_spec, fast_spec in (
            ("the default head", "the default head: one step against eight, converged",
             lambda name: solved_by(name, substeps=8, tolerance=1e-8, iterations=2000), solved_by),
            ("the Hopper face", "the Hopper face, the thesis's model: implicit against quasi-implicit",
             thesis_spec, lambda name: thesis_spec(name, "implicit"))):
        apart = {}
        for name in names:
            model, reference, _ = held_apex(reference_spec(name))
            _, fast_apex, _ = held_apex(fast_spec(name))
            largest = np.linalg.norm(reference - model.rest_position, axis=1).max()
            apart[name] = float(np.linalg.norm(fast_apex - reference, axis=1).max() / largest)
        figures[f"apex, {face}"] = apart
        apex_rows.append([label] + [f"{100 * apart[n]:.2f}" for n in names])
    text += "\n\n" + table(["held apex, % of the largest displacement"] + [n.replace("_", " ") for n in names], apex_rows)
    return text, figures


def numba_vs_numpy(repeats: int) -> tuple[str, float]:
    import naive

    spec = thesis_spec("happy")
    model = model_for(spec)
    table_ = activation_table(spec, model.muscles)
    steps = len(table_) * model.material.substeps
    numba_step = median(timed(lambda: run(model, table_, spec.dt), repeats)) / steps
    x, v = model.rest_position.copy(), np.zeros_like(model.rest_position)
    h = spec.dt / model.material.substeps
    numpy_step = median(timed(lambda: naive.step(model, x, v, table_[-1], h), max(3, repeats // 3)))
    ratio = numpy_step / numba_step
    text = table(["one step of happy (468 vertices)", "time per step (µs)"],
                 [["NumPy reference (tests/naive.py)", f"{numpy_step * 1e6:,.0f}"],
                  ["Numba kernels", f"{numba_step * 1e6:,.1f}"], ["ratio", f"{ratio:,.0f}x"]])
    return text, ratio


COMPILE_CODE = """
import json, time
t0 = time.perf_counter()
import facesim
t1 = time.perf_counter()
spec = facesim.load_spec("expressions/happy.yaml"){face}
from facesim.animation.simulate import model_for
from facesim.physics.run import run
from facesim.animation.spec import activation_table
m = model_for(spec); tab = activation_table(spec, m.muscles)
t2 = time.perf_counter(); run(m, tab, spec.dt); t3 = time.perf_counter(); run(m, tab, spec.dt); t4 = time.perf_counter()
from facesim.physics import solver, twins
kernels = twins.variants(solver._simulate)  # the kernel the run ran: the serial twin on a small face
hits = sum(sum(k.stats.cache_hits.values()) for k in kernels)
misses = sum(sum(k.stats.cache_misses.values()) for k in kernels)
print(json.dumps(dict(imports=t1 - t0, first=t3 - t2, warm=t4 - t3, loaded=hits, compiled=misses)))
"""


def compilation(quick: bool) -> tuple[str, dict]:
    """Happy's first call compiling every kernel into an empty cache, then in a fresh
    process loading them. ``quick`` (the test suite's smoke test) skips the compiling
    (a minute of the suite, measured by ``make bench``): two processes on facesim's own
    cache, the second of which must load, not compile, the solver."""
    code = COMPILE_CODE.replace("{face}", THESIS_FACE)
    if quick:
        python_json(code)  # loads the kernels, or compiles them if this code has none yet
        cold, cached = None, python_json(code)
    else:
        with tempfile.TemporaryDirectory() as cache:  # compiled: the shipped kernels left out
            cold = python_json(code, {"NUMBA_CACHE_DIR": cache, "FACESIM_SHIPPED_KERNELS": "0"})
            cached = python_json(code, {"NUMBA_CACHE_DIR": cache})
    rows = [["first call, compiling (empty cache)", "not measured (--quick)" if quick else f"{cold['first'] * 1e3:,.0f}"],
            ["first call in a fresh process, Numba's cache", f"{cached['first'] * 1e3:,.0f}"],
            ["warm call", f"{cached['warm'] * 1e3:,.1f}"],
            ["(importing facesim, for reference)", f"{cached['imports'] * 1e3:,.0f}"]]
    return table(["happy, 35 frames", "ms"], rows), dict(cold=cold, cached=cached)


def fresh_render_wall(repeats: int, size: int = 512) -> tuple[float, list[float], float]:
    """`facesim render expressions/happy.yaml` as a fresh process, caches warm: median
    wall (s), the walls, and the peak resident memory of the runs (MB)."""
    out = Path(tempfile.mkdtemp()) / "happy.mp4"
    command = [str(Path(sys.executable).parent / "facesim"), "render", "expressions/happy.yaml", "-o", str(out), "--force",
               "--size", f"{size}x{size}"]
    subprocess.run(command, cwd=ROOT, capture_output=True, check=True)
    walls = timed(lambda: subprocess.run(command, cwd=ROOT, capture_output=True, check=True), repeats)
    # one more run under a parent of its own, whose only child it is: its maximum resident set
    watch = ("import resource, subprocess, sys; subprocess.run(sys.argv[1:], capture_output=True, check=True); "
             "print(resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss)")
    peak = subprocess.run([sys.executable, "-c", watch, *command], cwd=ROOT, capture_output=True, text=True, check=True)
    return median(walls), walls, int(peak.stdout) / 1024  # KB on Linux


def _installed_facesim(into: Path) -> Path:
    """facesim as a user installs it: a wheel of this checkout built and installed into
    ``into`` (its dependencies are this environment's). Returns the folder to put on
    PYTHONPATH."""
    wheels, site = into / "wheels", into / "site"
    subprocess.run([sys.executable, "-m", "pip", "wheel", "-q", "--no-deps", "-w", str(wheels),
                    str(ROOT)], check=True, capture_output=True)
    (wheel,) = wheels.glob("facesim-*.whl")
    subprocess.run([sys.executable, "-m", "pip", "install", "-q", "--no-deps", "--target", str(site), str(wheel)],
                   check=True, capture_output=True)
    return site


def _timed_render(site: Path, home: Path, out: Path, env: dict | None = None) -> tuple[float, dict[str, float]]:
    """`facesim render expressions/happy.yaml --timings` in a fresh process of the
    installed facesim, with ``home`` as HOME and XDG_CACHE_HOME's parent and no
    NUMBA_CACHE_DIR or FACESIM_CACHE: its wall (s) and its phases."""
    clean = {k: v for k, v in os.environ.items() if k not in ("NUMBA_CACHE_DIR", "FACESIM_CACHE", "NUMBA_CPU_NAME",
                                                               "NUMBA_CPU_FEATURES", "PYTHONPATH")}
    clean.update(HOME=str(home), XDG_CACHE_HOME=str(home / ".cache"), PYTHONPATH=str(site), **(env or {}))
    command = [sys.executable, "-m", "facesim", "render", str(EXPRESSIONS / "happy.yaml"), "-o", str(out), "--force",
               "--timings"]
    home.mkdir(exist_ok=True)
    start = time.perf_counter()
    result = subprocess.run(command, cwd=home, env=clean, capture_output=True, text=True, check=True)
    wall = time.perf_counter() - start
    line = next(line for line in result.stderr.splitlines() if line.startswith("timings: "))
    phases = {name.strip(): float(seconds) for name, seconds in re.findall(r"([A-Za-z ]+) ([0-9.]+) s", line[9:])}
    phases.pop("wall", None)
    return wall, phases


def first_run(cold_runs: int, warm_runs: int, quick: bool) -> tuple[str, dict]:
    """A new user's first `facesim render expressions/happy.yaml`: facesim freshly
    installed from a wheel, a new HOME and XDG_CACHE_HOME each run, no NUMBA_CACHE_DIR
    or FACESIM_CACHE (the kernels that ship compiled count); then the same run again
    with the caches that first run filled; and, once, the first run without the shipped
    kernels (what another architecture or Python pays). Medians; phases from
    ``--timings`` (they overlap: the simulation runs beside the drawing). ``quick``
    (the smoke test): the checkout's facesim, and no compiling run."""
    with tempfile.TemporaryDirectory() as scratch:
        scratch = Path(scratch)
        site = ROOT if quick else _installed_facesim(scratch)  # the smoke test: the checkout, no wheel built
        rows, figures = [], {}

        def measured(label, runs, homes, env=None):
            results = [_timed_render(site, home, scratch / "happy.mp4", env) for home in homes]
            walls = [wall for wall, _ in results]
            names = sorted({name for _, phases in results for name in phases},
                           key=lambda n: PHASE_ORDER.index(n) if n in PHASE_ORDER else len(PHASE_ORDER))
            phases = {name: median([phases.get(name, 0.0) for _, phases in results]) for name in names}
            figures[label] = dict(wall=median(walls), walls=walls, phases=phases)
            rows.append([label, f"{median(walls):.2f}", ", ".join(f"{w:.1f}" for w in walls),
                         ", ".join(f"{name} {seconds:.2f}" for name, seconds in phases.items())])

        cold = [scratch / f"home-{k}" for k in range(cold_runs)]
        measured("first run, new user (shipped kernels)", cold_runs, cold)
        measured("later runs, caches warm", warm_runs, [cold[-1]] * warm_runs)
        if not quick:
            measured("first run without the shipped kernels (compiling)", 1, [scratch / "home-compiling"],
                     {"FACESIM_SHIPPED_KERNELS": "0"})
    return table(["`facesim render expressions/happy.yaml`", "median wall (s)", "runs (s)", "phases (s, medians)"],
                 rows), figures


PHASE_ORDER = ["imports", "kernels", "model", "figure", "GL context", "simulation", "drawing", "encoding"]


def long_clip_memory(short: int, long: int, size: int) -> tuple[str, dict]:
    """Peak resident memory of `facesim render` of happy on the head to MP4, a short clip
    and a long one, each a fresh process under a parent of its own: the long clip is
    simulated into a ring of a few frames (simulate(stream=True)) while it is drawn."""
    folder = Path(tempfile.mkdtemp())
    happy = (ROOT / "expressions" / "happy.yaml").read_text()
    watch = ("import resource, subprocess, sys, time; t = time.perf_counter(); "
             "subprocess.run(sys.argv[1:], capture_output=True, check=True); "
             "print(resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss, time.perf_counter() - t)")
    figures = {}
    for frames in (short, long):
        spec = folder / f"happy{frames}.yaml"
        spec.write_text(re.sub(r"(?m)^frames: .*$", f"frames: {frames}", happy))
        command = [str(Path(sys.executable).parent / "facesim"), "render", str(spec), "-o", str(folder / f"{frames}.mp4"),
                   "--size", f"{size}x{size}"]
        peak, wall = subprocess.run([sys.executable, "-c", watch, *command], capture_output=True, text=True,
                                    check=True).stdout.split()
        figures[frames] = (int(peak) / 1024, float(wall))
    rows = [[f"{frames:,}", f"{peak:.0f}", f"{wall:.1f}"] for frames, (peak, wall) in figures.items()]
    rows.append(["difference", f"{figures[long][0] - figures[short][0]:+.0f}", ""])
    return table(["frames (happy, the head, " + f"{size}², MP4)", "peak resident memory (MB)", "wall (s)"], rows), figures


# --- scaling ---------------------------------------------------------------------------

def scaling(levels: int, repeats: int, plot: Path | None) -> tuple[str, dict]:
    base = load_mesh(HOPPER_MESH)
    muscle_file = load_model(HOPPER_MUSCLES, MuscleFile)
    carried = muscles_as_points(muscle_file, base)
    spec = thesis_spec("happy")
    rows, figures = [], {}
    base_steps = None
    for level in range(levels + 1):
        mesh = subdivide(base, level) if level else base
        model = face_model(mesh, resolve_muscles(carried, mesh, f"level {level}"), spec.material)
        base_steps = base_steps or model.material.substeps
        # a finer mesh takes more sub-steps per frame (facesim.physics.model); keep the number of
        # steps of the default face's 35 frames by simulating fewer frames
        frames = max(4, round(35 * base_steps / model.material.substeps))
        table_ = activation_table(spec.with_overrides(frames=frames), model.muscles)
        run(model, table_[:2], spec.dt, stop_on_inversion=False)
        # one thread and two side by side, alternating, each the median of its runs
        times = {1: [], 2: []}
        for _ in range(repeats if level < 4 else 1):
            for threads in times:
                times[threads] += timed(lambda: run(model, table_, spec.dt, stop_on_inversion=False, threads=threads), 1)
        seconds, both = median(times[1]), median(times[2])
        steps = len(table_) * model.material.substeps
        per = seconds / (steps * model.vertex_count)
        figures[model.vertex_count] = (per, both / (steps * model.vertex_count))
        rows.append([level, f"{model.vertex_count:,}", f"{len(mesh.faces):,}", model.material.substeps, frames,
                     f"{seconds * 1e3:,.1f}", f"{per * 1e9:.0f}", f"{1 / per / 1e6:.2f}", f"{both * 1e3:,.1f}",
                     f"{seconds / both:.2f}x"])
    if plot:
        import matplotlib

        matplotlib.use("Agg")
        import matplotlib.pyplot as plt

        n = np.array(list(figures))
        cost = np.array(list(figures.values())) * 1e9
        fig, ax = plt.subplots(figsize=(6, 4))
        ax.plot(n, cost[:, 0], "o-", label="1 thread")
        ax.plot(n, cost[:, 1], "s-", label="2 threads (wall time per vertex-step)")
        ax.legend()
        ax.set_xscale("log")
        ax.set_xlabel("vertices (default face, Loop-subdivided 0-4 times)")
        ax.set_ylabel("ns per vertex-step")
        ax.set_ylim(bottom=0)
        ax.set_title("facesim: simulation cost per vertex-step")
        ax.grid(alpha=0.3)
        fig.tight_layout()
        fig.savefig(plot, dpi=110)
        plt.close(fig)
    return table(["subdivisions", "vertices", "triangles", "sub-steps per frame", "frames", "happy, 1 thread (ms)",
                  "ns per vertex-step", "million vertex-steps per second", "happy, 2 threads (ms)", "2 threads against 1"],
                 rows), figures


def default_solver_scaling(levels: int, repeats: int, thesis: dict) -> tuple[str, dict]:
    """happy by the default solver (implicit, with bending; the head's calibrated muscles
    carried by position, as any face given with --mesh takes them) on the Hopper face
    Loop-subdivided: its factorised preconditioner's size and time to factorise, and the
    cost per vertex-step on one thread against the thesis's update (``thesis``: the
    scaling table's figures, by vertex count)."""
    from facesim.config import DEFAULT_MUSCLES
    from facesim.face.loading import write_obj
    from facesim.face.muscle_file import carried_text
    from facesim.physics import solver

    base = load_mesh(HOPPER_MESH)
    rows, figures, base_steps = [], {}, None
    with tempfile.TemporaryDirectory() as scratch:
        muscles = Path(scratch) / "face.muscles.yaml"
        muscles.write_text(carried_text(DEFAULT_MUSCLES, base))
        for level in range(levels + 1):
            mesh = Path(scratch) / f"face{level}.obj"
            write_obj(mesh, subdivide(base, level) if level else base)
            spec = facesim.load_spec(EXPRESSIONS / "happy.yaml").with_overrides(mesh=str(mesh), muscles=str(muscles))
            model = model_for(spec)
            steps = model.material.substeps
            base_steps = base_steps or steps
            h = spec.dt / steps
            factorised = median(timed(lambda: solver.rest_preconditioner(model, h), 1))
            factor = model.preconditioner(h)
            blocks = factor.lower_block.shape[0] + factor.upper_block.shape[0] + 2 * model.vertex_count
            megabytes = (factor.lower_block.nbytes + factor.upper_block.nbytes + factor.lower_pivot.nbytes
                         + factor.upper_pivot.nbytes) / 1e6
            frames = max(4, round(35 * base_steps / steps))  # about as many steps as the scaling table's rows
            table_ = activation_table(spec.with_overrides(frames=frames), model.muscles)
            run(model, table_[:2], spec.dt, threads=1)
            seconds = median(timed(lambda: run(model, table_, spec.dt, threads=1), repeats if level < 3 else 1))
            per = seconds / (len(table_) * steps * model.vertex_count)
            versus = thesis.get(model.vertex_count, (float("nan"),))[0]
            figures[model.vertex_count] = dict(blocks_per_vertex=blocks / model.vertex_count, megabytes=megabytes,
                                               factorised=factorised, ns=per * 1e9)
            rows.append([level, f"{model.vertex_count:,}", steps, frames, f"{blocks / model.vertex_count:.0f}",
                         f"{megabytes:,.1f}", f"{factorised:.2f}", f"{seconds * 1e3:,.1f}", f"{per * 1e9:,.0f}",
                         f"{per / versus:.1f}x" if versus == versus else "-"])
    return table(["subdivisions", "vertices", "sub-steps per frame", "frames", "3x3 blocks per vertex in the factor",
                  "factor (MB)", "factorised (s)", "happy, 1 thread (ms)", "ns per vertex-step",
                  "against the thesis's update"], rows), figures


def vertex_orders(level: int, repeats: int) -> tuple[str, dict]:
    """Happy on the Hopper face Loop-subdivided ``level`` times, one thread, in the mesh's own
    vertex order and in facesim's cache order (facesim.physics.model.reordered), and the same for
    the mesh with its vertices shuffled (as an exported or scanned mesh may number them):
    the four models alternating, each the median of its runs."""
    from facesim.physics.mesh import FaceMesh, inverse_permutation
    base = load_mesh(HOPPER_MESH)
    carried = muscles_as_points(load_model(HOPPER_MUSCLES, MuscleFile), base)
    spec = thesis_spec("happy")
    mesh = subdivide(base, level)
    shuffle = np.random.default_rng(1).permutation(mesh.vertex_count)
    meshes = {"the subdivided mesh's own": mesh,
              "shuffled": FaceMesh(mesh.vertices[shuffle], inverse_permutation(shuffle)[mesh.faces])}
    models = {(label, reorder): face_model(m, resolve_muscles(carried, m, label), spec.material, reorder=reorder)
              for label, m in meshes.items() for reorder in (False, True)}
    first = next(iter(models.values()))
    frames = max(4, round(35 * 4 / first.material.substeps))
    table_ = activation_table(spec.with_overrides(frames=frames), first.muscles)
    times = {key: [] for key in models}
    for model in models.values():
        run(model, table_[:2], spec.dt, stop_on_inversion=False)
    for _ in range(repeats):
        for key, model in models.items():
            times[key] += timed(lambda: run(model, table_, spec.dt, stop_on_inversion=False, threads=1), 1)
    steps = len(table_) * first.material.substeps * first.vertex_count
    per = {key: median(t) / steps for key, t in times.items()}
    rows = [[label, f"{per[(label, False)] * 1e9:.0f}", f"{per[(label, True)] * 1e9:.0f}",
             f"{per[(label, False)] / per[(label, True)]:.2f}x"] for label in meshes]
    return table([f"happy, {first.vertex_count:,} vertices, one thread: vertex order", "as numbered, ns per vertex-step",
                  "facesim's cache order, ns per vertex-step", "speed-up"], rows), per


# --- rendering -------------------------------------------------------------------------

RENDER_FLOOR_CODE = """
import json, time, statistics
import numpy as np, facesim
from facesim.renderer.scene import FaceRenderer
from facesim.renderer.settings import RenderSettings
size, repeats, frames = {size}, {repeats}, 35
a = facesim.simulate(facesim.load_spec("expressions/happy.yaml"){face})
r = FaceRenderer(a.rest, a.faces, RenderSettings(size, size), {backend!r})
for p in a.positions[:3]: r.render(p)
ours, floor = [], []
for _ in range(repeats):
    t = time.perf_counter()
    for image in r.frames(a): pass
    ours.append((time.perf_counter() - t) / frames)
    # the floor: the same scene, the same renderer, settings and antialiasing, nothing updated
    t = time.perf_counter()
    for _ in range(frames): r._antialiased(r._drawn((np.zeros(3), [])))
    floor.append((time.perf_counter() - t) / frames)
print(json.dumps(dict(ours=statistics.median(ours), floor=statistics.median(floor), backend=r.backend)))
"""

PROCESSES_CODE = """
import json, time, numpy as np, facesim
from facesim.export.output import render_frames
from facesim.renderer.settings import RenderSettings
spec = facesim.load_spec("expressions/happy.yaml"){face}.with_overrides(frames={frames})
a = facesim.simulate(spec)
out = {{}}
for jobs in (1, 2):
    t = time.perf_counter(); render_frames(a, RenderSettings(512, 512), jobs=jobs); out[jobs] = time.perf_counter() - t
print(json.dumps(out))
"""


def rendering(sizes: list[int], repeats: int, frames: int) -> tuple[str, dict]:
    rows, figures = [], {}
    for backend in ("egl", "osmesa"):
        for size in sizes:
            r = python_json(RENDER_FLOOR_CODE.format(size=size, repeats=repeats, backend=backend, face=THESIS_FACE))
            figures[(backend, size)] = r
            rows.append([backend, f"{size}²", f"{r['ours'] * 1e3:.1f}", f"{r['floor'] * 1e3:.1f}", f"{r['ours'] / r['floor']:.2f}"])
    text = table(["backend", "size", "facesim per frame (ms)", "bare draw floor (ms)", "ratio"], rows)
    processes = python_json(PROCESSES_CODE.format(frames=frames, face=THESIS_FACE))
    text += "\n\n" + table([f"{frames} frames at 512², processes", "wall (s)", "frames per second"],
                           [[jobs, f"{t:.2f}", f"{frames / t:.1f}"] for jobs, t in processes.items()])
    figures["processes"] = processes
    return text, figures


HEAD_CODE = """
import json, statistics, tempfile, time
from pathlib import Path
import numpy as np, facesim
from facesim.geometry import _vertex_normals
from facesim.export.output import write_frames
from facesim.renderer.scene import FaceRenderer
from facesim.renderer.settings import RenderSettings
from facesim.animation.simulate import model_for
from facesim.physics.run import run
from facesim.animation.spec import activation_table
size, repeats, backend = {size}, {repeats}, {backend!r}
spec = facesim.load_spec("expressions/happy.yaml")
model = model_for(spec)
table = activation_table(spec, model.muscles)
run(model, table, spec.dt)
sim = []
for _ in range(3 * repeats):
    t = time.perf_counter(); run(model, table, spec.dt); sim.append(time.perf_counter() - t)
a = facesim.simulate(spec)
t = time.perf_counter(); figure = a.figure; build = time.perf_counter() - t
r = FaceRenderer.of(a, RenderSettings(size, size), backend)
# the floor's vertex buffers: the same geometry, computed before the clock starts
buffers = []
for k in range(a.frames):
    x = figure.positions(a.positions[k], a.jaw_at(k))
    _vertex_normals(x, r._faces, r._normals)
    buffers.append([np.hstack([x[rows], r._normals[rows], attribute]).astype(np.float32) for _, rows, attribute in r._parts])
for k in range(3): r.frame(a, k)
import importlib.util
from facesim.renderer.backend import LIT_SHADER
# facesim's lit shader, and pyrender's own (read from its package: a test dependency)
programs = dict(lit=LIT_SHADER, pbr=Path(importlib.util.find_spec("pyrender").submodule_search_locations[0]) / "shaders" / "mesh.frag")

def floor_frame(data, programs):
    r.lit_shader = programs
    r._antialiased(r._drawn((np.zeros(3), [(primitive, d) for (primitive, _, _), d in zip(r._parts, data)])))

floor_frame(buffers[0], programs["pbr"])
ours, floor, pbr, encode = [], [], [], []
for _ in range(repeats):
    t = time.perf_counter(); frames = np.stack(list(r.frames(a))); ours.append((time.perf_counter() - t) / a.frames)
    for times, which in ((floor, "lit"), (pbr, "pbr")):
        t = time.perf_counter()
        for data in buffers:
            floor_frame(data, programs[which])
        times.append((time.perf_counter() - t) / a.frames)
    r.lit_shader = programs["lit"]
    t = time.perf_counter(); write_frames(frames, Path(tempfile.mkdtemp()) / "head.mp4", "mp4", 25); encode.append(time.perf_counter() - t)
r.close()
# end to end as `facesim render` runs it: simulated in the background while drawn, each frame encoded while the next draws
from facesim.export.output import write_animation
e2e = {{}}
for key, settings in (("fps", RenderSettings(size, size)), ("fps_supersample", RenderSettings(size, size, supersample=True)),
                      ("fps_plain", RenderSettings(size, size, antialias=False))):
    with FaceRenderer.of(a, settings, backend) as renderer:
        walls = []
        for _ in range(repeats + 1):
            path = Path(tempfile.mkdtemp()) / "e2e.mp4"
            t = time.perf_counter(); write_animation(facesim.simulate(spec, background=True), path, settings, renderer=renderer)
            walls.append(time.perf_counter() - t)
        e2e[key] = a.frames / statistics.median(walls[1:])
m = statistics.median
print(json.dumps(dict(sim=m(sim), build=build, ours=m(ours), floor=m(floor), pbr=m(pbr), encode=m(encode), frames=a.frames,
                      vertices=len(figure.rest), triangles=len(figure.triangles), simulated=model.vertex_count,
                      backend=r.backend, **e2e)))
"""


OVERLAP_CODE = """
import json, statistics, tempfile, time
from pathlib import Path
import facesim
from facesim.export.output import write_animation
from facesim.renderer.scene import FaceRenderer
from facesim.renderer.settings import RenderSettings
size, repeats = {size}, {repeats}
root = Path(tempfile.mkdtemp())
spec = facesim.load_spec("expressions/happy.yaml")
a = facesim.simulate(spec)
settings = RenderSettings(size, size)
with FaceRenderer.of(a, settings, "auto") as renderer:
    walls = {{False: [], True: []}}
    for k in range(repeats + 1):
        for background in walls:
            t = time.perf_counter()
            write_animation(facesim.simulate(spec, background=background), root / f"{{k}}-{{background}}.mp4", settings,
                            renderer=renderer)
            walls[background].append(time.perf_counter() - t)
sim = statistics.median([facesim.simulate(spec).seconds for _ in range(repeats)])
print(json.dumps(dict(vertices=a.model.vertex_count, frames=a.frames, sim=sim, after=statistics.median(walls[False][1:]),
                      overlapped=statistics.median(walls[True][1:]))))
"""


def overlap(size: int, repeats: int) -> tuple[str, dict]:
    """Happy on the default head written to MP4 as `facesim render` does, the simulation
    run first and then drawn, against the simulation run in the background while its
    frames are drawn and encoded (facesim.animation.simulate), alternating in one process, renderer
    warm."""
    f = python_json(OVERLAP_CODE.format(size=size, repeats=repeats))
    rows = [["the default head", f"{f['vertices']:,}", f["frames"], f"{f['sim'] * 1e3:,.0f}", f"{f['after'] * 1e3:,.0f}",
             f"{f['overlapped'] * 1e3:,.0f}", f"{f['after'] / f['overlapped']:.2f}x"]]
    return table([f"happy to MP4 at {size}²", "simulated vertices", "frames", "simulation alone (ms)",
                  "simulated, then drawn and encoded (ms)", "drawn and encoded as it is simulated (ms)", "speed-up"],
                 rows), f


def head(sizes: list[int], repeats: int) -> tuple[str, dict]:
    """The default head: simulation, rendering against the bare floor, end to end."""
    rows, figures = [], {}
    for size in sizes:
        h = python_json(HEAD_CODE.format(size=size, repeats=repeats, backend="egl"))
        figures[size] = h
        rows.append([f"{size}²", f"{h['sim'] * 1e3:.1f}", f"{h['ours'] * 1e3:.1f}", f"{h['floor'] * 1e3:.1f}",
                     f"{h['ours'] / h['floor']:.2f}", f"{h['pbr'] * 1e3:.1f}", f"{h['pbr'] / h['floor']:.2f}x",
                     f"{h['encode'] * 1e3:.0f}", f"{h['fps']:.1f}", f"{h['fps_supersample']:.1f}", f"{h['fps_plain']:.1f}"])
    h = figures[sizes[-1]]
    text = table(["size", "happy, 35 frames, simulation (ms)", "facesim per frame (ms)", "bare draw floor (ms)",
                  "ratio", "the floor with pyrender's PBR shader (ms)", "its cost against facesim's lit shader",
                  "MP4 encode alone (ms)", "end-to-end fps", "end-to-end fps, --supersample",
                  "end-to-end fps, --no-antialias"], rows)
    text += (f"\n\nThe head draws {h['vertices']:,} vertices and {h['triangles']:,} triangles ({h['backend']}); "
             f"its skin is simulated on {h['simulated']} vertices (facesim.face.head). The floor uploads the same "
             "vertex buffers, computed before the clock starts, and renders the same scene with the same renderer "
             "and antialiasing: "
             "facesim's frame adds the skin's interpolation (facesim.face.figure), the jaw, the eyelid contact and the "
             "normals, computed for each frame on a second thread while the frame before it draws, which is also "
             "where each drawn frame is filtered while the next one draws (FaceRenderer.frames, as `facesim render` "
             f"draws an animation). Building the head's figure the first time in a process: {h['build']:.2f} s (its skin "
             "weights read from facesim's on-disk cache; solving for them takes about 1.2 s, once per machine). "
             "Antialiasing filters each frame along its edges (facesim.renderer, an FXAA-style pass); --supersample "
             "renders at twice the size and averages, 4 samples per pixel. Simulation: median of warm "
             f"runs; render and encode: medians of {repeats}; end-to-end fps: 35 frames over the wall time of "
             "simulating and writing the MP4 as `facesim render` does (frames stream to the encoder while the next "
             "renders), renderer warm, median of the runs after the first.")
    return text, figures


PROFILE_TERMS = ["springs (eq. 3.6)", "edge repulsion (eq. 3.7)", "bending", "damping (eq. 3.10)", "hypodermis and rig drive",
                 "muscles (eq. 3.1-3.4, 3.21-3.25)", "all force terms (`solver._forces`)",
                 "one conjugate-gradient product A p", "the preconditioner, applied once"]


def _looped():
    """A compiled loop over one kernel, so a profile's figures carry no call overhead."""
    from numba import njit

    from facesim.physics import bending, damping, muscle_forces, repulsion, solver, springs, tissue

    @njit
    def looped(which, repeats, model, xp, control, work, forces, krylov, h):
        for _ in range(repeats):
            if which == 0:
                springs._spring_forces(model, xp, forces)
            elif which == 1:
                repulsion._edge_repulsion_forces(model, xp, forces)
            elif which == 2:
                bending._bending_forces(model, xp, control, forces)
            elif which == 3:
                damping._damping_forces(model, forces)
            elif which == 4:
                tissue._tissue_forces(model, xp, control, forces)
            elif which == 5:
                muscle_forces._muscle_forces(model, xp, control, work, forces)
            elif which == 6:
                solver._forces(model, xp, control, work, forces)
            elif which == 7:
                solver._system_product(model, forces, h, krylov.p, krylov.q)
            else:
                solver._precondition(krylov, krylov.r, krylov.z)
    return looped


def profile(repeats: int) -> tuple[str, dict]:
    """Per step, each term's kernel and the implicit step's parts, on happy at frame 12 of the
    default head and of the Hopper face (the thesis's model, implicit), and the conjugate
    gradients' iterations per step over the 35 frames."""
    from facesim.physics import layout, rig_control, solver

    looped = _looped()
    columns, figures = {}, {}
    for label, spec in (("the default head", solved_by("happy")), ("the Hopper face, the thesis's model",
                                                                   thesis_spec("happy", solver="implicit"))):
        model = model_for(spec)
        arrays, n, h = model.arrays, model.vertex_count, spec.dt / model.material.substeps
        factored = arrays.bending > 0
        factorised = median(timed(lambda: solver.rest_preconditioner(model, h), 3)) if factored else 0.0
        factor = model.preconditioner(h)
        table_ = activation_table(spec, model.muscles)
        state = layout.State(model.rest_position.copy(), np.zeros((n, 3)))
        control = rig_control.control(arrays, table_[0])
        work, forces, xp = layout.workspace(arrays), layout.forces(arrays), np.empty((n, 3))
        krylov = solver.Krylov(*(np.empty((n, 3)) for _ in range(5)), np.empty(3 * n), factor)
        iterations = []
        for frame, row in enumerate(table_):
            control.activation[:] = row
            rig_control._rig_control(arrays, control)
            for _ in range(model.material.substeps):
                iterations.append(solver._implicit_step(arrays, state, control, h, xp, work, forces, krylov))
            if frame == 12:
                snapshot = state.x.copy(), state.v.copy(), control.activation.copy()
        x, v, activation = snapshot
        control.activation[:] = activation
        rig_control._rig_control(arrays, control)
        solver._predict(arrays, layout.State(x.copy(), v.copy()), control, h, xp)
        solver._forces(arrays, xp, control, work, forces)
        solver._jacobi(arrays, forces, h, krylov.diagonal)
        krylov.r[:] = forces.force
        krylov.p[:] = v
        times = []
        for which in range(len(PROFILE_TERMS)):
            looped(which, 1, arrays, xp, control, work, forces, krylov, h)
            count = 50 * repeats
            times.append(median(timed(lambda: looped(which, count, arrays, xp, control, work, forces, krylov, h), 3)) / count)
        columns[label] = [f"{t * 1e6:,.1f}" for t in times] + [
            f"{np.median(iterations):.0f} (at most {max(iterations)})",
            f"{factorised * 1e3:,.0f} ({9 * (factor.lower_block.shape[0] + factor.upper_block.shape[0]) + 18 * factor.order.size:,} entries in 3x3 blocks)"
            if factored else "Jacobi: none"]
        figures[label] = dict(zip(PROFILE_TERMS, times), iterations=float(np.median(iterations)))
    rows = [[name] + [columns[label][k] for label in columns] for k, name in
            enumerate(PROFILE_TERMS + ["conjugate-gradient iterations per step (median)",
                                       "the rest system factorised, once per model and step size (ms)"])]
    return table(["per step, µs (happy, frame 12)"] + list(columns), rows), figures


#: The suite is not run by this script (it runs this script's smoke test): its wall time from
#: a fresh clone, as CI measured it (`time .ci/run`), is recorded here when it changes.
SUITE_MEASURED = "5 min 55.5 s, 5 min 54.6 s, 5 min 59.9 s, 6 min 2.8 s and 6 min 9.6 s (five CI runs of 2026-12-08, pytest 345, 344, 349, 354 and 359 s; not measured by this script): at the target, not reliably under it"

ANALYSIS = """### Where the targets stand: the missed ones and what would close them, and how the others were met

The per-step profile above (each kernel looped in compiled code, so no call overhead) names
where a step's time goes. **The machine moves the figures more than the code does.** This
run is on an AMD EPYC (Zen 4, 2 cores) whose kernel runs DAMON (`kdamond`) with a scheme
that pages out memory it finds cold, the page cache included, and samples every page's
accessed bit twice a second. This run (21:15) and the one before it (21:05), minutes
apart with the same code, gave the Hopper face's happy 17.4 and 17.9 ms by the thesis's
update, the profile's springs 26.2 and 49.6 µs a step, the fresh render 2.71 and 3.19 s
and `prange` 1.67x and 1.66x; the quiet run of 19:07 with the simulation code before
tonight's vertex order, 11.8 ms, 21.8 µs, 2.47 s and 1.84x. Earlier tonight three runs
within an hour with the same simulation code gave happy 16.3, 17.7 and 11.8 ms and the
fresh render 3.49, 2.95 and 2.47 s; the same fresh-render measurement run alone
between the first two took 2.62 s (median of five) and, a minute later, 3.05 s. On 2026-12-02 the runs were on
an Intel Xeon. Changes are therefore measured side by side (the old and the new code
alternating, in one process or in alternating fresh processes), not across runs of this
script.

- **Night (2026-12-03): the last two means of the issue's point 3, a cache-friendly
  vertex order and rendering overlapped with the simulation.**
  - A mesh of at least 4,000 vertices is simulated in a vertex order of its own
    (facesim.physics.model.reordered): reverse Cuthill-McKee on its edge graph
    (scipy.sparse.csgraph), the springs, triangles and hinges sorted by their first vertex
    in it, each vertex's neighbours and ring in their sequence; positions, NPZ files and
    messages keep the mesh's numbering (tests/test_model.py, which also simulates the
    Hopper face both ways: the same motion to 1e-6 cm). The vertex-order table above, at
    27,614 vertices on one thread: 1.00x in this run on the subdivided mesh, whose own
    order is already local (1.12x in the run before; 300 -> 274 ns when first measured),
    and 1.68x on the same mesh with its vertices shuffled, as an exported or scanned mesh
    may number them (1.99x in the run before, 422 -> 267 ns first). With two threads it
    gains more: 706 -> 540 ms (below, `prange`).
  - `facesim render` simulates on a thread of its own and draws each frame as soon as it
    is simulated (facesim.animation.simulate: `simulate(background=True)`, `Animation.ready`); the
    same bits as a simulation run first, a divergence still fails the render at its frame
    with nothing written, a failed render stops the simulation (tests/test_simulation.py).
    Only where Numba's threading layer lets two threads start parallel loops at once
    (OpenMP, TBB; its own workqueue, the fallback without libgomp, stops the process),
    and only for a face simulated on one thread: a mesh of 4,000 vertices or more wants
    both cores, which the renderer (llvmpipe's threads, the frames' preparation, the
    encoder) already keeps busy. Measured side by side in one process on the Hopper face
    subdivided twice (6,990 vertices, happy to MP4 at 512²): 891 ms simulated first
    against 1,271 overlapped with the simulation on two threads, 1,103 against 1,268 on
    one. On the head 1,035 -> 988 and 1,048 -> 1,013 ms by hand, 1,017 -> 1,022 and 968
    -> 1,026 in the overlapped-render table of the run before and of this one: its
    simulation is 20-30 ms of a second, less than this machine's noise. On a machine with
    cores to spare the overlap would pay more; on this one it is worth at most the
    head's simulation, and it is kept because it costs nothing there either.
  - Noticed and left: the Hopper face subdivided twice folds 2-4 of its 13,632 triangles at
    happy's apex, whichever vertex order and material: slivers of the mouth's slit at its
    inner corners (0.0003 cm² against a median 0.0135), hidden between the lips. The
    scaling table simulates on through them, as before.

- **Late evening (2026-12-03): a fresh `facesim render` 3.02 -> 2.63 s (medians of six
  alternating fresh processes, the commit before against after).** Four changes to what
  a fresh process does besides drawing, each measured:
  - pyrender is imported without its on-screen viewer (facesim.renderer.scene.offscreen_pyrender):
    its `__init__` imports the viewer and with it pyglet's windows and GL bindings,
    150-180 ms, for a window facesim never opens (pyrender imported after trimesh 251-317
    ms, without the viewer 96-157). A stand-in module takes the viewer's place during the
    import only; a later `import pyrender.viewer` gets the real one (tests/test_head.py).
  - The implicit step's preconditioner is kept on disk (facesim.cache), keyed by every
    array of the model, the step and facesim's code: factorising took 47 ms of a fresh
    render and loading the two kernels it runs (the force terms and the system's entries,
    1.3 MB of compiled code) 177 ms more. The cache keeps a name's latest entries only,
    so versions and faces do not pile up (tests/test_cache.py).
  - A renderer closes without the full garbage collection pyrender's delete ends with:
    112-125 ms at the end of every render of the head.
  - YAML is read by libyaml's safe loader: the head's muscle file 36.8 -> 5.2 ms.
  Measured and left: Numba's first dispatch in a process (its typing set up, 0.35-0.6 s
  with LLVM's), loading the solver's compiled kernels (60 ms), importing Numba (0.25-0.33
  s), trimesh with SciPy's optimize module (0.45 s, imported by pyrender's mesh module),
  the head's figure (72 ms, spread over many small steps), the GL context (73 ms) and
  first shaders (149 ms), and 35 frames at 21-25 ms, during which both cores are busy
  (1.65-1.71 cores: llvmpipe's rasteriser threads, its vertex work on the calling thread
  and the next frame's preparation).


- **This evening (2026-12-03): the head's preconditioner by blocks, an animation's frames
  drawn two in flight, the muscles' back-projection inlined.**
  - The implicit step's preconditioner, the rest system's LU factors (facesim.physics.solver),
    took two thirds of the head's step: two triangular solves entry by entry, 170 µs each
    time and about four times a step. The vertices are now put in a minimum-degree order
    of their own graph with each vertex's three coordinates together, so that the factors
    are made of 3x3 blocks, and the solves run block by block: 55-70 µs (the profile's
    "applied once" 65.0 µs in this run, 54.0 in the quiet one, 173.1 this afternoon), the same 180,000 entries.
    Happy on the head 55 -> 31 ms side by side in one process, the positions the same to
    4e-15 cm; 20.6 ms in this evening's last run against 36.1 in this afternoon's.
    Factorising takes a few ms more, once per model and step (31-56 ms; since tonight
    read from facesim's cache instead). Tried and not kept: the solves entry
    by entry by rows instead of columns (310 µs), float32 values or int32 indices (no
    gain).
  - An animation's frames are drawn two in flight (`FaceRenderer.frames`, what `facesim
    render` and this script's frame timings use): each frame's vertex arrays are
    computed on a second thread while the frame before it draws, and each drawn frame is
    filtered there while the next one draws, where llvmpipe's vertex work on the calling
    thread left a core idle. The same bytes (tests/test_head.py draws look_left, and the
    wireframe with the muscles' arrows, both ways, and fails when the two frames share one
    set of arrays); side by side in one process, the head 16.9 -> 13.1 ms a frame at 256²
    and 21.1 -> 18.5 at 512², the mask 4.2 -> 3.3.
  - The muscles' back-projection (eq. 3.22-3.25) is inlined into their loop, where a call
    per region vertex handed over the ring's arrays: the muscles at frame 12 of happy,
    looped, 99.6 -> 91.7 ns a vertex on the Hopper face, 85.9 -> 71.4 at 27,614 vertices
    on one thread and 46.3 -> 37.4 on two. Tried and not kept: inlining the links'
    helpers, the falloff and the frame's point (nothing measured), inlining `_set_link`
    into the parallel loops (it broke the step: Numba drops writes made there through a
    tuple's arrays, and the head's happy inverted a triangle at frame 26), and a lone
    wedge's direction taken without its weight (slower).

- **Rendering (2026-12-03, afternoon).** Three changes to how facesim drives pyrender,
  each drawing the same pixels (max difference 0), each measured side by side in one
  process on the head at 512² (facesim.renderer): the lit shader loops over the scene's
  two lights as a constant compiled in (`DIRECTIONAL_LIGHTS`), not pyrender's uniform
  count, which Mesa runs under a mask of the pixels still in the loop (31.6 -> 28.8 and
  34.4 -> 27.4 ms a frame); the programs set a uniform only when its value changes,
  where pyrender sets all of them before each of the head's nine parts, 162 calls a
  frame through PyOpenGL (25.7 -> 24.4 ms; at 128² 16.3 -> 14.7); and a frame drawn with
  one sample a pixel is read where it was drawn, without the blit into pyrender's second
  framebuffer (29.1 -> 27.4 and 25.8 -> 24.4 ms); and the edge filter takes each pixel's
  luma once, where it took nine (1.51 -> 0.95 ms a frame, the same bytes over 56 frames
  of four expressions). Lines have no normals: the shader turns them to the camera as
  pyrender's does, where the fixed loop had drawn the muscle arrows black (a test
  compares them with pyrender's, tests/test_head.py). Where the frame's time goes now
  (512², one process): drawing and reading back about 23 ms, of which the skin's
  shading is about 9 (the same frame with a flat shader: 13.6 against 25.1 ms) and a
  fixed 10-12 ms at any size (128²: 12-17 ms a frame), the draw calls' vertex work and
  pyrender's Python; the skin carried from the simulated mesh 1.1 ms, the edge filter
  1.0, the normals and vertex arrays 0.9. Tried and not kept: `gc.freeze()` after
  the renderer is built (within noise; a full collection here takes 100 ms, but they
  are rare), x264 with fewer threads beside llvmpipe (within noise).

- **Vector lanes for the thesis's update (2026-12-03).** The springs' and the pairs' loops
  were scalar: they read the ends' positions through an index, and LLVM declined them
  (its remarks, read with `-pass-remarks-analysis=loop-vectorize`: "too many memory
  checks needed"; it checks every pair of arrays it cannot prove apart before
  vectorising, and an array reached through a tuple is one it cannot prove apart). The
  thesis's update now gathers the ends and corners into rows first and then runs a loop
  that reads and writes rows alone, every array an argument of its own
  (springs._spring_tensions, repulsion._repulsion_corners): LLVM vectorises it, 8 doubles
  a lane ("vectorized loop (vectorization width: 8)"). Side by side in one process, one
  thread: at 27,614 vertices the springs 56 -> 41 ns a vertex and the edge repulsion
  168 -> 97 (the triangles' loop alone about 6 ns a triangle against 36 scalar); on the
  Hopper face 60 -> 45 and 129 -> 51; whole runs of happy, the Hopper face 25.2 -> 21.7
  ms and 27,614 vertices 454 -> 367 ns a vertex-step (1,944 -> 1,569 ms). The implicit
  step's loops, which also write the links of K, stay scalar and read the positions where
  they are: a gathering pass of their own made them slower (springs 68 -> 84 ns a
  vertex), so they keep the old form (within this machine's noise of it).
- **Simulation, 2 ms for happy on the Hopper face.** Not met: 17.4 ms by the thesis's
  update in this run and 17.9 in the one before (11.8 in the quiet run of 19:07; 16.3 and
  17.7 in the two runs before that, in a slow hour; 12.8
  and 12.0 in this evening's two; 12.4, 13.8 and 18.0 this afternoon), four steps a frame, 140 steps of 80-130 µs; the implicit solver takes
  one step a frame, but its step is the force terms, their links of K (a scalar loop of
  their own) and about eight conjugate-gradient iterations, each a product over the links
  about as costly as the springs and the repulsion together (the profile). 2 ms is 14 µs
  per step of the thesis's update, 30 ns per vertex-step: below what the springs' loop
  alone costs written as the plainest serial loop (8.6 ns a spring, 2.8 springs a vertex,
  measured here). A step of the 468-vertex face also starts about 33 parallel regions
  (one per parallel loop, one per active muscle), 1.2 µs each on one thread here (a
  one-line loop over 468 entries, against 0.06 µs compiled serially; 0.78 µs with one
  thread and 1.22 with two measured tonight, 0.04 serially). They are not what
  the step pays for: the muscles' region loops fused into one parallel loop for all the
  muscles (a step then starts some 19 fewer) measured the same side by side in one
  process, happy on the Hopper face 16.45 against 16.39 ms on one thread, on the head
  43.5 against 44.6 ms (2026-12-03; not kept). What would close it: a model with less
  work per vertex-step (the muscles' flood fills and back-projection, 35 µs of the step,
  redone at every step because the thesis's regions move with the skin) and the product
  over the links gathered into rows as the springs' loop now is. Not fewer iterations by the head's
  preconditioner: the Hopper face's system at rest factorised (60,275 entries) made happy
  26.6 ms against Jacobi's 22.0 (2026-12-02), each iteration's two triangular solves
  costing more than the iterations they save.
- **10 million vertex-steps per second per core at 28k vertices.** Not met: 3.80 million
  in this run (263 ns per vertex-step at 27,614, the scaling table; 3.63 million in the
  run before; 4.55 million, 220 ns, in the quiet run of 19:07; 3.01 and 3.41 million
  in tonight's two runs before it, in a slow hour; 3.45 and 4.11 million in this
  evening's two runs, with the back-projection inlined; 3.7-3.9 million over three
  runs this afternoon), 2.9 million (348 ns) in this morning's with the same
  simulation code (2.7 million, 373 ns, before the vector
  lanes), 7.1-7.5 million on the Xeon on 2026-12-02 (134-141 ns). Profiled
  here after the vector lanes (2026-12-03, 27,614 vertices, happy at frame 12, one
  thread, per vertex-step, the range of three runs in three processes): the muscles
  75-164 ns (their frame 7; the flood fills of section 3.3 and the pull with its
  back-projection of eq. 3.22-3.25 the rest, about 0.5 region vertices per vertex; the
  most variable term here), the edge repulsion 50-82 (its triangles' loop 16, the
  scatter to the vertices and the sum 24, the gathering the rest), the springs 28-31
  (their loop 3.6, the scatter and the sum 24), the hypodermis 3-4.5, the prediction
  2. Profiled on the Xeon on 2026-12-02: the muscles 47 ns (frame 4.5,
  fills 11, pull 25), the edge repulsion 42, the springs 26. Changes of 2026-12-02: the
  muscles' frame takes its atan2 without branches (facesim's own, numerics._atan2,
  NumPy's to 4e-15: 11 -> 4.5 ns a vertex), the back-projection tests each wedge by
  signs before dividing (69 -> 59 ns a region vertex), and a vertex's force and
  stiffness scatter side by side (36.0 -> 33.3 ns). Tried and not kept: the
  back-projection's edge angles by that atan2 (the pull 4 times slower: the call is then
  not inlined), the back-projection without branches (93 ns against 69), the kernels
  compiled without `parallel` (195 ns against 141), Intel's SVML (llvmlite here is not
  built for it); earlier, each vertex gathering its springs from its one-ring (20 ns
  against 13). A reverse Cuthill-McKee order, within 3% when first tried, is now built
  (the vertex order, first bullet and its table): about a tenth on the subdivided mesh,
  whose own order is already local, and robustness to a mesh numbered any old way. **Not
  memory alone:** where a mesh's arrays fit in the caches the step still costs 128-210 ns
  at 6,990 vertices and 138-171 ns at 1,790 over this evening's five runs (128 and 138 in
  this one), 1.3 to 2 times the 100 ns that 10 million a second allows; the springs and the edge repulsion together,
  looped on one thread tonight, took 77 ns a vertex at 1,790 and 85 at 27,614, so a
  gathering by blocks that kept their per-link rows in the first-level cache would save at
  most that tenth. Every index of the model in int32 instead of int64, side by side in
  one process tonight (one thread, happy): 27,614 vertices 817 -> 743 ms (-9%), the
  Hopper face 11.6 -> 13.3 ms (+14%, nine runs each, 11.5-12.4 against 13.0-15.3); not
  kept. What would close it: the
  muscles are now the limit. The thesis's regions kept while the skin under them moves
  less than a tolerance (the fills), the pull's back-projection gathered by rows as the
  pairs' loop now is, the scatters to the vertices (scalar, about half of each link
  term now) fused into one for the springs, the pairs and the hinges. Not float32: the
  springs' vector loop in float32 took 2.98 ns a vertex against 3.17 in float64 at
  27,614 vertices (one process, one thread, 2026-12-03; g within 1e-6 of float64's), the
  loop being bound by its memory, not its lanes, and the scalar scatters and fills
  around it would not change.
- **`prange`, 2 threads against 1: 1.67x in this run at 27,614 and 1.66x in the one
  before, short of 1.7x (1.77x at 6,990 and 1.92x at 109,758 in this run); met at 1.84x in
  the quiet run of 19:07, 1.77x and 1.78x in the two before it. Side by side in one process
  at 27,614 vertices (five alternating runs each, tonight), the vertex order raised it:
  the mesh's own order 1,024 ms on one thread and 706 on two (1.45x), facesim's cache order
  933 and 540 (1.73x); so this run's figure is the hour's, not the order's. 1.60x and 1.42x in this
  evening's two runs and 1.49-1.74x over four of the afternoon's, with the same step; met on the Xeon
  (1.71x at 27,614 on 2026-12-02).** Alternating one thread and two in one process
  tonight, the two-thread runs of the same work took 447-759 ms against 890-1,088 for one
  (2.0-2.2x when the second core was free, 1.3-1.5x when not); with libgomp's threads
  sleeping instead of spinning between loops (`OMP_WAIT_POLICY=passive`) 1.5x, pinned
  to cores (`OMP_PROC_BIND`) no different. The springs, the edge repulsion, the
  bending, the muscles' flood fills (the muscles split by fixed slices,
  muscle_forces._find_regions) and each muscle's region loop run on every core for a mesh of
  at least 4,000 vertices (facesim.config.PARALLEL_FROM), scattering by fixed slices into
  buffers of their own so the bits do not depend on the thread count
  (tests/test_kernels.py). Profiled on the Xeon at 27,614 vertices: springs 1.77x,
  repulsion 1.99x, muscles 1.78x, the whole quasi-implicit step 1.92x. Profiled here
  before the vector lanes (2026-12-03, happy at frame 12, one thread and two): springs
  39 -> 28 ns a vertex (1.40x), edge repulsion 103 -> 65 (1.59x), muscles 74 -> 50
  (1.49x), the whole step 307 -> 179 (1.71x); the whole run of five frames 1.59x. With
  the vector lanes the arithmetic a core does shrank, and the scatters and gathers,
  bound by memory the two cores share, are a larger part of the step; the ratio was
  1.58x in this script's run before them and 1.49x after, which this machine's noise
  between runs accounts for: the same simulation code gave 1.74x in a run this afternoon. What would raise
  it: the same fused scatter, which reads and writes each vertex's buffers once. The 468-vertex faces run their loops on one thread,
  where a parallel region's start outweighs its share of the step; during a render
  llvmpipe already runs on both cores.
- **Compiling, measured apart.** Numba hands a parallel loop every tuple its body names,
  whole; the model's 67 fields cost each loop about 3 s of compiling (a one-line loop:
  3.9 s against 1.0 with its array taken out first). Since 2026-12-03 each term takes
  out what it reads before its loop (facesim.physics): every kernel compiled in 143 s ->
  79 s on this machine, the test suite from a fresh clone 954 -> 717 s. A kernel taking
  the model still costs about 0.4 s more to compile than one taking a few arrays
  (measured on a one-line kernel: 0.70 s against 0.28), about 13 s of the whole over the
  32 kernels that take it. Numba files compiled kernels by their file's directory, so a
  second copy of the same code (a wheel in a virtual environment, a CI clone) compiled
  everything again; facesim's own cache locator files them by a hash of the code and the
  package's name instead (facesim.config), and a copy elsewhere now loads them (a fresh
  render from a copy: 87 s -> 2.7 s; tests/test_cache.py).
- **`make test` from a fresh clone in 6 minutes (setup included; the Debian packages
  installed, facesim's user cache as this machine's earlier runs left it): at the target,
  not reliably under it: 5 min 55.5 s, 5 min 54.6 s, 5 min 59.9 s, 6 min 2.8 s and 6 min
  9.6 s (pytest 345, 344, 349, 354 and 359 s), 2026-12-08.** Seven CI runs the day before
  took 7 min 3 s to 7 min 37 s; after the first four of the changes below 6 min 8.6 s and
  6 min 8.2 s, then the five above, the last two with the setup's two halves side by side
  too: from 5 s under the target to 10 s over it, this machine's noise between runs (the
  seven varied by 34 s). Each measured side by side: the venv's packages installed by uv, the same
  versions pip chose (the setup 22.7 -> 9.4 s, and 6.5 s with the tests' npm packages
  installed beside them, make -j2); the command-line tests' fork server
  importing a render's modules before it forks, and MediaPipe's face mesh in a second
  server for the commands that read faces in images, which import it first (the
  command-line, faults, README, photo and capture modules 237 -> 214 s of the workers'
  wall); the install test's pip not compiling every module's bytecode (35 -> 22 s); the
  benchmark's smoke test timing each thing once (57 -> 49.5 s alone); and two cuts in
  what compiling the physics costs, found with Numba's compile events (a kernel's
  exclusive time): a slice copy's formatted error message and its strings' kernels (3 s),
  and the implicit step's machine code emitted once, inlined into the loop that calls it
  (8 s: a render compiling from nothing 63-65 -> 55.5 s). Where the suite's time goes
  now (the CPU of its two workers, 627 s): compiling the physics from nothing once
  (61-67 s, what the test of what a render compiles needs), the fold test's 591 pairs of
  action units held 200 frames each (67-72 s: 0.55 ms a step on the head, of which four
  triangular solves of the rest factor, 65 µs each, whether it is read from L and U or from L
  alone, so not bound by memory), the benchmark's smoke test (50-56 s) and the wheel
  installed into a new venv (22 s). Tried, not kept: three workers on the two cores
  (358 s against 357, 4% more CPU). A machine with an empty user cache also compiles the
  kernels the tests call directly and the shipped set lacks, and measures the capture's
  subjects: about a minute more (428-466 s against 371-385 s locally, 2026-12-07).
- **The head's frame against its floor, 1.2x: met, 0.94x at 256² and 1.13x at 512² in
  this run (1.00x and 1.02x in the run before, 0.93x and 1.04x in the quiet run of 19:07;
  1.02x and 1.07x, 1.02x and 1.06x in the two before that; 1.01x and 1.06x,
  1.11x and 0.99x in this evening's two; 1.25x and 1.20x this afternoon,
  1.13-1.37x at 512² over its three runs).** What closed it is what this paragraph named
  this afternoon as the way to close it: the next frame's skin, normals and vertex arrays
  computed while llvmpipe draws this one, and the drawn frame's edge filter moved there
  too (the frames in flight above). The floor draws the same scene with the same renderer
  and antialiasing and uploads vertex arrays computed before the clock starts, one frame
  after another; facesim's per-frame work (profiled on the Xeon at 512², 22-24 ms a
  frame: the skin carried from the simulated mesh, facesim.face.figure._followed, 0.9 ms looped
  and 1.6 ms between draws, the normals 0.4-0.7 ms, the nine parts' vertex arrays written
  in place 0.3 ms, the uploads 0.2 ms, the edge filter 1.3 ms, which the floor also does)
  now runs beside llvmpipe's vertex work instead of after it.
- **25 frames per second end to end on the head at 512², antialiased: met, 35.9 in this
  run (32.0 in the one before, 39.8 in the quiet run of 19:07, 32.6 and 31.8 in the two
  before that; 26.5 and 29.7 in this evening's two; 32.3, 29.2 and
  29.6 this afternoon; 20.5 this morning), 34.8 on the Xeon (2026-12-02).** What made it
  here: the render changes above (facesim's frame 23.2 ms in this run, the floor 20.5; the floor alone was 34-37
  ms in this morning's run). Measured end to end in one process
  (2026-12-03): 35 frames in 1.05-1.31 s, of which the simulation 0.04 s, drawing 0.84-1.07 s
  with the encoder running beside it on the same two cores (x264 alone takes 0.2 s for
  the 35), the sends to it 0.1 s, its close 0.03 s and reading the file back 0.03-0.04
  s. What made it on the Xeon: antialiasing as a filter
  on the frame as drawn (facesim.renderer.scene._smooth_edges, the sub-pixel pass of FXAA),
  where drawing four times the pixels cost 30 ms more a frame (against the 4-samples
  frame the filtered one is 44.3 dB, the unfiltered 41.5 dB; tests/test_head.py;
  `--supersample` keeps the 4 samples), and the head's opaque parts culling their back
  faces (12-15% of a frame). Multisampling costs more in llvmpipe (108 ms at 512² with 2
  or 4 samples, measured on 2026-12-01).
- **3 s for `facesim render` in a fresh process: met, 2.71 s in this run (nine runs,
  2.54-2.88 s), missed at 3.19 s (2.96-3.31) in the run before it ten minutes earlier;
  2.47 s (nine runs, 2.25-2.74 s) in the quiet run of 19:07; 3.49 s (five runs, 3.16-3.63)
  and 2.95 s (nine runs, 2.44-3.59) in the two runs before that, in a slow hour, with the same code, and 2.62 s, then 3.05
  s, for the same five-run measurement alone between them. By hand tonight 2.59-2.77 s. Before tonight's changes (late evening, above): 3.98 and 3.38 s in
  this evening's two runs, 3.02, 3.06 and 3.58 s in this afternoon's three, 2.64 s on the
  Xeon.** On this machine the target is met when the second core is free and missed when
  it is not. This evening's changes shorten two of its
  parts, the head's simulation (the head's table) and its 35 frames (the frames in
  flight); the rest is unchanged, and this machine's evicted page cache makes the
  imports the most variable part (a first render after a pause took 8.2 s). Profiled here this afternoon
  (`python -X importtime`, one process): of about 3.3 s, the imports are 1.2-1.7 s:
  facesim with Numba 0.55 s, SciPy's optimize module 0.34 s (which trimesh imports
  anyway; SciPy 1.17 parses docstrings at import for its array-API notes, and 1.15 imports
  the same modules 0.05 s faster: not worth pinning), trimesh 0.30 s, pyrender 0.16 s,
  and Numba's cffi support 0.13 s where cffi is installed (MediaPipe's `photo` extra
  brings it; a plain install has none). Then the model 0.24 s (Numba's typing set up and
  its cached kernels loaded), the simulation 0.18 s, the figure 0.07 s, the GL context,
  scene and shaders 0.3 s, and the 35 frames at about 25 ms. Tried: pyrender imported in
  a second thread while the model builds: no gain (3.64-3.94 s against 3.69-4.56 s over
  four pairs of runs; imports hold the interpreter's lock); and a process forked when the
  command starts that loads the head, builds its figure, imports pyrender and opens its
  context while this one builds the model and simulates, then draws the frames it is
  sent: 3.67 s against 3.73 (medians of five pairs of runs; not kept). That process
  was the longer of the two (its imports, the head and its figure 0.67 s after the fork,
  pyrender, the context, scene and shaders 0.86 s more, against 1.2 s for the model and
  the simulation), so it could save at most the simulation's share, 0.2 s, and the two
  processes sharing two cores took that back. What would close it: less to import
  (pyrender brings trimesh, trimesh SciPy's optimize and spatial modules and networkx:
  0.6 s of every fresh process) and frames drawn faster.
  Profiled there (3.0-3.5 s wall before the changes named): importing the command line
  0.3 s; the model 0.6 s (with the imports of trimesh and SciPy it needs); the
  simulation 0.2 s (Numba's cached kernels loaded); the head's figure 0.06 s; the GL
  context and scene 0.3 s; the 35 frames 1.2 s, encoding overlapped; facesim's command
  leaves by os._exit once its threads are joined and its streams flushed
  (facesim.cli.main), which saves the interpreter's 0.3 s teardown. Here the frames
  alone, at llvmpipe's 34 ms, take 1.2 s of drawing and 0.2 s of encoding. Profiled here
  (2026-12-03): the model 1.7 s of a 4.5 s run, 1.4 s of it imports (trimesh, which
  pyrender imports anyway, brings SciPy's spatial and optimize modules and networkx:
  0.5 s), Numba's cached kernels loaded 0.6 s, the simulation 0.3 s, the writing 2.5 s.
  Taking SciPy's assignment solver out of the head's mirror map saved nothing, since
  trimesh imports the same modules (tried, reverted).
- **50 ms for happy on the head: met, 22.6 ms in this run (31.7 in the one before, 19.4 in
  the quiet run of 19:07, 22.1 and 27.2 in the two before that, 20.6 and 19.6 in this evening's two; 36.1, 45.1 and 49.3 this afternoon, 38.1 this
  morning)** (38 ms on the Xeon), since the preconditioner's solves by blocks (above);
  the head's table above, which times the same run in a process of its own, gives 19.8
  and 22.0 ms in this run
  (51.6-54.2 in this morning's). That is this machine's noise between processes, not pyrender: the median of
  nine runs in six fresh processes was 42-58 ms, alike whether pyrender was imported
  and a GL context made first or not (2026-12-03), before the preconditioner by blocks.
  Side by side in
  one process (2026-12-01), the head's tied rim (issue 16) costs 7% over a pinned one.
  The profile above names the force terms (138 µs a step in this run, 117 in the quiet
  one, 213 in a slow one, the edge repulsion the largest) and the conjugate gradients' products (46 µs
  each, three or four a step) as the largest parts of a step, then the preconditioner
  (54 µs, four a step).
"""


DATASET_CODE = """
import json, shutil, tempfile, time
from pathlib import Path
from facesim.dataset import DatasetSettings, build_dataset
out = {{}}
for executor in ("local", "dask"):
    for jobs in {workers}:
        directory = Path(tempfile.mkdtemp())
        build_dataset(directory / "warm", 2, DatasetSettings(0, {size}, {size}), executor, jobs)  # caches, imports
        t = time.perf_counter()
        build_dataset(directory / "run", {n}, DatasetSettings(1, {size}, {size}), executor, jobs)
        out[f"{{executor}} {{jobs}}"] = {n} / (time.perf_counter() - t)
        shutil.rmtree(directory)
print(json.dumps(out))
"""


def dataset_throughput(n: int, size: int, workers: tuple[int, ...] = (1, 2)) -> str:
    figures = python_json(DATASET_CODE.format(n=n, size=size, workers=workers))
    rows = [[key.split()[0], key.split()[1], f"{rate:.2f}"] for key, rate in figures.items()]
    return table(["executor", "workers", "samples per second"], rows) + (
        f"\n\n{n} samples of {size}² each (simulate 20 frames, render the last, write PNG and label), "
        "timed after a warm-up run. One local worker runs in the calling process, already warm; the other rows "
        "include starting their worker processes (and the Dask LocalCluster), about two seconds, which a long "
        "run amortises. Two workers share two cores with llvmpipe's own rendering threads, so they gain little "
        "on this machine; the point of Dask is more machines.")


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--quick", action="store_true", help="tiny sizes, few repeats: a smoke test")
    parser.add_argument("-o", "--output", type=Path, default=ROOT / "BENCHMARKS.md")
    parser.add_argument("--json", type=Path, help="also write the figures as JSON (the smoke test reads them)")
    args = parser.parse_args()
    quick = args.quick
    repeats = 1 if quick else 7
    started = time.perf_counter()
    sections = []

    def section(title: str, body: str) -> None:
        print(f"\n## {title}\n\n{body}", flush=True)
        sections.append(f"## {title}\n\n{body}")

    section("Machine", machine())
    t31, f31 = table_31(repeats, 128 if quick else 512, 1 if quick else 3)
    section("Table 3.1: the eight expressions, 35 frames, Δt = 0.01", t31 + "\n\nSimulation: median of "
            f"{repeats} warm runs. Render: 35 frames offscreen (auto backend), one renderer reused, median of "
            f"{1 if quick else 3}. End-to-end fps: 35 frames over simulation + render + MP4 encode, one process. "
            "The thesis's elapsed time (Matlab) covers its simulation and on-screen plotting. Surprise counts "
            "8 muscles: its jaw drop (AU26) stands for the two the thesis's text leaves out.")
    section("Table 3.2: 10 consecutive runs of the six basic expressions (simulation only)", table_32(3 if quick else 10))
    section("Table 3.3: happy at other frame counts and time steps", table_33(repeats))
    text, ratio = numba_vs_numpy(repeats)
    section("Numba against the NumPy reference, side by side", text)
    text, solver_figures = solvers(repeats, list(THESIS_31)[:2] if quick else list(THESIS_31))
    section("The two solvers, side by side", text + "\n\nThe thesis's quasi-implicit update (eq. 3.14-3.20, "
            "per-vertex stiffness) needs 4 steps per frame; the implicit step (the whole stiffness, conjugate "
            "gradients: facesim.physics.solver) is stable at 1. The skin's bending (facesim's default, not in the thesis) "
            "couples four vertices per hinge, which only the implicit step carries: on the head the reference is "
            "the same model at eight steps per frame with its conjugate gradients run to 1e-8. Simulation: median "
            "of warm runs. Apex: each expression's strongest frame held 200 frames, the mean of the last 50, the "
            "largest vertex distance between the two.")
    text, profile_figures = profile(1 if quick else 5)
    section("Where a step's time goes", text + "\n\nThe default head's skin has bending, so its conjugate "
            "gradients are preconditioned by its system at rest, factorised once (facesim.physics.solver); the Hopper "
            "face's, in the thesis's model, by the system's diagonal. Medians of compiled loops; iterations over "
            "happy's 35 frames.")
    text, compile_figures = compilation(quick)
    section("Compilation, measured apart", text + "\n\nEach row is one fresh process; `cache=True` keeps compiled "
            "kernels on disk, so only the first run of this code on a machine pays for compilation, whichever copy "
            "of facesim runs it (facesim.config).")
    text, first = first_run(1 if quick else 3, 1 if quick else 7, quick)
    section("First run: a new user's first render, and the ones after", text + "\n\nfacesim built into a wheel "
            "and installed on its own (`pip install --target`), its dependencies this environment's; each first run "
            "in a new HOME and XDG_CACHE_HOME, with no NUMBA_CACHE_DIR or FACESIM_CACHE; the later runs in the last "
            "of those homes. The kernels ship compiled for the CPU's baseline (facesim/compiled, `make kernels`), "
            "so the first run unpacks them and compiles nothing; *kernels* is Numba compiling (none when every "
            "kernel loads). Phases overlap: the face is simulated on a thread of its own beside the drawing, "
            "which waits for its frames.")
    wall, walls, peak_mb = fresh_render_wall(1 if quick else 9, 64 if quick else 512)
    section("`facesim render expressions/happy.yaml` in a fresh process, caches warm (the default head, 512² MP4)",
            f"median wall {wall:.2f} s over {len(walls)} runs: " + ", ".join(f"{w:.2f}" for w in walls) +
            f"; peak memory (maximum resident set) {peak_mb:.0f} MB")
    text, scale = scaling(1 if quick else 4, repeats, None if quick else ROOT / "docs" / "scaling.png")
    section("Scaling: the Hopper face Loop-subdivided (muscles carried by position)", text +
            "\n\nA finer mesh of the same face takes more sub-steps per frame (its lighter vertices oscillate "
            "faster: `facesim.physics.model`); each row simulates about as many steps as the default face's 35 frames." +
            ("" if quick else "\n\n![cost per vertex-step](docs/scaling.png)"))
    text, default_figures = default_solver_scaling(1 if quick else 3, repeats, scale)
    section("Scaling by the default solver: its preconditioner on finer meshes", text + "\n\nThe table above "
            "is the thesis's model and update (no bending, per-vertex). facesim's default solver, the implicit step "
            "with bending, preconditions its conjugate gradients by the skin's system at rest factorised exactly, "
            "once per model and step (facesim.physics.solver.rest_preconditioner: SuperLU, minimum-degree order), "
            "and applies it twice a step or more. Its fill grows faster than the mesh, and applying it reads the whole "
            "factor: on tens of thousands of vertices the step is bound by memory, an order of magnitude above the "
            "thesis's update per vertex-step (its peak resident memory at 27,614 vertices was 3.4 GB, 2026-12-07). "
            "Not yet solved: orderings other than SuperLU's minimum degree filled more (on 6,990 vertices, the "
            "vertex graph's factor's entries per vertex: COLAMD 75, MMD on AᵀA 87, reverse Cuthill-McKee 183, a "
            "geometric nested dissection 90-97, against 64), and SuperLU's incomplete factorisation (drop 1e-4) "
            "halved the factor but took more "
            "iterations: 2.98 -> 2.12 s on 6,990 vertices, 3.2 -> 14.7 µs a vertex-step on 27,614 (2026-12-07). "
            "Nor does an algebraic multigrid off the shelf scale here: PyAMG's smoothed aggregation (5.4.1, not a "
            "dependency), on the rest system with bending, took 23-24 conjugate-gradient iterations to 1e-3 on 6,990 "
            "vertices and 45-48 on 27,614, doubling with each refinement, against the exact factor's 1-3 "
            "(2026-12-07): the bending, a fourth-order term, defeats its default aggregation. A multigrid built for "
            "the bending is what a mesh this fine needs. The implicit step takes one step per frame on every "
            "mesh (facesim.physics.model), each step on a finer mesh more iterations.")
    text, order_figures = vertex_orders(1 if quick else 3, repeats)
    section("Vertex order", text + "\n\nA mesh of at least 4,000 vertices is simulated in an order of its own "
            "(facesim.physics.model.reordered): reverse Cuthill-McKee on its edge graph (scipy.sparse.csgraph), the springs, "
            "triangles and hinges sorted by their first vertex in it; what a user sees (positions, NPZ, messages) "
            "stays in the mesh's numbering. The four models alternate, each the median of "
            f"{repeats} runs; the scaling table above is in facesim's order.")
    text, render_figures = rendering([64] if quick else [256, 512, 1024], 1 if quick else 3, 12 if quick else 70)
    section("Rendering: facesim against the bare draw floor", text + "\n\nThe floor renders the same scene "
            "with the same renderer and settings, antialiased the same way (the edge filter), and updates nothing; "
            "facesim's frame adds the vertex normals (Numba) and the in-place vertex-buffer upload; its frames "
            "are drawn as `facesim render` draws an animation (FaceRenderer.frames: each frame's arrays computed, "
            "and each drawn frame filtered, on a second thread while another draws).")

    text, overlap_figures = overlap(64 if quick else 512, 1 if quick else 7)
    section("Simulation, drawing and encoding overlapped", text + "\n\n`facesim render` simulates a face of fewer "
            "than 4,000 vertices on a thread of its own (the kernels release the GIL) and hands each frame to the "
            "renderer as soon as it is done; each drawn frame is encoded while the next one draws. A larger mesh's "
            "simulation wants every core and is run first: overlapped with the renderer on this machine's two cores "
            "it made the Hopper face subdivided twice render slower, not faster (891 ms simulated first against "
            "1,271 overlapped, 2026-12-03; facesim.animation.simulate.simulate). Wall time of "
            "writing the MP4, medians of the runs after the first, the two ways alternating in one process, "
            "renderer warm.")

    text, head_figures = head([64] if quick else [256, 512], 1 if quick else 7)
    section("The default head (ICT FaceKit), happy", text)

    text, memory = long_clip_memory(30 if quick else 300, 240 if quick else 30_000, 32 if quick else 128)
    section("Memory: a long clip streamed to MP4", text + "\n\nEach a fresh `facesim render` under a parent of its own; "
            "`facesim render` simulates a video's frames into a ring of 8 and draws each as it comes "
            "(facesim.animation.simulate, `stream=True`), so the positions of the whole clip are never held.")

    throughput = dataset_throughput(6, 64, (1,)) if quick else dataset_throughput(120, 256)  # quick: one worker of each
    section("Datasets: samples per second, local processes and Dask", throughput)

    cost_28k = next((v for k, v in scale.items() if 20_000 < k < 40_000), (float("nan"), float("nan")))
    per_core_28k, threads_28k = 1 / cost_28k[0] / 1e6, cost_28k[0] / cost_28k[1]
    egl512 = render_figures.get(("egl", 512), render_figures.get(("egl", 64)))
    head_size = max(head_figures)
    head_e2e = head_figures[head_size]
    targets = [
        ["happy, 35 frames, simulation only, warm, the default head", "≤ 50 ms",
         f"{solver_figures['the default head']['implicit']:.2f} ms (implicit, with bending; "
         f"{solver_figures['the default head']['no_bending']:.2f} ms without)"],
        ["happy, 35 frames, simulation only, warm, the Hopper face", "≤ 2 ms",
         f"{solver_figures['the Hopper face']['implicit']:.2f} ms (implicit, the thesis's model; "
         f"{solver_figures['the Hopper face']['quasi']:.2f} ms by its quasi-implicit update)"],
        ["vertex-steps per second per core, ~28k vertices", "≥ 10 million", f"{per_core_28k:.2f} million"],
        ["`prange`, 2 threads against 1, ~28k vertices", "≥ 1.7x", f"{threads_28k:.2f}x"],
        ["Numba step against the NumPy reference", "≥ 50x", f"{ratio:,.0f}x"],
        [f"happy end to end on the head at {head_size}², antialiased, to MP4, warm", "≥ 25 fps",
         f"{head_e2e['fps']:.1f} fps ({head_e2e['fps_supersample']:.1f} fps with --supersample, "
         f"{head_e2e['fps_plain']:.1f} with --no-antialias)"],
        ["a 30,000-frame render of the head at 128² to MP4 against a 300-frame one: peak memory", "within 100 MB",
         ", ".join(f"{frames:,} frames {peak:.0f} MB" for frames, (peak, _) in memory.items())],
        ["`facesim render expressions/happy.yaml`, a new user's first run (installed, new HOME, 2 cores)", "≤ 20 s (stretch 10)",
         f"{first['first run, new user (shipped kernels)']['wall']:.2f} s"
         + (f"; {first['first run without the shipped kernels (compiling)']['wall']:.1f} s compiling without them"
            if 'first run without the shipped kernels (compiling)' in first else "")],
        ["`facesim render expressions/happy.yaml`, fresh process, warm caches", "≤ 2 s",
         f"{first['later runs, caches warm']['wall']:.2f} s installed; {wall:.2f} s from the checkout, "
         f"peak memory {peak_mb:.0f} MB"],
        ["one implicit step per frame against converged small steps, held apex of the eight expressions", "≤ 2%",
         f"{100 * max(solver_figures['apex, the default head'].values()):.2f}% at most on the head"],
        ["facesim per-frame render against the bare floor, Hopper face", "≤ 1.2x",
         f"{egl512['ours'] / egl512['floor']:.2f}x (EGL, 512²)"],
        ["the head: per-frame render against the bare floor", "≤ 1.2x",
         ", ".join(f"{h['ours'] / h['floor']:.2f}x at {size}²" for size, h in head_figures.items())],
        ["`make test` from a fresh clone, setup included, 2 cores", "≤ 6 min", SUITE_MEASURED],
    ]
    figures = dict(first_run=first, table_31=f31, solvers=solver_figures, profile=profile_figures, numba_ratio=ratio, compile=compile_figures, fresh_wall=wall,
                   fresh_peak_mb=peak_mb, scaling={str(k): v for k, v in scale.items()},
                   vertex_order={f"{label}, {'reordered' if reorder else 'as numbered'}": v for (label, reorder), v in order_figures.items()},
                   render={f"{key[0]}-{key[1]}": v for key, v in render_figures.items() if key != "processes"},
                   head={str(k): v for k, v in head_figures.items()}, overlap=overlap_figures,
                   memory={str(k): v for k, v in memory.items()},
                   default_solver={str(k): v for k, v in default_figures.items()})
    if args.json:
        args.json.write_text(json.dumps(figures))
    section("Targets", table(["target", "goal", "measured"], targets) + "\n\n" + ANALYSIS)
    header = ("# facesim benchmarks\n\nProduced by `make bench` (`python scripts/bench.py`) on "
              f"{time.strftime('%Y-%m-%d')} in {time.perf_counter() - started:.0f} s. Thesis figures are from T. "
              "Erkoç, *Anatomy Based Animation of Facial Expressions*, Tables 3.1-3.3 (Matlab).\n")
    if not quick:
        args.output.write_text(header + "\n" + "\n\n".join(sections) + "\n")
        print(f"\nwrote {args.output}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
