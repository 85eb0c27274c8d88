"""A simulated fleet through `vdsbi fleet`: coverage, changes, levels, time per drive.

    python experiments/fleet_sim.py [--quick] [--cars N] [--drives N] [--workers N]
    python experiments/fleet_sim.py --real [DIR]   # the shared real drives, each a car of its own

`vdsbi.fleet.simulated_fleet` writes N cars of one platform, each with its own θ, driving random
manoeuvres over several days without torque columns; from its third drive on, car01's tyres lose a
quarter of their cornering stiffness, car02's centre of gravity moves 0.2 m back (a load) and
car03's steer signal lags 0.15 s more. The fleet runs on a local cluster; its table: coverage of
the truth by the 90 % intervals (identified parameters), the changes detected at the right drive
and the false alarms, the share of drives answered at each level, wall time per drive.

With --real, the real drives (default ../shared/real/*/recording.csv) are a fleet of their own,
on the first 70 % of each drive without its torques: each drive's fleet answer beside its own
`identify` on the same part (with the platform's effects and nothing held out, as the fleet
escalates), both scored on the rest of the drive (held-out NRMSE of the estimate, share of the
held-out samples inside the 90 % predictive band) with `real_drives.py`'s least-squares floor.

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
from vdsbi.problem import ProblemSettings, make_problem

sys.path.insert(0, str(Path(__file__).resolve().parent))
import real_drives  # noqa: E402

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


def real(folder: Path, workers: int, quick: bool = False) -> dict:
    """The real drives as a fleet, each a car of its own, on the first `TRAIN_FRACTION` of the
    drive without its torques (as `real_drives.py` runs `identify`); beside each answer, `identify`
    alone on the same part (the platform's effects, nothing held out, as the fleet escalates).
    Both, and the least-squares floor, are scored on the rest of the drive. `quick`: the quick
    fleet settings and a one-round `identify` of 300 simulations (a smoke run)."""
    import pandas as pd

    from vdsbi import api
    from vdsbi.io import load_drive

    with tempfile.TemporaryDirectory() as tmp:
        rows, rests = [], {}
        for path in sorted(folder.glob("*/recording.csv")):
            car = path.parent.name
            rec, veh = load_drive(path, path.parent / "vehicle.json")
            cut = rec.t[0] + real_drives.TRAIN_FRACTION * rec.duration
            first = real_drives.without_torques(rec, rec.t[0], cut)
            (Path(tmp) / car).mkdir()
            first.to_csv(Path(tmp) / car / "recording.csv")
            rows.append(
                {
                    "car": car,
                    "recording": f"{car}/recording.csv",
                    "vehicle": str(path.parent / "vehicle.json"),
                    "time": 0,
                }
            )
            rests[car] = (real_drives.without_torques(rec, cut, rec.t[-1]), veh, path.parent)
        manifest = Path(tmp) / "manifest.csv"
        pd.DataFrame(rows).to_csv(manifest, index=False)
        fleet_out = Path(tmp) / "out"
        settings = quick_settings() if quick else FleetSettings()
        records = fleet(manifest, fleet_out, settings, Cluster(workers=workers), log=print).records
        misfits = {}
        if (fleet_out / "misfit.json").exists():
            misfits = {m["platform"]: m for m in json.loads((fleet_out / "misfit.json").read_text())}
        out = {}
        for r in records:
            if not r.get("parameters"):
                out[r["car"]] = {
                    "method": r["method"],
                    "error": r.get("error"),
                    "fleet_seconds": r["seconds"],
                }
                continue
            rest, veh, source = rests[r["car"]]
            names = list(r["parameters"])
            effects = tuple(dict.fromkeys(n.split(".")[0] for n in names if "." in n))
            start = time.perf_counter()
            alone = api.identify(
                str(Path(tmp) / r["car"] / "recording.csv"),
                veh,
                api.IdentifyOptions(
                    drive=api.DriveOptions(holdout=0.0, longitudinal="speed"),
                    model=api.ModelOptions(effects=effects),
                    budget=api.Budget(rounds=1, sims=300) if quick else api.Budget(),
                ),
            )
            seconds = time.perf_counter() - start
            test = make_problem(
                rest, veh, ProblemSettings(longitudinal="speed", max_window=10.0, held_out=0.0)
            )
            drawn = _fleet_draws(fleet_out / "drives" / r["key"], r, test.channels)
            fleet_est = [r["parameters"][n]["estimate"] for n in names]
            alone_params = alone.summary["parameters"]
            alone_noise = [alone.summary["noise_model"][c]["residual_rms"] for c in test.channels]
            ref = real_drives.reference(r["car"], source)
            params = {}
            for name, p in r["parameters"].items():
                q = alone_params.get(name)
                if q is not None:
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
                "test_seconds": round(float(test.train.sum()) * test.compared_dt, 1),
                "held_out": {
                    "fleet": _held_out(test, names, fleet_est, effects, drawn),
                    "identify": _held_out(
                        test,
                        list(alone_params),
                        [alone_params[n]["estimate"] for n in alone_params],
                        effects,
                        (alone.predictive, alone_noise),
                    ),
                    "least_squares": real_drives.baseline(alone.problem, test, ref, [0.0])["nrmse"],
                },
                "parameters": params,
                "diagnosis": None
                if misfit is None
                else {k: misfit[k] for k in ("detected", "named", "claimed", "verdict")},
            }
    return out


#: Draws resampled from a fleet answer's weighted draws for its predictive band.
BAND_DRAWS = 200


def _fleet_draws(folder: Path, record: dict, channels) -> tuple:
    """(draws, noise std per channel of `channels`) of a fleet answer: its weighted draws
    resampled, or an escalated drive's `identify` draws."""
    from vdsbi.fleet import DRAWS_FILE

    if record["method"] == "identify":
        import pandas as pd

        res = json.loads((folder / "identify" / "posterior.json").read_text())
        draws = pd.read_csv(folder / "identify" / "predictive_draws.csv").to_numpy()
        return draws, [res["noise_model"][c]["residual_rms"] for c in channels]
    saved = np.load(folder / DRAWS_FILE)
    pick = np.random.default_rng(0).choice(len(saved["weights"]), BAND_DRAWS, p=saved["weights"])
    scale = dict(zip(saved["channels"], saved["noise_scale"]))
    return saved["theta"][pick], [scale[c] for c in channels]


def _held_out(test, names: list[str], estimate: list[float], effects: tuple, drawn) -> dict:
    """The point estimate's held-out NRMSE per channel and the share of held-out samples inside
    the 90 % predictive band of the draws (with their noise model)."""
    import jax

    from vdsbi.problem.validation import band_coverage, predict, predictive_band
    from vdsbi.simulator.effects import get_effect

    est = np.asarray(estimate, float)
    values = {e: {p: float(est[names.index(f"{e}.{p}")]) for p in get_effect(e).param_names} for e in effects}
    pred, ok = predict(test, est[:6], effects, values)
    draws, noise = drawn
    band = predictive_band(
        jax.random.key(0), test, np.asarray(draws, float), np.asarray(noise, float), effects
    )
    return {
        "nrmse": real_drives.nrmse(test, pred, test.train) if ok else None,
        "band_coverage": band_coverage(test, band, test.train),
    }


def real_markdown(s: dict) -> str:
    lines = [
        "# The shared real drives as a fleet: the first 70 % of each, scored on the rest",
        "",
        "| drive | level | held-out NRMSE yaw rate / a_y: fleet | identify alone | LS fit | inside 90 % band (yaw rate / a_y): fleet | identify alone | seconds: fleet / identify |",
        "|---|---|---|---|---|---|---|---|",
    ]
    two = lambda d: " / ".join(
        "–" if d is None or d.get(c) is None else f"{d[c]:.3f}" for c in ("yaw_rate", "ay")
    )
    share = lambda d: " / ".join(
        "–" if d.get(c) is None else f"{100 * d[c]:.0f}%" for c in ("yaw_rate", "ay")
    )
    for car, r in s.items():
        if "held_out" not in r:
            continue
        h = r["held_out"]
        lines.append(
            f"| {car} | {r['method']} | {two(h['fleet']['nrmse'])} | {two(h['identify']['nrmse'])} | "
            f"{two(h['least_squares'])} | {share(h['fleet']['band_coverage'])} | "
            f"{share(h['identify']['band_coverage'])} | {r['fleet_seconds']} / {r['identify_seconds']} |"
        )
    lines += [
        "",
        "Each drive is a car of its own (its platform's estimator trained on it alone). The estimate "
        "scored is each table's `estimate` column; the band is the posterior's draws (the fleet's "
        "importance-weighted draws, resampled) with its noise model. A drive escalated to `identify` is "
        "answered by the same call as `identify` alone. The fleet's seconds are the drive's own on its "
        "worker, the first drive of its platform there, so compiling is in them; `benchmarks/fleet.py` "
        "measures speed.",
        "",
    ]
    for car, r in s.items():
        if "parameters" not in r:
            lines += [f"## {car}: {r['method']} in {r['fleet_seconds']} s: {r.get('error')}", ""]
            continue
        checks = ", ".join(f"{k} k̂ {v['k_hat']}" for k, v in (r["checks"] or {}).items())
        lines += [
            f"## {car}: {r['method']} ({checks}); the held-out part {r['test_seconds']} s",
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
        s = real(Path(args.real), args.workers, args.quick)
        stem = "fleet_real_quick" if args.quick else "fleet_real"
        RESULTS.mkdir(exist_ok=True)
        (RESULTS / f"{stem}.json").write_text(json.dumps(s, indent=1) + "\n")
        (RESULTS / f"{stem}.md").write_text(real_markdown(s))
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
