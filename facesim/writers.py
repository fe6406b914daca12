"""Output writers: PNG sequences, MP4, GIF and raw NPZ, each written under a temporary
name and renamed into place only when complete, so that a failure or Ctrl-C never leaves a
half-written output behind.
"""

from __future__ import annotations

import os
import shutil
from contextlib import contextmanager
from pathlib import Path


@contextmanager
def atomic_path(path: str | Path, directory: bool = False):
    """Yield a temporary sibling of ``path``; rename it to ``path`` if the block succeeds.

    The temporary name keeps the suffix so that writers choosing a format by extension
    still work.
    """
    path = Path(path)
    tmp = path.with_name(f".{path.stem}.partial-{os.getpid()}{path.suffix}")
    if directory:
        tmp.mkdir(parents=False)
    try:
        yield tmp
        if path.is_dir() and not path.is_symlink():
            shutil.rmtree(path)
        os.replace(tmp, path)
    except BaseException:
        if tmp.is_dir():
            shutil.rmtree(tmp, ignore_errors=True)
        else:
            tmp.unlink(missing_ok=True)
        raise
