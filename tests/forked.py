"""`python -m facesim ...` for the suite, forked from a Python that has imported it.

The command-line tests run hundreds of facesim commands, each in a process of its own as
a user runs them; each paid for Python, NumPy, pydantic, Numba and facesim's imports and
Numba's first kernel (0.4-0.6 s of CPU before the command's own work: `validate` 0.78-0.93
s fresh against 0.26-0.28 s forked, 2026-12-07). A fork server per test worker pays that
once: a Python that has imported facesim's command line and the modules a render imports
(none of OpenGL; for the commands that read faces in images, ``PHOTOS``, MediaPipe's
face mesh too) and loaded one kernel, and for
each command forks a child that runs ``python -m facesim`` as the interpreter would (its
arguments, working directory and environment, its stdout and stderr to files, its exit
code from SystemExit or an uncaught exception, atexit at its end; its CPU time, counted
with the suite's subprocesses' in tests/conftest.py's table). The child is a fresh
process to everything a command sets up: nothing of OpenGL, no Numba threads, no
signal handler of facesim's is loaded or started before the fork.

A command whose environment differs from the server's (a test's ``env``: another cache,
another OpenGL platform, another threading layer, read when Python starts or a library
is imported) runs in a process of its own, as before.
"""

from __future__ import annotations

import atexit
import json
import os
import select
import shutil
import signal
import subprocess
import sys
import tempfile
import threading
from pathlib import Path

#: What the server runs: imports, one kernel loaded (Numba's typing set up), then a fork
#: per request line; the child takes the request's directory, environment and files.
SERVER = r"""
import json, os, runpy, sys
before = dict(os.environ)
import numpy as np
import facesim.cli
from facesim.config import prepare_numba
prepare_numba()
from facesim.geometry import _vertex_normals
_vertex_normals(np.zeros((3, 3)), np.array([[0, 1, 2]], dtype=np.int64), np.empty((3, 3)))
added = {k: v for k, v in os.environ.items() if k not in before}  # what facesim set for itself (prepare_numba)
started = dict(os.environ)  # the environment a command starts in (OpenCV, imported below, adds its own)
import facesim.animation.simulate, facesim.export.output, facesim.face.figure  # a render's modules, none of OpenGL
if sys.argv[1:] == ["photos"]:  # the server of the commands that read faces in images, which import it first
    from facesim.face.photo import quiet_stderr
    with quiet_stderr():
        import mediapipe.python.solutions.face_mesh
requests, answers = os.fdopen(os.dup(0), "r"), os.fdopen(os.dup(1), "w")
null = os.open(os.devnull, os.O_RDWR)
os.dup2(null, 0)
os.dup2(null, 1)
answers.write(json.dumps(dict(env=started, added=added)) + "\n")
answers.flush()
for line in requests:
    request = json.loads(line)
    pid = os.fork()
    if pid == 0:
        requests.close()
        answers.close()
        os.chdir(request["cwd"])
        for fd, name in ((1, "stdout"), (2, "stderr")):
            opened = os.open(request[name], os.O_WRONLY | os.O_CREAT | os.O_TRUNC)
            os.dup2(opened, fd)
            os.close(opened)
        os.environ.clear()
        os.environ.update({**added, **request["env"]})
        sys.argv = [sys.executable, *request["args"]]
        runpy.run_module("facesim", run_name="__main__", alter_sys=True)
        sys.exit(0)
    answers.write(f"{pid}\n")
    answers.flush()
    _, status, usage = os.wait4(pid, 0)
    answers.write(f"{os.waitstatus_to_exitcode(status)} {usage.ru_utime + usage.ru_stime}\n")
    answers.flush()
"""

#: Variables that may differ between the server and a command: pytest's name for the
#: test, and OpenGL's platform, which facesim sets in a process that draws
#: (facesim.renderer.backend) and which the server, having loaded nothing of OpenGL, has
#: not read. Any other difference (read as Python started or a library loaded) runs the
#: command in a process of its own.
PASSED_ON = ("PYTEST_CURRENT_TEST", "PYOPENGL_PLATFORM", "EGL_PLATFORM")


class _Server:
    def __init__(self, kind: str):
        self.process = subprocess.Popen([sys.executable, "-c", SERVER, kind], stdin=subprocess.PIPE, stdout=subprocess.PIPE,
                                        text=True, env=dict(os.environ))
        self.folder = Path(tempfile.mkdtemp(prefix="facesim-forked-"))
        self.lock = threading.Lock()
        started = json.loads(self._line(120))  # its environment once set up, and what facesim added to it
        self.env, self.added = self._comparable(started["env"]), started["added"]

    @staticmethod
    def _comparable(env) -> dict:
        return {k: v for k, v in env.items() if k not in PASSED_ON}

    def serves(self, env) -> bool:
        """Whether a command in ``env`` would start as the server did (what facesim adds
        to a process's environment for itself added to ``env`` as a fresh one would)."""
        return self.process.poll() is None and self._comparable({**self.added, **env}) == self.env

    def _line(self, timeout: float) -> str:
        ready, _, _ = select.select([self.process.stdout], [], [], timeout)
        if not ready:
            raise TimeoutError
        return self.process.stdout.readline().strip()

    def run(self, args: list[str], cwd, env: dict, timeout: float) -> subprocess.CompletedProcess:
        command = [sys.executable, "-m", "facesim", *args]  # what the result names, as subprocess.run's would
        with self.lock:
            out, err = self.folder / "stdout", self.folder / "stderr"
            request = dict(args=args, cwd=str(cwd or os.getcwd()), env=dict(env), stdout=str(out), stderr=str(err))
            self.process.stdin.write(json.dumps(request) + "\n")
            self.process.stdin.flush()
            pid = int(self._line(30))
            try:
                code, seconds = self._line(timeout).split()
            except TimeoutError:
                os.kill(pid, signal.SIGKILL)
                self._line(30)
                raise subprocess.TimeoutExpired(command, timeout) from None
            global cpu
            cpu += float(seconds)
            return subprocess.CompletedProcess(command, int(code), out.read_text(errors="replace"),
                                               err.read_text(errors="replace"))

    def close(self) -> None:
        self.process.stdin.close()
        self.process.wait(timeout=30)
        shutil.rmtree(self.folder, ignore_errors=True)


#: The commands that read faces in images (MediaPipe's face mesh, which loads OpenGL's
#: libraries of its own) before anything else: forked from a server that has imported
#: it (0.7 s each), as they would import it first; any other command from one that has not.
PHOTOS = (("face", "from-photo"), ("mesh", "from-photo"), ("capture",))
_servers: dict[str, _Server] = {}
#: CPU time (user + system, s) of the commands forked so far, with their own children's
#: (ffmpeg's, a batch's workers'): the suite's table counts it with its subprocesses'.
cpu = 0.0


def facesim_process(args: list, cwd=None, env=None, timeout: float = 600) -> subprocess.CompletedProcess:
    """``python -m facesim *args`` (captured, text), forked from the server when ``env``
    is this process's, else in a process of its own."""
    args = list(map(str, args))
    env = dict(os.environ) if env is None else env
    kind = "photos" if any(tuple(args[:len(command)]) == command for command in PHOTOS) else "commands"
    if kind not in _servers:
        _servers[kind] = _Server(kind)
        atexit.register(_servers[kind].close)
    if _servers[kind].serves(env):
        return _servers[kind].run(args, cwd, env, timeout)
    return subprocess.run([sys.executable, "-m", "facesim", *args], capture_output=True, text=True, cwd=cwd, env=env,
                          timeout=timeout)
