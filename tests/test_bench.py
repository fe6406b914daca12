"""The benchmark script runs at a tiny size (`--quick`) and its figures make sense: every
time positive and finite, the Numba kernels far ahead of the NumPy reference, the implicit
solver faster than the thesis's update and holding the expressions where it does, the
renderer near the bare pyrender floor. The real figures live in BENCHMARKS.md."""

import json
import math
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent


def numbers(tree):
    if isinstance(tree, dict):
        for value in tree.values():
            yield from numbers(value)
    elif isinstance(tree, (int, float)) and not isinstance(tree, bool):
        yield tree


def test_bench_quick_prints_every_table_with_sensible_figures(tmp_path):
    figures_path = tmp_path / "figures.json"
    result = subprocess.run([sys.executable, str(ROOT / "scripts" / "bench.py"), "--quick", "--json", str(figures_path)],
                            capture_output=True, text=True, cwd=ROOT, timeout=600)
    assert result.returncode == 0, result.stderr[-3000:]
    for title in ("Table 3.1", "Table 3.2", "Table 3.3", "Numba against the NumPy reference", "two solvers",
                  "Compilation", "fresh process", "Scaling", "Rendering", "default head", "Targets"):
        assert title in result.stdout
    assert "happy" in result.stdout and "disgusted anger" in result.stdout
    f = json.loads(figures_path.read_text())

    assert all(math.isfinite(v) and v >= 0 for v in numbers(f))
    for row in f["table_31"].values():
        assert 0 < row["sim"] < 1 and row["render"] > 0 and row["fps"] > 0
    assert f["numba_ratio"] > 20
    assert f["compile"]["cached"]["first"] < f["compile"]["cold"]["first"]
    for face in ("the Hopper face", "the default head"):
        assert 0 < f["solvers"][face]["implicit"] < f["solvers"][face]["quasi"]
    assert max(f["solvers"]["apex, the default head"].values()) < 0.02
    assert 0 < f["fresh_wall"] < 60 and 50 < f["fresh_peak_mb"] < 4000
    for render in f["render"].values():
        assert 0.3 < render["ours"] / render["floor"] < 2
    for head in f["head"].values():
        assert head["fps"] > 1 and head["fps_plain"] >= 0.8 * head["fps"]
