"""Every command in the README runs as written: each shell line of its ``sh`` blocks that
starts with ``facesim`` and needs no photo of the user's (``me.jpg``, a face directory
made from it, a scan, a video ``me.mp4``) runs in a fresh directory beside the expression library and the
faces, at a small frame size and with few dataset samples so the suite stays quick, and
exits 0 with its output written. The docs the README links to exist."""

import re
import shlex
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent
README = (ROOT / "README.md").read_text()
#: What the user brings: a command that names one of these is left to the face tests.
NEEDS_A_PHOTO = ("me.jpg", "me/", "me.obj", "scan.", "me.mp4")
SIZED = ("render", "say", "batch", "sheet", "dataset")


def readme_commands() -> list[str]:
    blocks = re.findall(r"```sh\n(.*?)```", README, flags=re.S)
    lines = [line.split("  #")[0].strip() for block in blocks for line in block.splitlines()]
    return [line for line in lines if line.startswith("facesim ")]


def runnable() -> list[str]:
    return [c for c in readme_commands() if not any(p in c for p in NEEDS_A_PHOTO)]


def small(command: str) -> str:
    """The command at 64x64 frames and 2 dataset samples."""
    words = shlex.split(command)
    if words[1] in SIZED:
        if "--size" in words:
            words[words.index("--size") + 1] = "64x64"
        else:
            words += ["--size", "64x64"]
    if "--n" in words:
        words[words.index("--n") + 1] = "2"
    return " ".join(shlex.quote(w) if "*" not in w else w for w in words)


def test_the_readme_shows_commands_and_links_its_docs():
    assert 15 <= len(readme_commands()) and len(runnable()) >= 12
    assert len(README.splitlines()) <= 250
    for link in ("docs/method.md", "docs/architecture.md", "BENCHMARKS.md", "REALISM.md", "CHANGELOG.md"):
        assert f"]({link})" in README and (ROOT / link).is_file(), link


@pytest.mark.parametrize("command", runnable())
def test_a_readme_command_runs_as_written(command, tmp_path):
    for data in ("expressions", "meshes"):
        (tmp_path / data).symlink_to(ROOT / data)
    line = small(command).replace("facesim ", f"{shlex.quote(sys.executable)} -m facesim ", 1)
    result = subprocess.run(["bash", "-c", line], cwd=tmp_path, capture_output=True, text=True, timeout=600)
    assert result.returncode == 0, f"{line}\n{result.stderr[-2000:]}"
    words = shlex.split(command)
    if "-o" in words:
        output = tmp_path / words[words.index("-o") + 1]
        assert output.exists() and (output.is_file() or any(output.iterdir())), output
    elif words[1] == "render":  # out/<the spec's title>.mp4
        assert any((tmp_path / "out").glob("*.mp4"))
    elif "--plot" in words:
        assert (tmp_path / words[words.index("--plot") + 1]).is_file()
