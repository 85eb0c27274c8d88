"""Fleet throughput: drives per hour with 1 and 2 workers, time per drive of the amortized path
against `identify`, the estimator's training time, and the extrapolation to 10⁴ drives on 100
workers.

    python benchmarks/fleet.py [--quick] [--cars N] [--drives N] [--platforms DIR]

One simulated fleet (`vdsbi.fleet.simulated_fleet`); the platform's estimator is trained once
(timed; or taken from `--platforms`, a fleet output's platforms/ folder of the same vehicle and
settings, e.g. experiments/fleet_sim.py's), then the same drives are answered with 1 worker and with 2 (the estimator reused, as on
every later night), and one drive by `vdsbi.api.identify` alone with identify's defaults. The
workers share a persistent compilation cache, as the `vdsbi` command's do: a first run with 2
workers fills it (cold), the runs with 1 and 2 workers read it (warm). The extrapolation:
T(N, W) = training + start-up + N · t_drive / W, with t_drive the median time a worker spends on a
drive (warm) and the start-up the wall time the run adds beyond its workers' busy time (the
cluster's start, the platform's preparation, the tables and report); the scheduler's own cost per
task is not measured at that scale.

Writes benchmarks/results/fleet{_quick}.json and .md.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import os
import shutil
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "experiments"))

from fleet_sim import quick_settings  # noqa: E402

from vdsbi import api  # noqa: E402
from vdsbi.fleet import Cluster, FleetSettings, fleet, simulated_fleet  # noqa: E402

RESULTS = Path(__file__).parent / "results"
#: How many times less a drive should cost the fleet than `identify` alone.
TARGET = 20.0


def _run(manifest, out, settings, workers, cache, platforms=None) -> dict:
    out.mkdir(parents=True, exist_ok=True)
    if platforms is not None:
        shutil.copytree(platforms, out / "platforms", dirs_exist_ok=True)
    start = time.perf_counter()
    res = fleet(manifest, out, settings, Cluster(workers=workers, compilation_cache=cache))
    wall = time.perf_counter() - start
    busy = [r["seconds"] for r in res.records]
    stages: dict[str, list[float]] = {}
    for r in res.records:
        for name, sec in (r.get("stages") or {}).items():
            stages.setdefault(name, []).append(sec)
    return {
        "workers": workers,
        "drives": len(res.records),
        "wall_seconds": round(wall, 1),
        "drives_per_hour": round(len(res.records) / wall * 3600, 1),
        "median_drive_seconds": round(float(np.median(busy)), 2),
        "median_drive_cpu_seconds": round(
            float(np.median([r.get("cpu_seconds", np.nan) for r in res.records])), 2
        ),
        "startup_seconds": round(max(0.0, wall - sum(busy) / workers), 1),
        "methods": res.methods(),
        "training_seconds": _training(out),
        # where a drive's time goes (median over the drives that reached each stage)
        "median_stage_seconds": {k: round(float(np.median(v)), 2) for k, v in stages.items()},
        # the machine's other work: the 1-minute load average as the run ended, against its cores
        "load_average": round(os.getloadavg()[0], 1),
        "cores": os.cpu_count(),
    }


def _training(out: Path) -> float | None:
    for f in (out / "platforms").glob("*/estimator.json"):
        return json.loads(f.read_text())["training"].get("seconds")
    return None


def main(argv=None) -> dict:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="3 cars × 2 drives, the quick settings")
    ap.add_argument("--cars", type=int, default=4)
    ap.add_argument("--drives", type=int, default=3)
    ap.add_argument("--platforms", default=None, help="a trained platforms/ folder to reuse")
    args = ap.parse_args(argv)
    if args.quick:
        args.cars, args.drives = 3, 2
    # drives per hour: the pooled diagnoses after the drives are not the drives' time
    settings = dataclasses.replace(quick_settings() if args.quick else FleetSettings(), misfit=None)
    with tempfile.TemporaryDirectory() as tmp:
        root = Path(tmp)
        manifest = simulated_fleet(root / "fleet", cars=args.cars, drives=args.drives, duration=30.0, seed=3)
        cache = root / "jax-cache"
        if args.platforms is None:
            cold = _run(manifest, root / "cold", settings, 2, cache)
            platforms = root / "cold" / "platforms"
        else:
            platforms = Path(args.platforms)
            cold = _run(manifest, root / "cold", settings, 2, cache, platforms=platforms)
            cold |= {"training_seconds": _training(platforms.parent), "estimator_reused": True}
        one = _run(manifest, root / "one", settings, 1, cache, platforms=platforms)
        two = _run(manifest, root / "two", settings, 2, cache, platforms=platforms)
        drive = sorted((root / "fleet").glob("car01/drive0.csv"))[0]
        start, cpu = time.perf_counter(), time.process_time()
        esc = settings.escalation
        effects = json.loads(next(platforms.glob("*/platform.json")).read_text())["platform"]["effects"]
        options = api.IdentifyOptions(
            drive=api.DriveOptions(holdout=0.0),
            model=api.ModelOptions(effects=tuple(effects)),
            budget=api.Budget(rounds=esc.rounds, sims=esc.sims, epochs=esc.epochs),
        )
        api.identify(drive, root / "fleet" / "vehicle.json", options)
        identify_seconds = time.perf_counter() - start
        identify_cpu = time.process_time() - cpu
    t_drive, startup = two["median_drive_seconds"], two["startup_seconds"]
    training = cold["training_seconds"] or 0.0
    n, w = 10_000, 100
    s = {
        "workers_2_cold": cold,
        "workers_1": one,
        "workers_2": two,
        "identify_seconds_one_drive": round(identify_seconds, 1),
        # the target's measure: a drive's wall time on one worker against identify's on the machine
        "speedup_per_drive_1_worker": round(identify_seconds / one["median_drive_seconds"], 2),
        "speedup_per_drive_2_workers": round(identify_seconds / t_drive, 2),
        "identify_cpu_seconds_one_drive": round(identify_cpu, 1),
        # processor time against processor time: what a shared machine's waiting leaves out
        "cpu_speedup_per_drive_1_worker": round(identify_cpu / one["median_drive_cpu_seconds"], 2),
        "throughput_speedup_2_workers": round(two["drives_per_hour"] * identify_seconds / 3600, 2),
        "target_per_drive": TARGET,
        "retrained": "once per platform; again only with --retrain or other estimator settings",
        "extrapolated_10k_drives_100_workers_hours": round((training + startup + n * t_drive / w) / 3600, 2),
    }
    RESULTS.mkdir(exist_ok=True)
    name = "fleet_quick" if args.quick else "fleet"
    (RESULTS / f"{name}.json").write_text(json.dumps(s, indent=1) + "\n")
    md = [
        f"# Fleet throughput ({args.cars} cars × {args.drives} drives of 30 s{', --quick' if args.quick else ''})",
        "",
        "| what | result |",
        "|---|---|",
        f"| estimator training (once per platform) | {training} s |",
        f"| 2 workers, cold cache | {cold['drives_per_hour']} drives/h; median {cold['median_drive_seconds']} s per drive ({cold['median_drive_cpu_seconds']} s CPU); {cold['methods']} |",
        f"| 1 worker, warm | {one['drives_per_hour']} drives/h; median {one['median_drive_seconds']} s per drive ({one['median_drive_cpu_seconds']} s CPU); {one['methods']} |",
        f"| 2 workers, warm | {two['drives_per_hour']} drives/h; median {two['median_drive_seconds']} s per drive ({two['median_drive_cpu_seconds']} s CPU); {two['methods']} |",
        f"| identify alone, one drive | {s['identify_seconds_one_drive']} s, {s['identify_cpu_seconds_one_drive']} s CPU |",
        f"| a drive on 1 worker against identify (target ≥ {TARGET}×) | {s['speedup_per_drive_1_worker']}× less wall time ({'met' if s['speedup_per_drive_1_worker'] >= TARGET else 'missed'}), {s['cpu_speedup_per_drive_1_worker']}× less CPU |",
        f"| 2 workers against identify | {s['speedup_per_drive_2_workers']}× less wall time per drive; {s['throughput_speedup_2_workers']}× its drives per hour |",
        f"| start-up of a run (2 workers, warm) | {startup} s |",
        f"| 10⁴ drives on 100 workers (extrapolated) | {s['extrapolated_10k_drives_100_workers_hours']} h |",
        "",
        "| run | median seconds per stage of a drive | load average at its end (cores) |",
        "|---|---|---|",
        *(
            f"| {name} | {run['median_stage_seconds']} | {run['load_average']} ({run['cores']}) |"
            for name, run in (("2 workers, cold", cold), ("1 worker, warm", one), ("2 workers, warm", two))
        ),
        "",
    ]
    (RESULTS / f"{name}.md").write_text("\n".join(md))
    print("\n".join(md))
    return s


if __name__ == "__main__":
    sys.exit(0 if main() else 1)
