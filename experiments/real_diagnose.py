"""Mismatch discovery on the real drives in /work/shared/real (see its README).

Runs `vdsbi.discovery.diagnose` on each drive's usable stretches (up to `--max-windows`
windows of ≤ 20 s; in each, the first 70 % fitted and the rest held out) and writes what it
finds to experiments/results/real_diagnose.json and .md, and the full reports (with figures)
to experiments/results/real_diagnose/<drive>/.

Usage:
    python experiments/real_diagnose.py [--real DIR] [--max-windows 3] [--drives a,b]
"""

from __future__ import annotations

import argparse
import json
import shutil
import sys
import time
from pathlib import Path

import jax

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from vdsbi.discovery import diagnose  # noqa: E402
from vdsbi.io import load_drive  # noqa: E402


def summary_row(name: str, rep: dict, seconds: float) -> dict:
    before, after = rep["fit"]["before"], rep["fit"]["after"]
    return {
        "drive": name,
        "windows_s": rep["windows"]["spans_s"],
        "channels": rep["channels"],
        "noise_sigma": rep["noise"]["sigma"],
        "mismatch_detected": rep["mismatch_detected"],
        "p_value": rep["p_value"],
        "p_value_after": rep["p_value_after"],
        "located": {k: rep["located"][k] for k in ("channels", "windows", "bands_hz")},
        "ranking": [
            {
                "name": e["name"],
                "score": round(e["score"], 1),
                "params": e["params"],
                "params_std": e["params_std"],
            }
            for e in rep["effects"][:6]
        ],
        "chosen": rep["chosen"],
        "explained": rep.get("explained"),
        "verdict": rep.get("verdict"),
        "ranking_confidence": rep["ranking_confidence"],
        "separability": [p["verdict"] for g in rep["separability"] for p in g["pairs"]],
        "heldout": {c: {"before": before[c], "after": after[c]} for c in before},
        "theta_before": rep["theta"]["before"],
        "theta_after": rep["theta"]["after"],
        "theta_std_after": rep["theta_std"]["after"],
        "at_bounds": rep["at_bounds"],
        "recording_warnings": rep["recording_warnings"],
        "seconds": seconds,
    }


def markdown(rows: list[dict]) -> str:
    L = ["# Mismatch discovery on real drives (VW GTI, Stanford ME227 data)", ""]
    L.append(
        "Produced by `experiments/real_diagnose.py`. Noise σ is estimated from each recording "
        "(no noise_std in vehicle.json); the real noise is coloured (ay carries ~4 m/s² of "
        "vibration), so χ² differences, evidence scores and ranking odds are overstated: read the "
        "ranking as an ordering, not as calibrated odds. Torques are derived from the *commanded* "
        "force, so actuator dynamics are expected to show up."
    )
    for r in rows:
        L += ["", f"## {r['drive']}", ""]
        L.append(f"- windows (s): {r['windows_s']}; channels: {', '.join(r['channels'])}")
        L.append(
            f"- mismatch detected: {r['mismatch_detected']} (p = {r['p_value']:.3g}; after fix {r['p_value_after']:.3g})"
        )
        loc = r["located"]
        L.append(
            f"- located: channels {loc['channels']}, bands {loc['bands_hz']}, {len(loc['windows'])} windows"
        )
        L.append(f"- chosen: **{', '.join(r['chosen']) or 'none'}**")
        if r.get("verdict"):
            L.append(f"- verdict: {r['verdict']}")
        chi_b = sum(d["before"]["chi2_dof"] for d in r["heldout"].values()) / len(r["heldout"])
        chi_a = sum(d["after"]["chi2_dof"] for d in r["heldout"].values()) / len(r["heldout"])
        verdict = "improves" if chi_a < chi_b else "does NOT improve (the fix absorbs some other mismatch)"
        L.append(f"- held-out mean χ²/dof {chi_b:.4g} → {chi_a:.4g}: the fix {verdict}")
        L.append("- ranking (score: BIC log Bayes factor vs none + log prior odds, pairs −3):")
        for e in r["ranking"]:
            ps = "; ".join(
                f"{eff}.{k} = {v:.4g} ± {e['params_std'][eff][k]:.2g}"
                for eff, d in e["params"].items()
                for k, v in d.items()
            )
            L.append(f"  - {e['name']}: {e['score']}  {ps}")
        L.append("- look-alikes: " + "; ".join(r["separability"]))
        L.append("")
        L.append("| channel | held-out NRMSE before → after | χ²/dof before → after |")
        L.append("|---|---|---|")
        for c, d in r["heldout"].items():
            L.append(
                f"| {c} | {d['before']['nrmse']:.3f} → {d['after']['nrmse']:.3f} | "
                f"{d['before']['chi2_dof']:.2f} → {d['after']['chi2_dof']:.2f} |"
            )
        L.append("")
        L.append("| θ | before | after |")
        L.append("|---|---|---|")
        for k, v in r["theta_before"].items():
            L.append(f"| {k} | {v:.4g} | {r['theta_after'][k]:.4g} ± {r['theta_std_after'][k]:.2g} |")
        if r["at_bounds"]:
            L.append(
                f"\nAt the edge of their range (absorbing unmodelled effects?): {', '.join(r['at_bounds'])}"
            )
        for w in r["recording_warnings"]:
            L.append(f"\nwarning: {w}")
        L.append(f"\n{r['seconds']:.0f} s")
    return "\n".join(L) + "\n"


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--real", default="/work/shared/real")
    ap.add_argument("--out", default=str(ROOT / "experiments" / "results"))
    ap.add_argument("--max-windows", type=int, default=3)
    ap.add_argument("--drives", default=None, help="comma-separated subset")
    args = ap.parse_args(argv)
    jax.config.update("jax_compilation_cache_dir", "/tmp/vdsbi_jax_cache")
    out = Path(args.out)
    drives = sorted(p for p in Path(args.real).iterdir() if (p / "recording.csv").exists())
    if args.drives:
        drives = [d for d in drives if d.name in args.drives.split(",")]
    rows = []
    for d in drives:
        rec, veh = load_drive(d / "recording.csv", d / "vehicle.json")
        target = out / "real_diagnose" / d.name
        if target.exists():
            shutil.rmtree(target)
        t0 = time.perf_counter()
        res = diagnose(rec, veh, target, max_windows=args.max_windows, quiet=False)
        rows.append(summary_row(d.name, res.report, time.perf_counter() - t0))
        (out / "real_diagnose.json").write_text(json.dumps(rows, indent=1, default=float))
        (out / "real_diagnose.md").write_text(markdown(rows))
        print(f"{d.name}: chosen {res.report['chosen']} ({rows[-1]['seconds']:.0f} s)", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
