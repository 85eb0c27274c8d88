"""The diagnose → identify loop on a real drive with a steer lag.

    python experiments/real_loop.py [--drive NAME] [--lag SECONDS] [--quick]

A real drive (torque columns dropped) with its steer signal advanced by `--lag` s, so the car's
response lags the logged steer as on a car whose steering is logged upstream of its actuator:
`vdsbi identify` (defaults) on the first 70 %; `vdsbi diagnose` on the same part; the identify
command diagnose prints, with the effects and prior ranges it measured; both estimates scored on
the last 30 % (10-s windows, each from its own measured state) by NRMSE of yaw rate and a_y.

Writes experiments/results/real_loop{_quick}.json and .md.
"""

from __future__ import annotations

import argparse
import json
import shlex
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))

from real_drives import REAL, nrmse, without_torques  # noqa: E402

from vdsbi import api  # noqa: E402
from vdsbi.cli import build_parser  # noqa: E402
from vdsbi.io import build_recording, load_drive  # noqa: E402
from vdsbi.problem import ProblemSettings, make_problem, predict  # noqa: E402
from vdsbi.simulator import get_effect  # noqa: E402

RESULTS = Path(__file__).parent / "results"


def lagged(rec, lag: float):
    """`rec` with its steer advanced by `lag` s (the last `lag` s hold the last value)."""
    steer = np.interp(rec.t + lag, rec.t, rec.steer)
    return build_recording(
        {"t": rec.t, "steer": steer, **rec.channels}, f"{rec.source} (steer {lag:g} s early)"
    )


def score(res, test) -> dict:
    s = res.summary
    names, effects = list(s["parameters"]), tuple(s["effects"])
    est = np.array([s["parameters"][n]["estimate"] for n in names])
    eff = {e: {p: float(est[names.index(f"{e}.{p}")]) for p in get_effect(e).param_names} for e in effects}
    pred, ok = predict(test, est[:6], effects, eff)
    return {
        "effects": list(effects),
        "estimate": dict(zip(names, est.tolist())),
        "nrmse": nrmse(test, pred, test.train) if ok else None,
    }


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--drive", default="vw_gti_high_speed_2")
    ap.add_argument("--lag", type=float, default=0.2)
    ap.add_argument("--real", type=Path, default=REAL)
    ap.add_argument("--quick", action="store_true", help="300 simulations, a short diagnosis")
    args = ap.parse_args(argv)
    budget = {"rounds": 1, "sims": 300} if args.quick else {}
    rec, veh = load_drive(args.real / args.drive / "recording.csv", args.real / args.drive / "vehicle.json")
    rec = lagged(rec, args.lag)
    cut = rec.t[0] + 0.7 * rec.duration
    first, rest = without_torques(rec, rec.t[0], cut), without_torques(rec, cut, rec.t[-1])
    test = make_problem(rest, veh, ProblemSettings(longitudinal="speed", max_window=10.0, held_out=0.0))
    t0 = time.perf_counter()
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        first.to_csv(tmp / "first.csv")
        (tmp / "vehicle.json").write_text(json.dumps(veh.to_dict()))
        rec_path, veh_path = str(tmp / "first.csv"), str(tmp / "vehicle.json")
        before = api.identify(rec_path, veh_path, out_dir=tmp / "identify", log=print, **budget)
        found = api.diagnose(rec_path, veh_path, tmp / "diagnose", longitudinal="speed", quiet=True)
        command = found.report["identify_command"]
        print(command)
        parsed = build_parser().parse_args(shlex.split(command)[1:])
        add = [] if parsed.effects in (None, "none") else parsed.effects.lstrip("+").split(",")
        priors = {p.split("=")[0]: tuple(map(float, p.split("=")[1].split(":"))) for p in parsed.prior}
        after = api.identify(rec_path, veh_path, add_effects=add, priors=priors, log=print, **budget)
    row = {
        "drive": args.drive,
        "lag_s": args.lag,
        "diagnosis": {
            "chosen": found.report["chosen"],
            "effect_params": found.report.get("effect_params"),
            "command": command.replace(str(tmp), "DRIVE"),
        },
        "before": score(before, test),
        "after": score(after, test),
        "seconds": round(time.perf_counter() - t0, 1),
    }
    tag = "_quick" if args.quick else ""
    RESULTS.mkdir(exist_ok=True)
    (RESULTS / f"real_loop{tag}.json").write_text(json.dumps(row, indent=2, default=float) + "\n")
    f = lambda d: "–" if d is None else f"{d['yaw_rate']:.3f} / {d['ay']:.3f}"
    text = "\n".join(
        [
            f"# The loop on {args.drive} with its steer logged {args.lag:g} s early",
            "",
            f"diagnose named: {', '.join(found.report['chosen']) or 'nothing'}; it printed:",
            "",
            f"    {row['diagnosis']['command']}",
            "",
            "| run | held-out NRMSE (yaw rate / a_y) | effects |",
            "|---|---|---|",
            f"| identify (defaults) | {f(row['before']['nrmse'])} | {', '.join(row['before']['effects'])} |",
            f"| the printed identify | {f(row['after']['nrmse'])} | {', '.join(row['after']['effects'])} |",
            "",
            f"{row['seconds']:.0f} s in all.",
        ]
    )
    (RESULTS / f"real_loop{tag}.md").write_text(text + "\n")
    print(text)
    return 0


if __name__ == "__main__":
    sys.exit(main())
