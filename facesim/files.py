"""Writing files without losing any: one rule for every output facesim makes.

1. Before any work, :func:`check_destination` decides whether ``path`` may be written: it
   must not exist, or, with ``--force``, be something facesim itself wrote (a file of the
   kind asked for; a directory whose manifest, ``MANIFEST``, lists every file in it with
   the hash it still has), never the working directory or one of its parents.
2. :func:`atomic_path` yields a temporary name in the destination directory, creating the
   missing parent directories it needs (and removing them again if the write fails).
3. The caller writes there; an optional ``verify`` reads it back (an MP4 that ffmpeg can
   decode, a complete NPZ) before anything is replaced.
   A directory gets its manifest before it is verified.
4. The temporary is renamed into place: a file with ``link`` so that an output written
   meanwhile by another run is never clobbered without ``--force``; a replaced directory is
   first moved aside, so the old output exists until the new one does.

Any failure, Ctrl-C, SIGTERM or SIGHUP (an exception within :func:`handling_termination`)
removes the temporary; a write the disk refuses is one line, not a traceback. A signal's
exception can land inside library code that swallows it (a bare ``except``) or turns it
into another error (ctypes, converting an OpenGL call's arguments): so the signal is also
recorded, :func:`check_terminated` raises it again at facesim's own checkpoints (each
frame, and before anything is renamed into place), and :func:`terminating_signal` lets the
command line report any error that follows it as the signal it was.
"""

from __future__ import annotations

import errno
import hashlib
import json
import os
import shutil
import signal
import sys
from contextlib import contextmanager
from pathlib import Path

from .errors import FacesimError, InputError

#: The files facesim writes, by suffix, with the bytes each kind starts with (at offset).
MAGIC = {".mp4": (4, b"ftyp"), ".glb": (0, b"glTF"), ".pc2": (0, b"POINTCACHE2"), ".gif": (0, b"GIF8"), ".npz": (0, b"PK"), ".png": (0, b"\x89PNG"),
         ".obj": None, ".yaml": None, ".json": None, ".csv": None, ".parquet": (0, b"PAR1"), ".usdc": (0, b"PXR-USDC")}
#: What facesim writes into every directory it makes (a frames directory, a face
#: directory): each file's SHA-256. ``--force`` replaces a directory only while it holds
#: exactly those files with those contents, so a user's file that a name would pass for
#: facesim's (``frame_0000.png``, ``head.obj``) is never taken, nor an output edited since.
MANIFEST = "facesim-manifest.json"


class WriteError(FacesimError):
    """The destination refused the write (full disk, permissions, ...): exit code 1."""

    exit_code = 1


class Terminated(BaseException):
    """SIGTERM or SIGHUP arrived: unwind like Ctrl-C so every temporary is removed."""

    def __init__(self, signum: int):
        super().__init__(signal.Signals(signum).name)
        self.signum = signum


#: The signals received within :func:`handling_termination`, first first.
_received: list[int] = []
#: Within :func:`signals_deferred`: a signal is recorded, not raised.
_deferred = False


@contextmanager
def handling_termination():
    """Within the block SIGTERM and SIGHUP raise :class:`Terminated` in the main thread,
    Ctrl-C (SIGINT, unless the process was started with it ignored) KeyboardInterrupt as
    Python's own handler does, and each is recorded; the handlers before it, and an empty
    record, are restored after. The record is what lets :func:`check_terminated` stop the
    work when library code swallowed the exception (CI saw a render finish all 3,000
    frames and exit 0 after its Ctrl-C)."""
    saved = {signum: signal.getsignal(signum) for signum in (signal.SIGTERM, signal.SIGHUP, signal.SIGINT)}

    def raise_terminated(signum, _frame):
        _received.append(signum)
        if not _deferred:
            raise _exception_for(signum)

    unraisable = sys.unraisablehook

    def swallowed(event):
        """Where Python cannot raise (an at-fork handler, a finaliser), the signal's
        exception is printed as "Exception ignored" with a traceback: a SIGTERM while the
        MP4's encoder was being started did that (CI). It is recorded, and
        check_terminated raises it again where the work can stop."""
        if not (isinstance(event.exc_value, (Terminated, KeyboardInterrupt)) and _received):
            unraisable(event)

    _received.clear()
    for signum, handler in saved.items():
        if signum != signal.SIGINT or handler is signal.default_int_handler:
            signal.signal(signum, raise_terminated)
    sys.unraisablehook = swallowed
    try:
        yield
    finally:
        for signum, handler in saved.items():
            signal.signal(signum, handler)
        sys.unraisablehook = unraisable
        _received.clear()


@contextmanager
def signals_deferred():
    """Within the block a signal is only recorded; :func:`check_terminated` after it
    raises it. For starting a child process that must then be closed: a SIGTERM raised
    while ffmpeg was being started left the encoder running with no one to close it,
    and it wrote its file after facesim had removed the temporary (CI)."""
    global _deferred
    outer, _deferred = _deferred, True
    try:
        yield
    finally:
        _deferred = outer


def terminating_signal() -> int | None:
    """The first SIGTERM, SIGHUP or SIGINT received, or None."""
    return _received[0] if _received else None


def check_terminated() -> None:
    """Raise :class:`Terminated` (KeyboardInterrupt for Ctrl-C) again if a signal arrived
    whose exception library code swallowed: the work stops here, not at the end with its
    output written."""
    signum = terminating_signal()
    if signum is not None:
        raise _exception_for(signum)


def _exception_for(signum: int) -> BaseException:
    """What a signal raises within :func:`handling_termination`: KeyboardInterrupt for
    Ctrl-C, as Python's own handler does, :class:`Terminated` for the others."""
    return KeyboardInterrupt() if signum == signal.SIGINT else Terminated(signum)


def _sha256(path: Path) -> str:
    digest = hashlib.sha256()
    with path.open("rb") as handle:
        for block in iter(lambda: handle.read(1 << 20), b""):
            digest.update(block)
    return digest.hexdigest()


def write_manifest(directory: Path) -> None:
    """``MANIFEST`` in ``directory``: the SHA-256 of every file facesim wrote there."""
    files = {p.name: _sha256(p) for p in sorted(directory.iterdir()) if p.name != MANIFEST}
    (directory / MANIFEST).write_text(json.dumps({"written_by": "facesim", "files": files}, indent=1) + "\n")


def _written_by_facesim(directory: Path) -> bool:
    """Whether ``directory`` holds exactly what its manifest lists, each file unchanged."""
    try:
        listed = json.loads((directory / MANIFEST).read_text())["files"]
        present = {p.name for p in directory.iterdir() if p.name != MANIFEST}
        return (isinstance(listed, dict) and present == set(listed)
                and all((directory / n).is_file() and not (directory / n).is_symlink()
                        and _sha256(directory / n) == h for n, h in listed.items()))
    except (OSError, ValueError, KeyError, TypeError):
        return False


def _is_facesim_output(path: Path, directory: bool) -> bool:
    """Whether an existing ``path`` is something facesim wrote and ``--force`` may replace:
    a directory by its manifest, a file by the bytes its kind starts with."""
    if path.is_symlink():
        return False
    if directory:
        return path.is_dir() and _written_by_facesim(path)
    if not path.is_file():
        return False
    magic = MAGIC.get(path.suffix.lower(), (0, b""))
    if magic is None:  # a text kind: the suffix says it
        return True
    offset, start = magic
    with path.open("rb") as handle:
        head = handle.read(offset + len(start))
    return head[offset:] == start


def check_destination(path: Path, force: bool, directory: bool = False) -> None:
    """Raise InputError unless ``path`` may be written (step 1 of the module's rule)."""
    resolved = path.resolve()
    cwd = Path.cwd().resolve()
    if resolved == cwd or resolved in cwd.parents:
        raise InputError(f"{path}: is the working directory or one of its parents; name a new output")
    if not (path.exists() or path.is_symlink()) or (directory and _empty_directory(path)):
        _check_parent(path)
        return
    if not force:
        raise InputError(f"{path}: already exists (use --force to overwrite)")
    if not _is_facesim_output(path, directory):
        what = f"a directory facesim wrote, unchanged since (its {MANIFEST} says)" if directory \
            else f"a {path.suffix or 'file'} file facesim wrote"
        raise InputError(f"{path}: exists and is not {what}; --force replaces only facesim's own outputs, "
                         "so move or remove it yourself")
    _check_parent(path)


def _empty_directory(path: Path) -> bool:
    """An existing directory with nothing in it: a frames output may go there."""
    return path.is_dir() and not path.is_symlink() and not any(path.iterdir())


def _check_parent(path: Path) -> None:
    """The nearest existing ancestor must be a writable directory."""
    parent = path.absolute().parent
    while not parent.exists():
        parent = parent.parent
    if not parent.is_dir() or not _writable(parent):
        raise InputError(f"{path}: output directory is not writable")


def _writable(directory: Path) -> bool:
    """Try it: permission bits do not tell for root or read-only file systems."""
    import tempfile

    try:
        with tempfile.TemporaryFile(dir=directory):
            return True
    except OSError:
        return False


@contextmanager
def atomic_path(path: str | Path, directory: bool = False, replace: bool = True, verify=None):
    """Yield a temporary sibling of ``path`` (a directory if ``directory``); when the block
    succeeds, run ``verify(tmp)`` and rename the temporary to ``path``.

    ``replace`` allows replacing an existing output (``--force``, or files facesim owns
    such as a dataset's manifest); without it a ``path`` that appeared meanwhile is an
    error. The temporary name keeps the suffix, so writers that choose a format by
    extension still work.
    """
    path = Path(path)
    created = _make_parents(path)
    tmp = path.with_name(f".{path.stem}.partial-{os.getpid()}{path.suffix}")
    try:
        if directory:
            tmp.mkdir()
        yield tmp
        check_terminated()
        if directory:
            write_manifest(tmp)
        if verify is not None:
            try:
                verify(tmp)
            except WriteError as exc:
                raise WriteError(f"{path}: {exc}; nothing was written") from None
        check_terminated()
        _move_into_place(tmp, path, directory, replace)
    except BaseException as exc:
        if tmp.is_dir() and not tmp.is_symlink():
            shutil.rmtree(tmp, ignore_errors=True)
        else:
            tmp.unlink(missing_ok=True)
        for made in created:  # innermost first, and only if still empty
            try:
                made.rmdir()
            except OSError:
                break
        if isinstance(exc, OSError):
            reason = exc.strerror or (str(exc).strip().splitlines() or [type(exc).__name__])[0]
            raise WriteError(f"{path}: cannot write ({reason}); nothing was written") from None
        raise


def _make_parents(path: Path) -> list[Path]:
    """Create the missing parents of ``path``; return them, innermost first."""
    missing = []
    parent = path.absolute().parent
    while not parent.exists():
        missing.append(parent)
        parent = parent.parent
    made = []
    try:
        for directory in reversed(missing):
            try:
                directory.mkdir()
                made.append(directory)
            except FileExistsError:  # another worker of the same run made it
                pass
    except OSError as exc:
        raise WriteError(f"{path}: cannot create the output directory ({exc.strerror})") from None
    return made[::-1]


def _move_into_place(tmp: Path, path: Path, directory: bool, replace: bool) -> None:
    exists = path.exists() or path.is_symlink()
    replace = replace or (directory and _empty_directory(path))
    if exists and not replace:
        raise InputError(f"{path}: appeared while facesim was writing it (another run?); use --force to overwrite")
    if directory:
        if exists:
            aside = path.with_name(f".{path.name}.replaced-{os.getpid()}")
            os.replace(path, aside)
            os.replace(tmp, path)
            shutil.rmtree(aside, ignore_errors=True)
        else:
            os.rename(tmp, path)
        return
    if replace:
        os.replace(tmp, path)
        return
    try:
        os.link(tmp, path)  # fails if path exists: never clobbers what another run wrote
    except FileExistsError:
        raise InputError(f"{path}: appeared while facesim was writing it (another run?); use --force to overwrite") from None
    except OSError as exc:
        if exc.errno not in (errno.EPERM, errno.ENOTSUP, errno.EXDEV):
            raise
        os.replace(tmp, path)  # a file system without hard links
    tmp.unlink(missing_ok=True)
