"""The pictures of docs/export.md (``make docs``): facesim's GLBs as other tools show
them. Happy's and surprise's clips played by three.js in headless Chromium at their apex
(``docs/export_threejs.png``, through tests/js/play.html), and happy's apex imported into
Blender and rendered there (``docs/export_blender.png``, scripts/blender_still.py).
Needs what ``make test`` installs: Debian's chromium and blender, and tests/js's packages."""

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
    print("wrote docs/export_threejs.png and docs/export_blender.png")
    return 0


if __name__ == "__main__":
    sys.exit(main())
