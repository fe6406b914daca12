"""The on-disk cache of derived data (facesim.cache): computed once, read back equal,
recomputed when an entry is damaged, skipped when it cannot be written."""

import os
import subprocess
import sys
import textwrap

import numpy as np

from facesim import cache


def test_an_entry_is_computed_once_and_read_back(tmp_path, monkeypatch):
    monkeypatch.setenv("FACESIM_CACHE", str(tmp_path))
    calls = []

    def compute():
        calls.append(1)
        return {"weights": np.arange(12.0).reshape(3, 4), "rows": np.array([4, 5, 6])}

    digest = cache.key(b"inputs", b"code")
    first = cache.cached_arrays("thing", digest, compute)
    second = cache.cached_arrays("thing", digest, compute)
    assert len(calls) == 1
    for k in first:
        assert np.array_equal(first[k], second[k]) and first[k].dtype == second[k].dtype
    assert [p.name for p in tmp_path.iterdir()] == [f"thing-{digest}.npz"]  # no partial file left
    assert cache.key(b"inputs", b"other code") != digest

    (tmp_path / f"thing-{digest}.npz").write_bytes(b"PK\x03\x04 truncated")
    assert np.array_equal(cache.cached_arrays("thing", digest, compute)["rows"], [4, 5, 6])
    assert len(calls) == 2


def test_an_unwritable_cache_only_costs_time(tmp_path, monkeypatch):
    blocked = tmp_path / "file"
    blocked.write_text("not a directory")
    monkeypatch.setenv("FACESIM_CACHE", str(blocked / "facesim"))
    arrays = cache.cached_arrays("thing", "0", lambda: {"a": np.ones(3)})
    assert np.array_equal(arrays["a"], np.ones(3)) and blocked.read_text() == "not a directory"


def test_the_heads_skin_weights_read_from_the_cache_are_the_computed_ones(tmp_path, monkeypatch):
    from facesim.config import HEAD
    from facesim.face import figure
    from facesim.face.head import load_head

    monkeypatch.setenv("FACESIM_CACHE", str(tmp_path))
    monkeypatch.setattr(figure, "_FOLLOW", {})
    head = load_head(HEAD)
    rows, weights = figure.skin_follow(head)  # computed and stored
    assert len(os.listdir(tmp_path)) == 1
    monkeypatch.setattr(figure, "_FOLLOW", {})
    again_rows, again = figure.skin_follow(head)  # read
    assert np.array_equal(rows, again_rows)
    assert all(np.array_equal(a, b) and a.dtype == b.dtype for a, b in zip(weights[:3], again[:3]))
    assert weights.shape == again.shape == (len(rows), len(head.landmarks)) and len(weights.data) > 0


def test_the_heads_figure_read_from_the_cache_is_the_built_one(tmp_path, monkeypatch):
    """A warm render reads the head's figure from the cache (figure._stored_figure): every
    array of it as built, to the bit and the dtype; another identity's head is another entry."""
    from dataclasses import fields

    from facesim.animation.simulate import model_for
    from facesim.animation.spec import Spec
    from facesim.face import figure

    def same(a, b, where="figure"):
        if isinstance(a, np.ndarray) or isinstance(b, np.ndarray):
            assert isinstance(a, np.ndarray) and isinstance(b, np.ndarray) and a.dtype == b.dtype, where
            assert np.array_equal(a, b), where
        elif isinstance(a, (tuple, list)):
            assert type(a) is type(b) and len(a) == len(b), where
            for k, (x, y) in enumerate(zip(a, b)):
                same(x, y, f"{where}[{k}]")
        elif hasattr(a, "__dataclass_fields__"):
            assert type(a) is type(b), where
            for f in fields(a):
                same(getattr(a, f.name), getattr(b, f.name), f"{where}.{f.name}")
        else:
            assert a == b and type(a) is type(b), (where, a, b)

    monkeypatch.setenv("FACESIM_CACHE", str(tmp_path))
    model = model_for(Spec(name="figure"))
    built = figure.head_figure(model.mesh.head, model)
    stored = figure._stored_figure(model)  # built and stored
    read = figure._stored_figure(model)  # read back
    entries = sorted(p.name for p in tmp_path.iterdir() if p.name.startswith("figure-"))
    assert len(entries) == 1
    same(built, stored)
    same(built, read)
    figure._stored_figure(model_for(Spec(name="figure", identity=7)))
    assert len([p for p in tmp_path.iterdir() if p.name.startswith("figure-")]) == 2


COMPILED = """
import importlib, sys
import numpy as np
numerics = importlib.import_module(sys.argv[1] + ".physics.numerics")
assert numerics._not_finite(np.array([[0.0, 1.0, 2.0], [3.0, np.nan, 5.0]])) == 1
print(sum(numerics._not_finite.stats.cache_hits.values()), sum(numerics._not_finite.stats.cache_misses.values()))
"""


def test_a_copy_of_the_same_code_elsewhere_loads_the_compiled_kernels(tmp_path):
    """A second checkout, a wheel in a virtual environment, a clone in CI: the same
    facesim code anywhere finds the kernels another copy compiled (facesim.config's
    CodeKeyedLocator; Numba alone files them by directory and compiled all again)."""
    import shutil
    import subprocess
    import sys

    from facesim.config import PACKAGE_DIR

    copy = tmp_path / "elsewhere"
    shutil.copytree(PACKAGE_DIR, copy / "facesim", ignore=shutil.ignore_patterns("__pycache__", "meshes", "expressions"))

    def hits_and_misses(root, package="facesim"):
        env = dict(os.environ, PYTHONPATH=str(root), NUMBA_CACHE_DIR=str(tmp_path / "cache"), FACESIM_SHIPPED_KERNELS="0")
        result = subprocess.run([sys.executable, "-c", COMPILED, package], capture_output=True, text=True, env=env,
                                cwd=tmp_path, timeout=300)
        assert result.returncode == 0, result.stderr[-2000:]
        return tuple(int(n) for n in result.stdout.split())

    assert hits_and_misses(PACKAGE_DIR.parent) == (0, 1)  # compiled, into an empty cache
    assert hits_and_misses(copy) == (1, 0)  # the copy loads it
    assert [p.name.startswith("numba-") for p in (tmp_path / "cache").iterdir()] == [True]
    # an edit to code without kernels (the command line) keeps them; one to a kernel's
    # file compiles again (facesim.config._code_digest)
    with (copy / "facesim" / "cli.py").open("a") as cli:
        cli.write("\n# an edit\n")
    assert hits_and_misses(copy) == (1, 0)
    with (copy / "facesim" / "physics" / "numerics.py").open("a") as kernels:
        kernels.write("\n# an edit\n")
    assert hits_and_misses(copy) == (0, 1)
    # the same code under another name compiles its own: a kernel names its module
    (copy / "facesim").rename(copy / "vendored")
    assert hits_and_misses(copy, "vendored") == (0, 1)


def test_a_name_keeps_its_latest_entries_and_nothing_else_is_touched(tmp_path, monkeypatch):
    """Each facesim version, and each face, writes entries of its own: a new one makes the
    oldest of its name go, and never a file facesim did not write."""
    monkeypatch.setenv("FACESIM_CACHE", str(tmp_path))
    others = [tmp_path / "thing-notes.npz", tmp_path / f"other-{'0' * 40}.npz"]
    for path in others:
        path.write_bytes(b"kept")
    digests = [cache.key(str(k).encode()) for k in range(5)]
    for k, digest in enumerate(digests):
        cache.cached_arrays("thing", digest, lambda: {"a": np.full(2, float(k))}, keep=3)
        os.utime(tmp_path / f"thing-{digest}.npz", ns=(k * 10**9, k * 10**9))  # written a second apart
    assert sorted(p.name for p in tmp_path.glob("thing-*.npz") if p not in others) == sorted(
        f"thing-{d}.npz" for d in digests[2:])
    assert all(path.read_bytes() == b"kept" for path in others)


def test_an_entry_read_outlives_entries_written_after_it_but_not_read(tmp_path, monkeypatch):
    """Pruning keeps the entries most recently used: the face rendered every day (read
    from the cache each time) is not dropped by a batch of other faces run after it."""
    monkeypatch.setenv("FACESIM_CACHE", str(tmp_path))
    digests = [cache.key(str(k).encode()) for k in range(5)]
    computed = []

    def entry(k):
        return cache.cached_arrays("thing", digests[k], lambda: computed.append(k) or {"a": np.full(2, float(k))},
                                   keep=3)

    for k in range(3):
        entry(k)
        os.utime(tmp_path / f"thing-{digests[k]}.npz", ns=(k * 10**9, k * 10**9))  # written a second apart
    assert entry(0)["a"][0] == 0.0  # read, not computed: now the most recently used
    entry(3)  # a fourth written: the least recently used (1) goes
    assert sorted(p.name for p in tmp_path.glob("thing-*.npz")) == sorted(f"thing-{digests[k]}.npz" for k in (0, 2, 3))
    entry(0)
    assert computed == [0, 1, 2, 3]


def test_the_heads_preconditioner_read_from_the_cache_is_the_factorised_one(tmp_path, monkeypatch):
    """A fresh process reads the implicit step's factor (facesim.physics.model.Model.preconditioner)
    instead of factorising again: the same arrays; another step size, another entry."""
    from facesim.config import HEAD, HEAD_MUSCLES
    from facesim.face.loading import load_face_model
    monkeypatch.setenv("FACESIM_CACHE", str(tmp_path))
    model = load_face_model(HEAD.resolve(), HEAD_MUSCLES.resolve())
    h = 0.0371  # a step no other test factorises this model at in this process
    computed = model.preconditioner(h)
    assert len(list(tmp_path.glob("preconditioner-*.npz"))) == 1
    del model.factors[h]  # this step only: the model is shared with other tests in the process
    read = model.preconditioner(h)
    assert read is not computed and computed.lower_block.size > 0
    for a, b in zip(computed, read):
        assert a.dtype == b.dtype and np.array_equal(a, b)
    model.preconditioner(h / 2)
    assert len(list(tmp_path.glob("preconditioner-*.npz"))) == 2


def test_kernels_made_later_in_a_process_are_kept_with_the_others(tmp_path):
    """facesim's kernel folder is fixed when Numba is set up (facesim.config._key_numba_cache):
    a kernel module imported, or a serial twin made, after FACESIM_CACHE changes is cached
    beside the others, not in the new folder (a test pointing FACESIM_CACHE at its own files
    had a twin compiled there, and the suite's next user of it waited 47-60 s)."""
    code = textwrap.dedent("""
        import os, sys
        import facesim.physics.springs  # Numba set up for facesim: its kernels' folder
        os.environ["FACESIM_CACHE"] = sys.argv[1]
        from numba.core.registry import CPUDispatcher
        from facesim.renderer import filters
        kernel = next(v for v in vars(filters).values() if isinstance(v, CPUDispatcher))
        print(kernel._cache._cache_path)
    """)
    env = {k: v for k, v in os.environ.items() if k not in ("FACESIM_CACHE", "NUMBA_CACHE_DIR")}
    result = subprocess.run([sys.executable, "-c", code, str(tmp_path)], capture_output=True, text=True, env=env,
                            timeout=120)
    assert result.returncode == 0, result.stderr[-2000:]
    path = result.stdout.split()[-1]
    assert not path.startswith(str(tmp_path)) and "numba-" in path
