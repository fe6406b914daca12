"""Rendering many specs at once: each in its own process (spawn, or the workers of a Dask
cluster), one renderer per process reused for every spec of the same mesh. A failing
spec is reported and the others still finish."""

from __future__ import annotations

from concurrent.futures import as_completed
from dataclasses import dataclass
from pathlib import Path

from .errors import FacesimError, InputError
from .renderer.scene import shared_renderer
from .renderer.settings import RenderSettings
from .workers import worker_pool


def collect_specs(inputs: list[Path]) -> list[Path]:
    """Spec files from files and directories (their *.yaml, sorted), in order given; a
    bare name that is no file here is a spec of the library (``happy``)."""
    from .animation.spec import library_spec

    specs: list[Path] = []
    for item in map(library_spec, inputs):
        if item.is_dir():
            found = sorted(item.glob("*.yaml")) + sorted(item.glob("*.yml"))
            if not found:
                raise InputError(f"{item}: no *.yaml specs in this directory")
            specs.extend(found)
        elif item.is_file():
            specs.append(item)
        else:
            raise InputError(f"{item}: no such spec file or directory")
    return specs


@dataclass
class BatchResult:
    spec: Path
    report: object | None = None
    error: str | None = None


def render_one(spec_path: Path, output: Path, settings: RenderSettings, backend: str, force: bool,
               mesh: Path | None = None, muscles: Path | None = None, identity: int | None = None,
               face: Path | None = None) -> BatchResult:
    """Load, simulate, render and write one spec; errors become a result, not an exception."""
    from .animation.simulate import simulate
    from .animation.spec import load_spec
    from .export.output import check_output, output_kind, write_animation

    try:
        spec = load_spec(spec_path).with_overrides(mesh=mesh, muscles=muscles, identity=identity, face=face)
        check_output(output, force, settings)
        animation = simulate(spec)
        renderer = None if output_kind(output) == "npz" else shared_renderer(animation.rest, animation.faces, settings, backend,
                                                                                    animation.figure, animation.face)
        return BatchResult(spec_path, report=write_animation(animation, output, settings, backend=backend, renderer=renderer,
                                                             replace=force))
    except FacesimError as exc:
        message = str(exc)  # named by its spec when the fault is in a file the spec names
        return BatchResult(spec_path, error=message if message.startswith(str(spec_path)) else f"{spec_path}: {message}")
    except Exception as exc:  # a bug must not cost the other specs their results  # noqa: BLE001
        return BatchResult(spec_path, error=f"{spec_path}: failed unexpectedly ({type(exc).__name__}: {exc})")


def run_batch(specs: list[Path], outdir: Path, suffix: str, settings: RenderSettings, backend: str, jobs: int,
              force: bool, mesh: Path | None = None, muscles: Path | None = None, identity: int | None = None,
              face: Path | None = None, on_done=None,
              executor: str = "local", scheduler: str | None = None,
              scheduler_timeout: float | None = None) -> list[BatchResult]:
    outputs = [outdir / (s.stem + suffix) for s in specs]
    if len(set(outputs)) != len(outputs):
        raise InputError("two specs share a file name; their outputs would collide in " + str(outdir))
    args = [(s, o, settings, backend, force, mesh, muscles, identity, face) for s, o in zip(specs, outputs)]
    results: dict[Path, BatchResult] = {}

    def done(result: BatchResult) -> None:
        results[result.spec] = result
        if on_done:
            on_done(result)

    if executor == "dask":
        from .dataset import dask_client, run_on_dask

        run_on_dask(dask_client(scheduler, jobs, scheduler_timeout), render_one, list(zip(*args)), done)
    elif jobs <= 1:
        for a in args:
            done(render_one(*a))
    else:
        with worker_pool(min(jobs, len(args))) as pool:
            futures = {pool.submit(render_one, *a): a[0] for a in args}
            for future in as_completed(futures):
                try:
                    done(future.result())
                except Exception as exc:  # the worker process itself died (killed, out of memory)  # noqa: BLE001
                    done(BatchResult(futures[future], error=f"{futures[future]}: its worker process died ({type(exc).__name__})"))
    return [results[s] for s in specs]
