"""The simulator benchmark runs (tiny version) and its numpy port matches the JAX model."""

import json
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def test_quick_benchmark_runs_and_reports(tmp_path):
    out = tmp_path / "simulator.json"
    cmd = [sys.executable, str(ROOT / "benchmarks" / "simulator.py"), "--quick", "--out", str(out)]
    proc = subprocess.run(cmd, capture_output=True, text=True, timeout=600, cwd=ROOT)
    assert proc.returncode == 0, proc.stderr[-3000:]
    assert "draws/s" in proc.stdout
    r = json.loads(out.read_text())
    for key in ("draws_per_s", "seconds_5000", "compile_s", "speedup_vs_scipy", "speedup_vs_numpy_rk4"):
        assert key in r
    assert r["all_ok"] and all(v > 0 for v in r["draws_per_s"].values())
    # the baselines integrate the same model: numpy float32 RK4 at the same step agrees with
    # JAX to float32 rounding, scipy's adaptive float64 RK45 to the RK4 error
    assert r["numpy_rk4"]["max_rel_diff_vs_jax"] < 1e-4
    assert r["scipy"]["max_rel_diff_vs_jax"] < 5e-3
