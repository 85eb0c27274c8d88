"""A simulated fleet through `vdsbi fleet`: coverage, changes, levels, time per drive.

    python experiments/fleet_sim.py [--quick] [--cars N] [--drives N] [--workers N]
    python experiments/fleet_sim.py --real [DIR]   # the shared real drives, each a car of its own

`vdsbi.fleet.simulated_fleet` writes N cars of one platform, each with its own θ, driving random
manoeuvres over several days without torque columns; from its third drive on, car01's tyres lose a
quarter of their cornering stiffness, car02's centre of gravity moves 0.2 m back (a load) and
car03's steer signal lags 0.15 s more. The fleet runs on a local cluster; its table: coverage of
the truth by the 90 % intervals (identified parameters), the changes detected at the right drive
and the false alarms, the share of drives answered at each level, wall time per drive.

With --real, the real drives (default ../shared/real/*/recording.csv) are a fleet of their own:
each drive's fleet answer beside its own `identify` (with the platform's effects and nothing held
out, as the fleet escalates).

Writes experiments/results/fleet_sim{_quick}.json and .md (fleet_real.json and .md with --real).
"""

from __future__ import annotations

import argparse
import json
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from vdsbi.fleet import (
    TRUE_CHANGES,
    AmortizedSettings,
    Cluster,
    Escalation,
    FleetSettings,
    MisfitSettings,
    fleet,
    simulated_fleet,
)
from vdsbi.inference import TrainingSettings

RESULTS = Path(__file__).parent / "results"
#: The parameters scored (those a drive without torques identifies, and the changes').
SCORED = ("l_f", "C_alpha_f", "C_alpha_r", "signal_delay.delay")


def quick_settings() -> FleetSettings:
    """A small estimator, a short identify and a short search in each pooled diagnosis: what the
    tests run."""
    training = TrainingSettings(
        batch_size=128, learning_rate=1e-3, max_epochs=8, patience=4, cosine_decay=True
    )
    return FleetSettings(
        amortized=AmortizedSettings(simulations=600, training=training, draws_per_window=200),
        escalation=Escalation(rounds=1, sims=100, epochs=2, ppc_draws=10),
        misfit=MisfitSettings(
            most_cars=2,
            options=(
                ("candidates", ("sensor_bias", "steering_lag")),
                ("max_effects", 1),
                ("final_dt", 0.005),
            ),
        ),
    )


def score(out: Path, truth: dict, result) -> dict:
    """Coverage per parameter, changes against the truth, levels, time per drive."""
    inside, n = {p: 0 for p in SCORED}, {p: 0 for p in SCORED}
    for r in result.records:
        true = truth[r["recording"]]["values"]
        for p in SCORED:
            q = r.get("parameters", {}).get(p)
            if q and q["identified"]:
                n[p] += 1
                inside[p] += int(q["q05"] <= true[p] <= q["q95"])
    expected = {}
    for ch in TRUE_CHANGES:
        drives = sorted((v for v in truth.values() if v["car"] == ch.car), key=lambda v: v["drive"])
        if ch.at < len(drives):
            names = ["C_alpha_f", "C_alpha_r"] if ch.scale else list(ch.shift)
            for name in names:
                expected[(ch.car, name)] = drives[ch.at]["time"]
    found = [(c.car, c.parameter, c.time) for c in result.changes]
    right = [f for f in found if expected.get((f[0], f[1])) == f[2]]
    scored_found = [f for f in found if f[1] in SCORED]
    false_alarms = [f for f in scored_found if (f[0], f[1]) not in expected]
    tests = sum(
        max(0, sum(1 for v in truth.values() if v["car"] == c) - 1)
        for c in {v["car"] for v in truth.values()}
    )
    seconds = [r["seconds"] for r in result.records]
    by_method: dict[str, list[float]] = {}
    for r in result.records:
        by_method.setdefault(r["method"], []).append(r["seconds"])
    return {
        "coverage_90": {p: (inside[p], n[p]) for p in SCORED},
        "changes_expected": [list(k) + [v] for k, v in expected.items()],
        "changes_found": found,
        "changes_right": right,
        "false_alarms": false_alarms,
        "sequential_tests": tests * len(SCORED),
        "levels": {m: len(v) for m, v in by_method.items()},
        "seconds_per_drive": {m: round(float(np.median(v)), 1) for m, v in by_method.items()},
        "seconds_per_drive_all": round(float(np.median(seconds)), 1),
        "wall_seconds": round(result.seconds, 1),
    }


def markdown(s: dict, args) -> str:
    cov = ", ".join(f"{p} {a}/{b}" for p, (a, b) in s["coverage_90"].items())
    lines = [
        f"# A simulated fleet: {args.cars} cars × {args.drives} drives, {args.workers} workers"
        + (" (--quick)" if args.quick else ""),
        "",
        "| what | result |",
        "|---|---|",
        f"| truth inside the 90 % interval (identified) | {cov} |",
        f"| changes expected | {len(s['changes_expected'])} |",
        f"| changes detected at the right drive | {len(s['changes_right'])} of {len(s['changes_expected'])} |",
        f"| false alarms (scored parameters) | {len(s['false_alarms'])} in {s['sequential_tests']} car-parameter-drive tests |",
        f"| drives per level | {', '.join(f'{m} {n}' for m, n in s['levels'].items())} |",
        f"| median seconds per drive (on one worker) | {', '.join(f'{m} {t}' for m, t in s['seconds_per_drive'].items())} |",
        f"| wall time of the run (training included) | {s['wall_seconds']} s |",
        "",
        f"Changes found: {s['changes_found']}",
        "",
    ]
    return "\n".join(lines)


def real(folder: Path, workers: int, answered: Path | None = None) -> dict:
    """The real drives as a fleet, each answer beside its own identify (`answered`: a fleet
    output of these drives to read the fleet's answers from instead of running it)."""
    import pandas as pd

    from vdsbi import api

    drives = sorted(folder.glob("*/recording.csv"))
    rows = [
        {"car": d.parent.name, "recording": str(d), "vehicle": str(d.parent / "vehicle.json"), "time": 0}
        for d in drives
    ]
    with tempfile.TemporaryDirectory() as tmp:
        manifest = Path(tmp) / "manifest.csv"
        pd.DataFrame(rows).to_csv(manifest, index=False)
        fleet_out = answered or Path(tmp) / "out"
        if answered is None:
            records = fleet(manifest, fleet_out, FleetSettings(), Cluster(workers=workers), log=print).records
        else:
            records = [json.loads(f.read_text()) for f in sorted((answered / "drives").glob("*/result.json"))]
        misfits = {}
        if (fleet_out / "misfit.json").exists():
            misfits = {m["platform"]: m for m in json.loads((fleet_out / "misfit.json").read_text())}
        out = {}
        for r in records:
            if r["car"] not in {x["car"] for x in rows}:
                continue
            if not r.get("parameters"):
                out[r["car"]] = {
                    "method": r["method"],
                    "error": r.get("error"),
                    "fleet_seconds": r["seconds"],
                }
                continue
            row = next(x for x in rows if x["car"] == r["car"])
            # identify alone reads the drive as the fleet did (following the measured speed) with
            # the effects the fleet's answer has
            named = [n.split(".")[0] for n in r["parameters"] if "." in n]
            start = time.perf_counter()
            alone = api.identify(
                row["recording"],
                row["vehicle"],
                api.IdentifyOptions(
                    drive=api.DriveOptions(holdout=0.0, longitudinal="speed"),
                    model=api.ModelOptions(effects=tuple(dict.fromkeys(named))),
                ),
            )
            seconds = time.perf_counter() - start
            params = {}
            for name, p in r.get("parameters", {}).items():
                q = alone.summary["parameters"].get(name)
                if q is None:
                    continue
                params[name] = {
                    "fleet": [p["q05"], p["estimate"], p["q95"], p["identified"]],
                    "identify": [q["q05"], q["estimate"], q["q95"], q.get("identified") is not False],
                }
            misfit = next((m for k, m in misfits.items() if k.startswith(r["car"] + "/")), None)
            out[r["car"]] = {
                "method": r["method"],
                "checks": r.get("checks"),
                "fleet_seconds": r["seconds"],
                "identify_seconds": round(seconds, 1),
                "parameters": params,
                "diagnosis": None
                if misfit is None
                else {k: misfit[k] for k in ("detected", "named", "claimed", "verdict")},
            }
    return out


def real_markdown(s: dict) -> str:
    lines = ["# The shared real drives as a fleet", ""]
    for car, r in s.items():
        if "parameters" not in r:
            lines += [f"## {car}: {r['method']} in {r['fleet_seconds']} s: {r.get('error')}", ""]
            continue
        checks = ", ".join(f"{k} k̂ {v['k_hat']}" for k, v in (r["checks"] or {}).items())
        lines += [
            f"## {car}: {r['method']} ({checks}); {r['fleet_seconds']} s in the fleet, identify alone {r['identify_seconds']} s",
            "",
            "| parameter | fleet q05 / estimate / q95 (identified) | identify q05 / estimate / q95 (identified) |",
            "|---|---|---|",
        ]
        for name, p in r["parameters"].items():
            f, i = p["fleet"], p["identify"]
            lines.append(
                f"| {name} | {f[0]:.4g} / {f[1]:.4g} / {f[2]:.4g} ({f[3]}) | {i[0]:.4g} / {i[1]:.4g} / {i[2]:.4g} ({i[3]}) |"
            )
        if r.get("diagnosis"):
            d = r["diagnosis"]
            lines += ["", f"The platform's diagnosis (its one drive): {d['verdict']}"]
        lines.append("")
    return "\n".join(lines)


def main(argv=None) -> dict:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--answered", default=None, help="with --real: a fleet output to read the answers from")
    ap.add_argument(
        "--real", nargs="?", const=str(Path(__file__).resolve().parents[2] / "shared" / "real"), default=None
    )
    ap.add_argument("--quick", action="store_true", help="3 cars × 3 drives, a small estimator")
    ap.add_argument("--cars", type=int, default=6)
    ap.add_argument("--drives", type=int, default=4)
    ap.add_argument("--duration", type=float, default=40.0)
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--out", default=None, help="keep the fleet and its output here")
    args = ap.parse_args(argv)
    if args.real is not None:
        s = real(Path(args.real), args.workers, None if args.answered is None else Path(args.answered))
        RESULTS.mkdir(exist_ok=True)
        (RESULTS / "fleet_real.json").write_text(json.dumps(s, indent=1) + "\n")
        (RESULTS / "fleet_real.md").write_text(real_markdown(s))
        print(real_markdown(s))
        return s
    if args.quick:
        args.cars, args.drives, args.duration = 3, 3, 20.0
    settings = quick_settings() if args.quick else FleetSettings(seed=args.seed)
    with tempfile.TemporaryDirectory() as tmp:
        root = Path(args.out or tmp)
        manifest = simulated_fleet(
            root / "fleet", cars=args.cars, drives=args.drives, duration=args.duration, seed=args.seed
        )
        truth = json.loads((root / "fleet" / "truth.json").read_text())
        start = time.perf_counter()
        result = fleet(manifest, root / "out", settings, Cluster(workers=args.workers), log=print)
        s = score(root / "out", truth, result) | {"run_seconds": round(time.perf_counter() - start, 1)}
    RESULTS.mkdir(exist_ok=True)
    name = "fleet_sim_quick" if args.quick else "fleet_sim"
    if result.answered == 0 and (RESULTS / f"{name}.json").exists():  # re-scored from saved answers
        s["wall_seconds"] = json.loads((RESULTS / f"{name}.json").read_text())["wall_seconds"]
    (RESULTS / f"{name}.json").write_text(json.dumps(s, indent=1, default=list) + "\n")
    (RESULTS / f"{name}.md").write_text(markdown(s, args))
    print(markdown(s, args))
    return s


if __name__ == "__main__":
    sys.exit(0 if main() else 1)
