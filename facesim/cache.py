"""Derived data kept between processes, as Numba keeps its compiled kernels: arrays that
take long to compute from the shipped data (the head's skin weights, facesim.face.figure), in
``$FACESIM_CACHE``, else ``$XDG_CACHE_HOME/facesim``, else ``~/.cache/facesim``.

An entry's name carries a hash of everything it was computed from, the code included, so
a changed input or a new facesim version computes a new entry instead of reading a stale
one. Entries are written under a temporary name and renamed into place; an entry that
cannot be read is computed again, and a cache that cannot be written is skipped: the
cache only ever saves time.
"""

from __future__ import annotations

import contextlib
import hashlib
import os
from pathlib import Path

import numpy as np


def directory() -> Path:
    if os.environ.get("FACESIM_CACHE"):
        return Path(os.environ["FACESIM_CACHE"])
    return Path(os.environ.get("XDG_CACHE_HOME") or Path.home() / ".cache") / "facesim"


def key(*parts: bytes) -> str:
    digest = hashlib.sha1()
    for part in parts:
        digest.update(hashlib.sha1(part).digest())
    return digest.hexdigest()


def cached_arrays(name: str, digest: str, compute, keep: int = 8) -> dict[str, np.ndarray]:
    """The arrays ``compute()`` returns (a dict of name to array), from the cache when an
    entry ``name``-``digest`` is there and readable, else computed and stored. A new entry
    makes the entries of ``name`` beyond the ``keep`` most recently used go (``_pruned``):
    each version of facesim, and each face, writes its own. An entry read is marked used
    (its modification time): the face rendered every day outlives a batch of other faces
    run after it, where pruning by when entries were written dropped it."""
    path = directory() / f"{name}-{digest}.npz"
    try:
        with np.load(path, allow_pickle=False) as stored:
            arrays = {k: stored[k] for k in stored.files}
    except Exception:  # absent, truncated or unreadable: computed again below
        pass
    else:
        with contextlib.suppress(OSError):  # a read-only cache is still read
            os.utime(path)
        return arrays
    arrays = compute()
    partial = path.with_name(f".{path.name}.partial-{os.getpid()}")
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        with open(partial, "wb") as handle:
            np.savez(handle, **arrays)
        os.replace(partial, path)
        _pruned(name, keep)
    except OSError:  # read-only home, full disk: run without the cache
        with contextlib.suppress(OSError):  # no partial file, or no directory to hold one
            partial.unlink()
    return arrays


def _pruned(name: str, keep: int) -> None:
    """Remove the entries of ``name`` but the ``keep`` most recently used (written or read).
    Only facesim's own entries (``name``-<40 hex digits>.npz) are touched; one another
    process removed first is skipped."""
    entries = []
    for path in directory().glob(f"{name}-*.npz"):
        digest = path.stem[len(name) + 1:]
        if len(digest) == 40 and all(c in "0123456789abcdef" for c in digest):
            with contextlib.suppress(OSError):
                entries.append((path.stat().st_mtime_ns, path))
    for _, path in sorted(entries, reverse=True)[keep:]:
        with contextlib.suppress(OSError):
            path.unlink()
