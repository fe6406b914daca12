"""Compile facesim's kernels ahead, for the package to ship: `make kernels`; and measure
the capture's basis on the default head (facesim.capture.solver.SHIPPED_BASIS), which ships too.

A new user's first `facesim render` compiled every Numba kernel it ran, about a minute on
two cores (issue 45). facesim compiles for the CPU's baseline (facesim.config._portable_target),
so kernels compiled here run on any machine of the same architecture; this script runs
the commands a new user starts with in fresh processes with an empty cache, the shipped
kernels turned off, then packs the cache folder they filled into
``facesim/compiled/kernels.tar.xz`` with ``kernels.json``: the hash of the code, Numba,
Python, machine and CPU it holds kernels for. facesim unpacks it into its cache on its
first run when all five match (facesim.config._install_shipped_kernels); any edit to a
file with kernels changes the hash, and tests/test_compile.py fails until this is run
again.
"""

import json
import os
import subprocess
import sys
import tarfile
import tempfile
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
#: What a new user runs first (the README): happy on the head to MP4 and to one PNG,
#: and on the Hopper face with the thesis's muscles; then a mesh large enough for the
#: kernels' parallel twins (facesim.physics.twins: at least PARALLEL_FROM vertices), the
#: Hopper face Loop-subdivided twice (6,990 vertices), which compile for about 50 s on
#: a large mesh's first run, in a new user's hands as in the suite's first run on a new machine.
#: Then a photo's (the README's next commands, with the photo extra's MediaPipe): the face
#: fitted to scikit-image's astronaut and baked from it (the back-projection's kernels,
#: 3-4 s of a new user's first `face from-photo`), drawn --onto the photo (the filters on
#: a frame with alpha, about 2 s), and a frame supersampled (its averaging down).
COMMANDS = [
    ["render", "expressions/happy.yaml", "-o", "{out}/happy.mp4"],
    ["render", "expressions/surprise.yaml", "-o", "{out}/surprise.png"],
    ["render", "expressions/happy.yaml", "--mesh", "meshes/face.obj", "-o", "{out}/hopper.gif", "--size", "64x64"],
    ["render", "expressions/happy.yaml", "--mesh", "{out}/fine.obj", "--muscles", "{out}/fine.muscles.yaml",
     "-o", "{out}/fine.npz"],
    ["face", "from-photo", "{out}/astronaut.png", "-o", "{out}/astronaut"],
    ["render", "expressions/happy.yaml", "--face", "{out}/astronaut", "--onto", "{out}/astronaut.png",
     "-o", "{out}/onto.png", "--frame", "34"],
    ["render", "expressions/surprise.yaml", "--supersample", "-o", "{out}/supersampled.png"],
]
#: Writes the photo of the photo's commands.
PHOTO = """
import sys, imageio.v3 as iio
from skimage import data
iio.imwrite(sys.argv[1] + "/astronaut.png", data.astronaut())
"""
#: Writes the large mesh of the last command, and the head's calibrated muscles carried to it by position.
FINE_MESH = """
import sys
from facesim.config import DEFAULT_MUSCLES, HOPPER_MESH
from facesim.face.loading import load_mesh, write_obj
from facesim.face.muscle_file import carried_text
from facesim.physics.mesh import subdivide
base = load_mesh(HOPPER_MESH)
write_obj(sys.argv[1] + "/fine.obj", subdivide(base, 2))
open(sys.argv[1] + "/fine.muscles.yaml", "w").write(carried_text(DEFAULT_MUSCLES, base))
"""

#: Measures the default head's capture basis (facesim.capture.solver.head_basis: its shapes
#: and turns rendered and read by MediaPipe, about 20 s) and writes it, with the key it was
#: measured from, where the package ships it (SHIPPED_BASIS); the floats as float32.
CAPTURE_BASIS = """
import os, sys
import numpy as np
from facesim.animation.spec import Spec
from facesim.capture import solver
spec = Spec(name="capture")
rest, _ = solver._landmarks_at_rest(spec)
arrays = {name: value.astype(np.float32) for name, value in solver._rendered(spec, rest, shapes=True).items()}
partial = str(solver.SHIPPED_BASIS) + ".partial.npz"
np.savez_compressed(partial, key=np.array(solver.basis_key(spec, rest)), **arrays)
os.replace(partial, solver.SHIPPED_BASIS)
print(f"wrote {solver.SHIPPED_BASIS}: {os.path.getsize(solver.SHIPPED_BASIS) / 1e6:.1f} MB")
"""


def _tar_info(info: tarfile.TarInfo) -> tarfile.TarInfo:
    """The same archive for the same kernels: no owner, no time."""
    info.uid = info.gid = 0
    info.uname = info.gname = ""
    info.mtime = 0
    return info


def main() -> int:
    if sys.argv[1:] == ["--capture-basis"]:  # the basis alone: after an edit to the capture's solver
        return subprocess.run([sys.executable, "-c", CAPTURE_BASIS], cwd=ROOT, check=True).returncode
    with tempfile.TemporaryDirectory() as scratch:
        scratch = Path(scratch)
        env = dict(os.environ, NUMBA_CACHE_DIR=str(scratch / "numba"), FACESIM_CACHE=str(scratch / "facesim"),
                   FACESIM_SHIPPED_KERNELS="0")
        env.pop("NUMBA_CPU_NAME", None)
        env.pop("NUMBA_CPU_FEATURES", None)
        subprocess.run([sys.executable, "-c", FINE_MESH, str(scratch)], cwd=ROOT, env=env, check=True)
        subprocess.run([sys.executable, "-c", PHOTO, str(scratch)], cwd=ROOT, env=env, check=True)
        for command in COMMANDS:
            command = [sys.executable, "-m", "facesim", *(part.format(out=scratch) for part in command)]
            print(" ".join(command[2:]), flush=True)
            subprocess.run(command, cwd=ROOT, env=env, check=True)
        key = subprocess.run([sys.executable, "-c", "import json, facesim.config as c; "
                              "print(json.dumps(c.shipped_kernels_key()))"],
                             cwd=ROOT, env=env, check=True, capture_output=True, text=True)
        key = json.loads(key.stdout)
        if key["cpu"] != "generic":
            raise SystemExit(f"the kernels were compiled for {key['cpu']}, not the baseline: unset NUMBA_CPU_NAME")
        (folder,) = (scratch / "numba").iterdir()
        target = ROOT / "facesim" / "compiled"
        target.mkdir(exist_ok=True)
        partial = target / "kernels.tar.xz.partial"
        with tarfile.open(partial, "w:xz") as tar:
            for path in sorted(folder.rglob("*")):
                if path.is_file():
                    tar.add(path, arcname=path.relative_to(folder).as_posix(), filter=_tar_info)
        os.replace(partial, target / "kernels.tar.xz")
        (target / "kernels.json").write_text(json.dumps(key, indent=1) + "\n")
        files = sum(1 for path in folder.rglob("*") if path.is_file())
        print(f"wrote {target / 'kernels.tar.xz'}: {files} files, "
              f"{(target / 'kernels.tar.xz').stat().st_size / 1e6:.1f} MB, for {key}")
        subprocess.run([sys.executable, "-c", CAPTURE_BASIS], cwd=ROOT, env=env, check=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
