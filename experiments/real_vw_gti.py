"""Identify the real VW GTI drives (../shared/real/) as a user would, beside the source lab's values.

    python experiments/real_vw_gti.py [--quick] [--rounds N] [--sims N] [--max-duration S]

For each recording: the usable segments (speed and excitation), estimated sensor noise (the
vehicle files give none), a kinematic time-base check (slope of d(vx)/dt against ax), and the
posterior from `vdsbi.api.identify` on the most excited usable window. Writes
experiments/results/real_vw_gti{_quick}.md/.json and per-drive plots under
experiments/results/real_vw_gti{_quick}/<drive>/ (ppc.png, pairplot.png), updating the table
after each drive.
"""

from __future__ import annotations

import argparse
import json
import shutil
import time
from pathlib import Path

from vdsbi import api
from vdsbi.io import estimate_noise_std, find_segments, kinematic_slopes, load_drive

REAL = Path("/work/shared/real")
RESULTS = Path(__file__).parent / "results"
DRIVES = ("vw_gti_low_speed", "vw_gti_high_speed_2")
#: Source lab's values (../shared/real/README.md): estimates, not ground truth. Axle stiffness, N/rad.
LAB = {
    "l_f": {"value": 1.264, "note": "a, CoG to front axle"},
    "C_alpha_f": {"value": 80e3, "note": "linear model (Fiala: 110e3)"},
    "C_alpha_r": {"value": 120e3, "note": "linear model (Fiala: 180e3)"},
}


def markdown(rows: dict) -> str:
    out = ["# Real VW GTI drives: identify as a user would", ""]
    for name, r in rows.items():
        out += [f"## {name}", ""]
        out.append(f"- usable segments: {r['usable_segments'] or 'none'}")
        out.append(f"- identified on: {r.get('segment')}")
        out.append(f"- estimated noise std: {r['noise_std_estimate']}")
        out.append(f"- kinematic check, slope of d(vx)/dt vs ax: {r['kinematic_slopes']}")
        slope = r["kinematic_slopes"].get("dvx/dt~ax")
        if slope is not None and not 0.8 <= slope <= 1.2:
            out.append(
                f"- **warning**: d(vx)/dt ≈ {slope:.2f}·ax, not 1: the file's time base (t = index × 5 ms) is "
                f"likely off by ~{1 / slope:.1f}×; the posterior below is from a mis-timed recording"
            )
        if r.get("error"):
            out += [f"- **not identified**: {r['error']}", ""]
            continue
        out.append(f"- budget: {r['budget']}, wall time {r['wall_s']:.0f} s")
        out.append(f"- posterior-predictive 90 % band coverage (fraction of samples inside): {r['ppc']}")
        out.append(
            f"- posterior draws that simulated successfully for the band: {r.get('ppc_draws_simulated')} of 100"
        )
        out.append(f"- simulations used per round (rest failed or non-finite): {r.get('used_per_round')}")
        out += [
            "",
            "| param | mean | std | 5 % | 95 % | prior | source lab |",
            "|---|---|---|---|---|---|---|",
        ]
        for p, s in r["parameters"].items():
            lab = LAB.get(p)
            lab_s = f"{lab['value']:.4g} ({lab['note']})" if lab else "—"
            out.append(
                f"| {p} | {s['mean']:.4g} | {s['std']:.3g} | {s['q05']:.4g} | {s['q95']:.4g} | "
                f"[{s['prior'][0]:.3g}, {s['prior'][1]:.3g}] | {lab_s} |"
            )
        out.append("")
    return "\n".join(out) + "\n"


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--quick", action="store_true")
    ap.add_argument("--rounds", type=int)
    ap.add_argument("--sims", type=int)
    ap.add_argument("--max-duration", type=float)
    ap.add_argument("--markdown-only", action="store_true", help="rewrite the .md from the .json")
    args = ap.parse_args()
    rounds = args.rounds or 2
    sims = args.sims or (200 if args.quick else 1000)
    max_dur = args.max_duration or (8.0 if args.quick else 20.0)
    stem = "real_vw_gti_quick" if args.quick else "real_vw_gti"
    RESULTS.mkdir(exist_ok=True)
    if args.markdown_only:
        rows = json.loads((RESULTS / f"{stem}.json").read_text())
        (RESULTS / f"{stem}.md").write_text(markdown(rows))
        return
    rows: dict = {}
    for name in DRIVES:
        rec, veh = load_drive(REAL / name / "recording.csv", REAL / name / "vehicle.json")
        segs = find_segments(rec, wheel_radius=veh.wheel_radius)
        usable = [(round(s.t0, 2), round(s.t1, 2)) for s in segs if s.usable]
        row = {
            "usable_segments": usable,
            "noise_std_estimate": {
                k: round(v, 4) for k, v in estimate_noise_std(rec, segments=usable or None).items()
            },
            "kinematic_slopes": {k: round(v, 3) for k, v in kinematic_slopes(rec).items()},
            "budget": f"{rounds} rounds x {sims} sims, stats embedding, window <= {max_dur:g} s",
        }
        out = RESULTS / stem / name
        if out.exists():
            shutil.rmtree(out)
        t0 = time.perf_counter()
        try:
            res = api.identify(
                rec,
                veh,
                rounds=rounds,
                sims=sims,
                embedding="stats",
                seed=0,
                out_dir=out,
                max_duration=max_dur,
                log=print,
            )
        except Exception as err:  # report, don't hide
            row["error"] = f"{type(err).__name__}: {err}"
        else:
            s = res.summary
            row.update(
                segment=[round(s["segment"]["t0"], 2), round(s["segment"]["t1"], 2)],
                parameters=s["parameters"],
                ppc={k: round(v, 3) for k, v in s["ppc"]["fraction_inside_90pct_band"].items()},
                wall_s=time.perf_counter() - t0,
                used_per_round=[h["num_used"] for h in s["rounds"]],
                ppc_draws_simulated=s["ppc"]["draws"],
            )
            for f in ("checkpoint.npz", "estimator.npz"):  # large binaries stay out of git
                (out / f).unlink(missing_ok=True)
        rows[name] = row
        (RESULTS / f"{stem}.json").write_text(json.dumps(rows, indent=2) + "\n")
        (RESULTS / f"{stem}.md").write_text(markdown(rows))
        print(markdown({name: row}))


if __name__ == "__main__":
    main()
