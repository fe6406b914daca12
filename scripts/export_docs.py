"""The pictures of docs/export.md (``make docs``): facesim's GLBs as other tools show
them. Happy's and surprise's clips played by three.js in headless Chromium at their apex
(``docs/export_threejs.png``, through tests/js/play.html), and happy's apex imported into
Blender and rendered there (``docs/export_blender.png``, scripts/blender_still.py); and a
face directory's rig (scikit-image's astronaut through `face from-photo`) with its photo,
in three.js and in Blender, beside facesim's own photo look (``docs/export_face.png``).
Needs what ``make test`` installs: Debian's chromium and blender, and tests/js's packages,
and the photo extra (MediaPipe)."""

from __future__ import annotations

import functools
import http.server
import shutil
import subprocess
import sys
import tempfile
import threading
from pathlib import Path

import numpy as np
from PIL import Image

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

from facesim.animation.simulate import simulate  # noqa: E402
from facesim.animation.spec import load_spec  # noqa: E402

JS = ROOT / "tests" / "js"


class _Quiet(http.server.SimpleHTTPRequestHandler):
    def log_message(self, *args):
        pass


def three_js(directory: Path, glb: str, seconds: float, png: Path) -> None:
    for name in ("play.html", "node_modules"):
        if not (directory / name).exists():
            (directory / name).symlink_to(JS / name)
    server = http.server.ThreadingHTTPServer(("127.0.0.1", 0), functools.partial(_Quiet, directory=str(directory)))
    threading.Thread(target=server.serve_forever, daemon=True).start()
    try:
        subprocess.run([shutil.which("chromium"), "--headless", "--no-sandbox", "--disable-gpu", "--disable-quic",
                        "--no-first-run", "--disable-background-networking", "--disable-component-update",
                        "--disable-sync", f"--user-data-dir={directory / 'profile'}", "--enable-unsafe-swiftshader",
                        "--use-angle=swiftshader", "--window-size=512,512", "--virtual-time-budget=30000",
                        f"--screenshot={png}",
                        f"http://127.0.0.1:{server.server_address[1]}/play.html?glb={glb}&t={seconds}"],
                       capture_output=True, timeout=300, check=True)
    finally:
        server.shutdown()


def face_rig(scratch: Path) -> None:
    """docs/export_face.png: the astronaut's face directory rigged (`facesim rig --face`),
    at rest, in three.js, in Blender and in facesim's photo look, side by side."""
    import imageio.v3 as iio
    from skimage import data

    iio.imwrite(scratch / "astronaut.png", data.astronaut())
    facesim = [sys.executable, "-m", "facesim"]
    subprocess.run([*facesim, "face", "from-photo", str(scratch / "astronaut.png"), "-o", str(scratch / "astronaut")], check=True)
    subprocess.run([*facesim, "rig", "--face", str(scratch / "astronaut"), "-o", str(scratch / "astronaut.glb")], check=True)
    three_js(scratch, "astronaut.glb", 0.0, scratch / "astronaut_three.png")
    subprocess.run(["blender", "-b", "--factory-startup", "--python", str(ROOT / "scripts" / "blender_still.py"), "--",
                    str(scratch / "astronaut.glb"), "0", "25", str(scratch / "astronaut_blender.png")],
                   capture_output=True, timeout=900, check=True)
    subprocess.run([*facesim, "render", str(ROOT / "expressions" / "happy.yaml"), "--face", str(scratch / "astronaut"),
                    "--look", "photo", "--frame", "0", "--size", "512x512", "-o", str(scratch / "astronaut_ours.png")],
                   check=True)
    shots = [np.asarray(Image.open(scratch / f"astronaut_{n}.png").convert("RGB").resize((512, 512)))
             for n in ("three", "blender", "ours")]
    Image.fromarray(np.hstack(shots)).save(ROOT / "docs" / "export_face.png")


def main() -> int:
    with tempfile.TemporaryDirectory() as scratch:
        scratch = Path(scratch)
        shots = []
        apex_seconds = {}
        for name in ("happy", "surprise"):
            spec = load_spec(ROOT / "expressions" / f"{name}.yaml")
            animation = simulate(spec)
            apex_seconds[name] = animation.apex_frame / animation.fps
            subprocess.run([sys.executable, "-m", "facesim", "render", str(ROOT / "expressions" / f"{name}.yaml"),
                            "-o", str(scratch / f"{name}.glb")], check=True)
            three_js(scratch, f"{name}.glb", apex_seconds[name], scratch / f"{name}.png")
            shots.append(np.asarray(Image.open(scratch / f"{name}.png").convert("RGB")))
        Image.fromarray(np.hstack(shots)).save(ROOT / "docs" / "export_threejs.png")
        subprocess.run(["blender", "-b", "--factory-startup", "--python", str(ROOT / "scripts" / "blender_still.py"), "--",
                        str(scratch / "happy.glb"), str(apex_seconds["happy"]), "25", str(ROOT / "docs" / "export_blender.png")],
                       capture_output=True, timeout=900, check=True)
        face_rig(scratch)
    print("wrote docs/export_threejs.png, docs/export_blender.png and docs/export_face.png")
    return 0


if __name__ == "__main__":
    sys.exit(main())
