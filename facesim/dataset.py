"""Datasets of labelled expressions for training and testing recognisers: many faces,
each simulated and rendered to a PNG with the exact muscle activations and action units
that made it.

The distribution (``sample``), drawn per sample from ``numpy.random.default_rng([seed,
index])``, so that a sample depends on the seed and its index only, never on the executor,
the number of workers or the order they finish in:

- with probability 1/2, one of the six basic expressions (happy, sad, angry, fear,
  disgust, surprise), uniformly, at an intensity uniform in [0.5, 1];
- otherwise one to three FACS action units, uniformly among those this face's muscles
  can show (never two that exclude each other), each at an intensity uniform in [0.3, 1];
- with ``jitter``: the camera turned by a yaw uniform in [-15, 15] and a pitch in [-8, 8]
  degrees, the lights scaled by a factor uniform in [0.8, 1.2], and the head and eyes
  turned (``POSE_JITTER``: head yaw ±20, pitch ±10, roll ±8, gaze yaw ±15, pitch ±10
  degrees, each uniform), and a new person: the head's identity from a seed drawn
  uniformly (facesim.face.head: weights of ICT's 100 modes from the standard normal), recorded
  in the label with its weights.

Each sample is simulated for 20 frames (the activations easing in over 10) and its last
frame rendered (with ``clip``, every frame too, as ``clips/<id>.mp4``). It is written atomically as ``images/<id>.png`` and ``labels/<id>.json``
(activations, AUs, the expression, the render settings and the image's SHA-256), the
label last (a draw whose simulation fails is labelled with the failure and no image): a sample whose label exists is finished, so a second run skips it and a worker
that dies loses only the sample it was drawing. The manifest (Parquet where pyarrow is
installed, CSV otherwise) is rebuilt from the labels on disk at the end of every run.

Executors: ``local`` (processes over the cores) and ``dask`` (``dask.distributed``: a
LocalCluster, or an existing cluster at ``--scheduler``). Every worker process keeps one
renderer for all its samples.
"""

from __future__ import annotations

import csv
import hashlib
import io
import json
import os
import re
from concurrent.futures import FIRST_COMPLETED, as_completed, wait
from dataclasses import asdict, dataclass
from itertools import repeat
from pathlib import Path

import numpy as np

from .errors import FacesimError, InputError, SimulationError
from .files import atomic_path
from .workers import capped_jobs, worker_pool

#: Samples in flight per worker: enough to keep each busy, few enough that memory stays
#: flat however many samples a run asks for.
WINDOW = 4
#: Seconds to wait for a Dask scheduler to answer, unless --scheduler-timeout says otherwise.
SCHEDULER_TIMEOUT = 10.0
#: What --scheduler takes: [tcp|tls|ws|wss://]HOST:PORT.
SCHEDULER_ADDRESS = re.compile(r"((tcp|tls|ws|wss)://)?(\[[0-9a-fA-F:.]+\]|[\w.-]+):\d{1,5}/?")

BASIC = ("happy", "sad", "angry", "fear", "disgust", "surprise")
FRAMES, ONSET = 20, 10
#: The largest head and gaze angle drawn with ``jitter`` (degrees), in facesim.animation.spec.POSE order.
POSE_JITTER = {"head_yaw": 20.0, "head_pitch": 10.0, "head_roll": 8.0, "gaze_yaw": 15.0, "gaze_pitch": 10.0}
#: With ``jitter`` each sample is a new person: an identity seed drawn below this.
IDENTITY_SEEDS = 2**31


@dataclass(frozen=True)
class DatasetSettings:
    seed: int
    width: int = 256
    height: int = 256
    jitter: bool = False
    backend: str = "auto"
    clip: bool = False
    face: str | None = None  # a face directory: every sample that person
    look: str = "auto"


def sample(seed: int, index: int, available_aus: list[str]) -> dict:
    """The draw of one sample: which expression or action units, and the view."""
    rng = np.random.default_rng([seed, index])
    draw: dict = {"expression": None, "intensity": None, "aus": {}}
    if rng.random() < 0.5:
        draw["expression"] = BASIC[rng.integers(len(BASIC))]
        draw["intensity"] = round(float(rng.uniform(0.5, 1.0)), 4)
    else:
        chosen = [str(au) for au in rng.permutation(available_aus)[: rng.integers(1, 4)]]
        draw["aus"] = {au: round(float(rng.uniform(0.3, 1.0)), 4) for au in sorted(chosen)}
    draw["yaw"], draw["pitch"], draw["light"] = rng.uniform(-15, 15), rng.uniform(-8, 8), rng.uniform(0.8, 1.2)
    draw.update({name: rng.uniform(-limit, limit) for name, limit in POSE_JITTER.items()})
    draw["identity"] = int(rng.integers(IDENTITY_SEEDS))
    return draw


def available_action_units(muscle_names) -> list[str]:
    from .animation.timeline import ACTION_UNITS, au_muscles

    out = []
    for au in ACTION_UNITS:
        try:
            au_muscles(au, muscle_names)
            out.append(au)
        except ValueError:
            pass
    return out


def sample_id(index: int) -> str:
    return f"{index:07d}"


def make_sample(directory: str, index: int, settings: DatasetSettings) -> str:
    """Draw, simulate, render and write sample ``index``; returns its id. Skips a
    finished sample."""
    from .animation.simulate import model_for, simulate
    from .animation.spec import Spec
    from .face.head import identity_weights

    root = Path(directory)
    sid = sample_id(index)
    label_path = root / "labels" / f"{sid}.json"
    if label_path.exists():
        return sid
    probe = Spec(frames=FRAMES, onset=ONSET)
    draw = sample(settings.seed, index, available_action_units(model_for(probe).muscles.names))
    identity = draw["identity"] if settings.jitter and settings.face is None else None
    what = {"expressions": {draw["expression"]: draw["intensity"]}} if draw["expression"] else {"aus": draw["aus"]}
    spec = Spec(frames=FRAMES, onset=ONSET, identity=identity, face=settings.face, **what)
    label = {"id": sid, "index": index, "seed": settings.seed, "expression": draw["expression"],
             "intensity": draw["intensity"], "aus": draw["aus"], "width": settings.width, "height": settings.height,
             "frames": FRAMES, "dt": spec.dt, "identity": identity,
             "identity_weights": [] if identity is None else [round(float(w), 6) for w in identity_weights(identity)]}
    if settings.face is not None:
        label.update(face=settings.face, identity_weights=[round(w, 6) for w in spec.head_identity])
    try:
        animation = simulate(spec)
    except SimulationError as exc:  # recorded, not fatal: the same draw fails the same way anywhere
        label.update(status=f"failed: {exc}", activations={}, yaw=0.0, pitch=0.0, light=1.0, image="", sha256="", clip="",
                     **dict.fromkeys(POSE_JITTER, 0.0))
    else:
        label.update(_render_sample(root, sid, animation, draw, settings))
    with atomic_path(label_path) as tmp:
        tmp.write_text(json.dumps(label, sort_keys=True))
    return sid


def _render_sample(root: Path, sid: str, animation, draw: dict, settings: DatasetSettings) -> dict:
    """Render a simulated sample, write its image (and clip); the label's fields for it."""
    import imageio.v3 as iio

    from .renderer.scene import shared_renderer
    from .renderer.settings import RenderSettings
    renderer = shared_renderer(animation.rest, animation.faces, RenderSettings(settings.width, settings.height, look=settings.look),
                               settings.backend, animation.figure, animation.face)
    yaw, pitch, light = (draw[k] if settings.jitter else v for k, v in (("yaw", 0.0), ("pitch", 0.0), ("light", 1.0)))
    renderer.view(yaw, pitch, light)
    pose = {name: float(draw[name]) if settings.jitter else 0.0 for name in POSE_JITTER}
    if settings.clip:
        from .export.output import write_frames

        frames = np.stack(list(renderer.frames(animation, pose=tuple(pose.values()))))
        write_frames(frames, root / "clips" / f"{sid}.mp4", "mp4", animation.fps)
        image = frames[-1]
    else:
        image = renderer.frame(animation, animation.frames - 1, pose=tuple(pose.values()))
    buffer = io.BytesIO()
    iio.imwrite(buffer, image, extension=".png")
    png = buffer.getvalue()
    with atomic_path(root / "images" / f"{sid}.png") as tmp:
        tmp.write_bytes(png)
    return dict(
        status="ok",
        activations={m: round(float(a), 6) for m, a in zip(animation.muscle_names, animation.activations[-1]) if a > 0},
        yaw=round(float(yaw), 4), pitch=round(float(pitch), 4), light=round(float(light), 4),
        **{name: round(angle, 4) for name, angle in pose.items()},
        image=f"images/{sid}.png", sha256=hashlib.sha256(png).hexdigest(),
        clip=f"clips/{sid}.mp4" if settings.clip else "",
    )


def _prepare(directory: Path, n: int, settings: DatasetSettings):
    """Create the layout, check a rerun matches the first run; the unfinished samples'
    indices, lazily (a run of ten million samples starts at once, in constant memory)."""
    (directory / "images").mkdir(parents=True, exist_ok=True)
    (directory / "labels").mkdir(exist_ok=True)
    if settings.clip:
        (directory / "clips").mkdir(exist_ok=True)
    for stale in directory.glob("*/.*.partial-*"):
        stale.unlink()  # left by a worker that was killed mid-write
    meta = directory / "dataset.json"
    defaults = asdict(DatasetSettings(settings.seed))
    wanted = {k: v for k, v in asdict(settings).items()  # a setting added later is recorded when it is used
              if k != "backend" and not (k in ("face", "look") and v == defaults[k])}
    if meta.exists():
        previous = json.loads(meta.read_text())
        if previous != wanted:
            raise InputError(f"{directory}: holds a dataset made with other settings {previous}; use another directory")
    else:
        with atomic_path(meta) as tmp:
            tmp.write_text(json.dumps(wanted, sort_keys=True))
    finished = {entry.name[:-5] for entry in os.scandir(directory / "labels") if entry.name.endswith(".json")}
    return (i for i in range(n) if sample_id(i) not in finished)


def _run_local(directory: Path, todo, settings: DatasetSettings, jobs: int, advance) -> None:
    if jobs <= 1:
        for i in todo:
            make_sample(str(directory), i, settings)
            advance()
        return
    with worker_pool(jobs) as pool:
        pending: set = set()
        for i in todo:  # at most WINDOW samples per worker in flight: memory stays flat in --n
            pending.add(pool.submit(make_sample, str(directory), i, settings))
            if len(pending) >= WINDOW * jobs:
                finished, pending = wait(pending, return_when=FIRST_COMPLETED)
                for future in finished:
                    future.result()
                    advance()
        for future in as_completed(pending):
            future.result()
            advance()


def dask_client(scheduler: str | None, jobs: int, timeout: float | None = None):
    """A dask.distributed client: a LocalCluster of ``jobs`` single-threaded worker
    processes, or the cluster at ``scheduler`` if it answers within ``timeout`` seconds
    (default SCHEDULER_TIMEOUT)."""
    import logging

    try:
        from dask.distributed import Client, LocalCluster
    except ImportError:
        raise InputError("--executor dask needs dask.distributed: pip install 'dask[distributed]'") from None
    logging.getLogger("distributed").setLevel(logging.ERROR)
    if scheduler:
        return _connect(Client, scheduler, SCHEDULER_TIMEOUT if timeout is None else timeout)
    # the cluster's nannies set their workers' variables (OMP_NUM_THREADS=1,
    # MALLOC_TRIM_THRESHOLD_, PYTHONHASHSEED, ...) in this process's environment, and left
    # them for every process the caller starts later: put back once the workers are up
    environment = dict(os.environ)
    try:
        cluster = LocalCluster(n_workers=jobs, threads_per_worker=1, processes=True, dashboard_address=None)
    finally:
        os.environ.clear()
        os.environ.update(environment)
    client = Client(cluster)
    client._facesim_cluster = cluster
    return client


def _connect(Client, scheduler: str, timeout: float):
    """A client of the scheduler at ``scheduler``, or one line within ``timeout`` seconds.
    Client's own timeout covers the TCP connect, not the handshake: a server that accepts
    and never answers held it for ever, so the client is made in a thread we stop waiting for."""
    import threading

    if not SCHEDULER_ADDRESS.fullmatch(scheduler):
        raise InputError(f"--scheduler {scheduler}: expected a scheduler address such as tcp://HOST:PORT")
    if not timeout > 0:
        raise InputError(f"--scheduler-timeout: expected a number of seconds above 0, got {timeout:g}")
    made: dict = {}

    def connect():
        try:
            made["client"] = Client(scheduler, timeout=f"{timeout}s", set_as_default=False)
        except Exception as exc:  # noqa: BLE001  (reported below, in the main thread)
            made["error"] = exc

    thread = threading.Thread(target=connect, name="facesim-dask-connect", daemon=True)
    thread.start()
    thread.join(timeout + 2.0)
    if "client" in made:
        return made["client"]
    why = f"({type(made['error']).__name__})" if "error" in made else f"(no answer within {timeout:g} s)"
    raise FacesimError(f"--scheduler {scheduler}: cannot reach the Dask scheduler {why}")


def run_on_dask(client, function, argument_lists, on_result) -> None:
    """Map ``function`` over the argument lists (iterables) on a Dask client, at most
    WINDOW calls per worker in flight, calling ``on_result`` as each finishes; then close
    the client (and its LocalCluster, if it made one)."""
    from dask.distributed import as_completed as dask_completed

    cluster = getattr(client, "_facesim_cluster", None)
    try:
        window = WINDOW * max(1, len(client.scheduler_info().get("workers", {})))
        running = dask_completed()
        for arguments in zip(*argument_lists):
            running.add(client.submit(function, *arguments, pure=False))
            if running.count() >= window:
                on_result(next(running).result())
        for future in running:
            on_result(future.result())
    finally:
        client.close()
        if cluster is not None:
            cluster.close()


def write_manifest(directory: Path) -> Path:
    """The manifest, rebuilt from every label on disk, ordered by index."""
    labels = sorted((json.loads(p.read_text()) for p in (directory / "labels").glob("*.json")), key=lambda r: r["index"])
    rows = [{**r, "aus": json.dumps(r["aus"], sort_keys=True), "activations": json.dumps(r["activations"], sort_keys=True)}
            for r in labels]
    columns = ["id", "index", "seed", "status", "expression", "intensity", "aus", "activations", "yaw", "pitch", "light",
               *POSE_JITTER, "identity", "width", "height", "frames", "dt", "image", "sha256", "clip"]
    try:
        import pyarrow as pa
        import pyarrow.parquet as pq
    except ImportError:
        path = directory / "manifest.csv"
        with atomic_path(path) as tmp, tmp.open("w", newline="") as handle:
            writer = csv.DictWriter(handle, fieldnames=columns)
            writer.writeheader()
            writer.writerows({k: r.get(k) for k in columns} for r in rows)
        return path
    path = directory / "manifest.parquet"
    with atomic_path(path) as tmp:
        pq.write_table(pa.Table.from_pylist([{k: r.get(k) for k in columns} for r in rows]), tmp)
    return path


def read_manifest(path: Path) -> list[dict]:
    if path.suffix == ".parquet":
        import pyarrow.parquet as pq

        return pq.read_table(path).to_pylist()
    with path.open() as handle:
        return list(csv.DictReader(handle))


def check_settings(settings: DatasetSettings) -> None:
    """Every setting checked before anything is written (dataset.json records them)."""
    from .renderer.settings import BACKENDS, RenderSettings
    if settings.seed < 0:
        raise InputError(f"--seed: expected a non-negative integer, got {settings.seed}")
    RenderSettings(settings.width, settings.height, look=settings.look).for_face(settings.face)  # --size, --look
    if settings.backend not in ("auto",) + BACKENDS:
        raise InputError(f"--backend: expected auto, {' or '.join(BACKENDS)}, got {settings.backend!r}")


def build_dataset(directory: Path, n: int, settings: DatasetSettings, executor: str = "local", jobs: int = 2,
                  scheduler: str | None = None, advance=None, warn=None,
                  scheduler_timeout: float | None = None) -> Path:
    """Make (or finish) a dataset of ``n`` samples; returns the manifest's path. ``warn``
    receives one-line notices (--jobs capped to the cores)."""
    if executor not in ("local", "dask"):
        raise InputError(f"--executor: expected local or dask, got {executor!r}")
    if jobs < 1:
        raise InputError(f"--jobs: must be at least 1, got {jobs}")
    if scheduler and executor != "dask":
        raise InputError("--scheduler: only with --executor dask")
    if n <= 0:
        raise InputError(f"--n: the number of samples must be at least 1, got {n}")
    check_settings(settings)
    if scheduler is None:  # a cluster elsewhere has its own cores
        jobs = capped_jobs(jobs, warn)
    client = dask_client(scheduler, jobs, scheduler_timeout) if executor == "dask" else None  # fail before writing anything
    try:
        todo = _prepare(directory, n, settings)
    except BaseException:
        if client is not None:
            client.close()
        raise
    advance = advance or (lambda n=1: None)
    if client is not None:
        run_on_dask(client, make_sample, (repeat(str(directory)), todo, repeat(settings)), lambda _: advance())
    else:
        _run_local(directory, todo, settings, jobs, advance)
    return write_manifest(directory)


def dataset_sheet(directory: Path, output: Path, count: int = 12, columns: int = 4) -> None:
    """The first ``count`` samples in a labelled grid."""
    import imageio.v3 as iio

    from .export.plots import contact_sheet
    chosen = [r for r in read_manifest(next(directory.glob("manifest.*"))) if r["status"] == "ok"][:count]
    if not chosen:
        raise InputError(f"{directory}: no finished samples to show")

    def label(r):
        if r["expression"]:
            return f"{r['expression']} {float(r['intensity']):.2f}"
        aus = json.loads(r["aus"]) if isinstance(r["aus"], str) else r["aus"]
        return ", ".join(f"{au} {v:.1f}" for au, v in aus.items())

    contact_sheet([iio.imread(directory / r["image"]) for r in chosen], [label(r) for r in chosen], output, columns)
