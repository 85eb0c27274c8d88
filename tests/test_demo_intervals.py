"""experiments/demo_intervals.py --quick: the demo's drives through identify, their intervals scored."""

import json

from experiments import demo_intervals


def test_quick_run_scores_every_identified_parameter(tmp_path):
    assert demo_intervals.main(["--quick", "--out", str(tmp_path)]) == 0
    out = json.loads((tmp_path / "demo_intervals_quick.json").read_text())
    summary, drives = out["summary"], out["drives"]
    assert summary["drives"] == len(drives) == 2
    scored = [r for d in drives for r in d["parameters"].values()]
    assert summary["scored"] == len(scored) >= 2 * 6  # θ's identified ones and the bias
    assert summary["inside"] == sum(r["inside"] for r in scored)
    assert len(summary["misses"]) == summary["scored"] - summary["inside"]
    for r in scored:
        assert r["q05"] <= r["estimate"] <= r["q95"]
        assert r["inside"] == (r["q05"] <= r["truth"] <= r["q95"])
    assert "truths inside their 90 % intervals" in (tmp_path / "demo_intervals_quick.md").read_text()
