"""The fleet's misfit: one car of a platform with a bent IMU mount, found and named by the fleet.

    python experiments/fleet_misfit.py [--quick] [--cars N] [--drives N] [--bias M/S2]

`vdsbi.fleet.simulated_fleet` writes N cars of one platform without torque columns and without
changes; then every drive of the last car gets a lateral-accelerometer offset (`--bias`, m/s²: what
`sensor_bias.ay` models, which the platform's model leaves out). The fleet runs on a local cluster
with its default misfit stage: `diagnose` on the platform's pooled drives (whose cars are clean: a
detection there is a false alarm) and on each car whose model error stands out from its
platform's (the biased car should, and its diagnosis should name `sensor_bias`).

`--quick` runs a small estimator, a short identify for escalated drives and a short search in
each diagnosis. Writes experiments/results/fleet_misfit{_quick}.json and .md.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import sys
import tempfile
import time
from pathlib import Path

import pandas as pd

sys.path.insert(0, str(Path(__file__).resolve().parent))

from fleet_sim import quick_settings  # noqa: E402

from vdsbi.fleet import Cluster, FleetSettings, MisfitSettings, fleet, simulated_fleet  # noqa: E402

RESULTS = Path(__file__).parent / "results"
#: The quick setting's diagnoses: two cars pooled, a short search among three effects.
QUICK_MISFIT = MisfitSettings(
    most_cars=2,
    options=(
        ("candidates", ("sensor_bias", "road_grade", "steering_lag")),
        ("max_effects", 1),
        ("final_dt", 0.005),
    ),
)


def bend_imu(manifest: Path, car: str, bias: float) -> list[str]:
    """Add `bias` to the `ay` of every drive of `car`; the drives changed."""
    rows = pd.read_csv(manifest)
    changed = []
    for rec in rows.loc[rows["car"] == car, "recording"]:
        path = manifest.parent / rec
        df = pd.read_csv(path)
        df["ay"] = df["ay"] + bias
        df.to_csv(path, index=False)
        changed.append(str(rec))
    return changed


def summary(result, biased_car: str, bias: float, seconds: float) -> dict:
    found = {("platform" if m.car is None else m.car): m.to_dict() for m in result.misfits}
    for m in found.values():  # the values the diagnosis fitted for what it named
        report = json.loads((result.out / m["folder"] / "report.json").read_text())
        m["fitted"] = {e: report.get("effect_params", {}).get(e) for e in m["named"]}
    car = found.get(biased_car)
    others = [k for k in found if k not in ("platform", biased_car)]
    return {
        "biased_car": biased_car,
        "bias_ay": bias,
        "cars_flagged_alone": sorted(k for k in found if k != "platform"),
        "platform_detected": bool(found.get("platform", {}).get("detected")),
        "platform_named": list(found.get("platform", {}).get("named", [])),
        "biased_car_flagged": car is not None,
        "biased_car_named": [] if car is None else list(car["named"]),
        "biased_car_claimed": bool(car and car["claimed"]),
        "clean_cars_flagged": others,
        "methods": result.methods(),
        "misfits": found,
        "seconds": round(seconds, 1),
        "answered_in_this_run": result.answered,
        "reused": result.skipped,
    }


def markdown(s: dict, args) -> str:
    lines = [
        f"# The fleet's misfit: {args.cars} cars × {args.drives} drives, {s['biased_car']}'s a_y offset "
        f"by {s['bias_ay']} m/s²" + (" (quick)" if args.quick else ""),
        "",
        "| what | result |",
        "|---|---|",
        f"| cars flagged alone by their model error | {', '.join(s['cars_flagged_alone']) or 'none'} |",
        f"| the biased car's diagnosis names | {', '.join(s['biased_car_named']) or 'nothing'} "
        f"(claimed: {'yes' if s['biased_car_claimed'] else 'no'}) |",
        f"| the clean platform's pooled diagnosis | "
        f"{'detected' if s['platform_detected'] else 'not detected'}; named {', '.join(s['platform_named']) or 'nothing'} |",
        f"| clean cars flagged alone (false alarms) | {len(s['clean_cars_flagged'])} |",
        f"| drives per level | {s['methods']} |",
        f"| wall time of this run | {s['seconds']} s ({s['answered_in_this_run']} drives answered in it, "
        f"{s['reused']} and any unchanged diagnosis reused from an earlier run into the same folder) |",
        "",
    ]
    for k, m in s["misfits"].items():
        fitted = "; ".join(f"{e} {v}" for e, v in m["fitted"].items())
        lines.append(f"- {k}: {m['verdict']}" + (f" Fitted: {fitted}." if fitted else ""))
    return "\n".join(lines) + "\n"


def main(argv=None) -> dict:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="a small estimator, 4 cars × 2 drives of 20 s")
    ap.add_argument("--cars", type=int, default=5)
    ap.add_argument("--drives", type=int, default=2)
    ap.add_argument("--duration", type=float, default=30.0)
    ap.add_argument("--bias", type=float, default=0.3, help="the last car's a_y offset, m/s²")
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--seed", type=int, default=3)
    ap.add_argument("--out", default=None, help="keep the fleet and its output here")
    args = ap.parse_args(argv)
    if args.quick:
        args.cars, args.drives, args.duration = 4, 2, 20.0
    settings = quick_settings() if args.quick else FleetSettings(seed=args.seed)
    settings = dataclasses.replace(settings, misfit=QUICK_MISFIT if args.quick else MisfitSettings())
    with tempfile.TemporaryDirectory() as tmp:
        root = Path(args.out or tmp)
        manifest = simulated_fleet(
            root / "fleet",
            cars=args.cars,
            drives=args.drives,
            duration=args.duration,
            changes=(),
            seed=args.seed,
        )
        biased = f"car{args.cars:02d}"
        bend_imu(manifest, biased, args.bias)
        start = time.perf_counter()
        result = fleet(manifest, root / "out", settings, Cluster(workers=args.workers), log=print)
        s = summary(result, biased, args.bias, time.perf_counter() - start)
    RESULTS.mkdir(exist_ok=True)
    name = "fleet_misfit_quick" if args.quick else "fleet_misfit"
    (RESULTS / f"{name}.json").write_text(json.dumps(s, indent=1) + "\n")
    (RESULTS / f"{name}.md").write_text(markdown(s, args))
    print(markdown(s, args))
    return s


if __name__ == "__main__":
    sys.exit(0 if main() else 1)
