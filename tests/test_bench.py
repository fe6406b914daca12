"""The benchmark script still runs (at a tiny size; the figures live in BENCHMARKS.md)."""

import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent


def test_bench_quick_prints_every_table():
    result = subprocess.run([sys.executable, str(ROOT / "scripts" / "bench.py"), "--quick"], capture_output=True,
                            text=True, cwd=ROOT, timeout=600)
    assert result.returncode == 0, result.stderr[-3000:]
    for title in ("Table 3.1", "Table 3.2", "Table 3.3", "Numba against the NumPy reference", "Compilation",
                  "fresh process", "Scaling", "Rendering", "default head", "Targets"):
        assert title in result.stdout
    assert "happy" in result.stdout and "disgusted anger" in result.stdout
