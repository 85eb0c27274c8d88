"""The diagnose → identify loop on drives whose car responds late to its logged steer.

    python experiments/real_loop.py [--quick] [--cases NAME ...]

Each case is a drive split 70 / 30 in time (no torque columns, as most logs come):

* a real drive with its steer signal advanced by 0.2 s, so the car's response lags the logged steer
  as on a car whose steering is logged upstream of its actuator;
* drives from another simulator (`other_simulator`: a single-track model not ours, no wheel
  speeds) whose road wheels follow the logged steer through a first-order lag, at 25 Hz and 10 Hz.

On the first 70 %: `vdsbi identify` with its defaults; `vdsbi diagnose`; and, where diagnose claims
a fix, the identify command it prints, run through the command line as printed. Both estimates
are scored on the last 30 % (10-s windows, each from its own measured state) by NRMSE of yaw rate
and a_y, beside the linear least-squares fit with the steer delay its training cost picks (the
floor). Reported per case: what diagnose found and claimed, the command, held-out NRMSE before →
after, the parameters identified before → after, the lag's interval against the truth where known,
and diagnose's wall time per 100 s of driving.

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

import linear_baseline  # noqa: E402
import other_simulator  # noqa: E402
from real_drives import REAL, baseline, nrmse, reference, without_torques  # noqa: E402

from vdsbi import api  # noqa: E402
from vdsbi.cli import main as vdsbi  # noqa: E402
from vdsbi.io import build_recording, load_drive  # noqa: E402
from vdsbi.problem import ProblemSettings, make_problem  # noqa: E402
from vdsbi.problem.validation import predict  # noqa: E402
from vdsbi.simulator.effects import get_effect  # noqa: E402

RESULTS = Path(__file__).parent / "results"
TRAIN_FRACTION = 0.7
#: name -> ("real", drive, steer lead s) or ("other", rate Hz, first-order lag s, car, C_αf, C_αr, seed)
CASES = {
    "vw_gti_high_speed_2, steer logged 0.2 s early": ("real", "vw_gti_high_speed_2", 0.2),
    "other simulator @ 25 Hz, 0.2 s first-order steer lag": (
        "other",
        25.0,
        0.2,
        linear_baseline.Car(1450.0, 1.1, 1.55, 2300.0),
        70e3,
        95e3,
        21,
    ),
    "other simulator @ 10 Hz, 0.1 s first-order steer lag": (
        "other",
        10.0,
        0.1,
        linear_baseline.Car(1500.0, 1.15, 1.5, 2600.0),
        80e3,
        100e3,
        22,
    ),
}
#: The lag's parameters, whichever effect models it.
LAGS = ("steering_lag.tau", "signal_delay.delay")


def lagged(rec, lead: float):
    """`rec` with its steer advanced by `lead` s (the last `lead` s hold the last value)."""
    steer = np.interp(rec.t + lead, rec.t, rec.steer)
    return build_recording(
        {"t": rec.t, "steer": steer, **rec.channels}, f"{rec.source} (steer {lead:g} s early)"
    )


def drive(name: str, folder: Path, quick: bool):
    """(recording, vehicle, reference {l_f, I_z, truth?}) of a case."""
    case = CASES[name]
    if case[0] == "real":
        _, real, lead = case
        rec, veh = load_drive(REAL / real / "recording.csv", REAL / real / "vehicle.json")
        return lagged(rec, lead), veh, reference(real)
    _, rate, lag, car, cf, cr, seed = case
    duration = 60.0 if quick else 150.0
    other_simulator.write_drive(folder, rate, lag, car, cf, cr, seed, duration, lag_kind="first_order")
    rec, veh = load_drive(folder / "recording.csv", folder / "vehicle.json")
    return rec, veh, json.loads((folder / "reference.json").read_text())


def estimate(summary: dict, test) -> dict:
    """An identify run's estimate and its held-out NRMSE on `test`."""
    names, effects = list(summary["parameters"]), tuple(summary["effects"])
    est = np.array([summary["parameters"][n]["estimate"] for n in names])
    eff = {e: {p: float(est[names.index(f"{e}.{p}")]) for p in get_effect(e).param_names} for e in effects}
    pred, ok = predict(test, est[:6], effects, eff)
    params = summary["parameters"]
    return {
        "effects": list(effects),
        "nrmse": nrmse(test, pred, test.train) if ok else None,
        "identified": sorted(n for n, p in params.items() if p.get("identified") is not False),
        "lag": {n: [params[n]["estimate"], params[n]["q05"], params[n]["q95"]] for n in LAGS if n in params},
        "trading_pairs": [p["pair"] for p in summary.get("combinations", {}).get("trading_pairs", [])],
    }


def run_case(name: str, quick: bool, tmp: Path) -> dict:
    rec, veh, ref = drive(name, tmp / "source", quick)
    cut = rec.t[0] + TRAIN_FRACTION * rec.duration
    first, rest = without_torques(rec, rec.t[0], cut), without_torques(rec, cut, rec.t[-1])
    test = make_problem(rest, veh, ProblemSettings(longitudinal="speed", max_window=10.0, held_out=0.0))
    first.to_csv(tmp / "first.csv")
    (tmp / "vehicle.json").write_text(json.dumps(veh.to_dict()))
    rec_path, veh_path = str(tmp / "first.csv"), str(tmp / "vehicle.json")
    budget = ["--rounds", "1", "--sims", "300"] if quick else []
    assert (
        vdsbi(
            ["identify", rec_path, "--vehicle", veh_path, "--out", str(tmp / "identify"), *budget, "--quiet"]
        )
        == 0
    )
    before = json.loads((tmp / "identify" / "posterior.json").read_text())
    t0 = time.perf_counter()
    found = api.diagnose(rec_path, veh_path, tmp / "diagnose", longitudinal="speed", quiet=True)
    diagnose_s = time.perf_counter() - t0
    rep = found.report
    command = rep["identify_command"]
    after = None
    if command:
        argv = shlex.split(command)
        assert vdsbi([*argv[1:], *budget, "--quiet"]) == 0
        after = json.loads((Path(argv[argv.index("--out") + 1]) / "posterior.json").read_text())
    fit_problem = make_problem(
        first, veh, ProblemSettings(longitudinal="speed", max_window=10.0, held_out=0.0)
    )
    floor = baseline(fit_problem, test, ref, np.arange(0.0, 0.31, 0.02))
    return {
        "case": name,
        "truth": ref.get("truth"),
        "fit_seconds": round(first.duration, 1),
        "diagnosis": {
            "base_effects": rep.get("base_effects"),
            "chosen": rep["chosen"],
            "dropped": rep.get("dropped", []),
            "held_out_improved": rep.get("held_out_improved"),
            "verdict": rep["verdict"],
            "not_claimed": rep.get("not_claimed"),
            "command": command.replace(str(tmp), "DRIVE") if command else None,
            "seconds": round(diagnose_s, 1),
            "seconds_per_100s": round(100.0 * diagnose_s / first.duration, 1),
        },
        "before": estimate(before, test),
        "after": None if after is None else estimate(after, test),
        "least_squares": {"nrmse": floor["nrmse"], "delay": floor["delay"]},
    }


def markdown(rows: list[dict]) -> str:
    f = lambda d: (
        "–"
        if d is None or d.get("nrmse") is None
        else f"{d['nrmse']['yaw_rate']:.3f} / {d['nrmse']['ay']:.3f}"
    )
    lines = [
        "# The diagnose → identify loop on drives with a steer lag",
        "",
        'Held-out NRMSE yaw rate / a_y on the last 30 % of each drive. "after": the identify command '
        "diagnose printed, run as printed (none where diagnose claims no fix).",
        "",
        "| case | diagnose found | claimed | held-out: identify | after the loop | LS fit (+ delay) | diagnose, s per 100 s |",
        "|---|---|---|---|---|---|---|",
    ]
    for r in rows:
        d = r["diagnosis"]
        found = ", ".join(d["chosen"] + [f"no {e}" for e in d["dropped"]]) or "nothing"
        claimed = "yes" if d["command"] else "no"
        ls = r["least_squares"]
        lines.append(
            f"| {r['case']} | {found} | {claimed} | {f(r['before'])} | {f(r['after'])} | "
            f"{f(ls)} (delay {ls['delay']:.2f} s) | {d['seconds_per_100s']:.0f} |"
        )
    for r in rows:
        d = r["diagnosis"]
        lines += [
            "",
            f"## {r['case']}",
            "",
            f"Base set (identify's defaults): {', '.join(d['base_effects']) or 'none'}.",
            f"Verdict: {d['verdict']}.",
        ]
        if d["not_claimed"]:
            lines.append(f"Not claimed: {d['not_claimed']}")
        if d["command"]:
            lines += ["", "The printed command:", "", f"    {d['command']}"]
        for key in ("before", "after"):
            e = r[key]
            if e is None:
                continue
            lag = "; ".join(f"{n} {v[0]:.4g} [{v[1]:.4g}, {v[2]:.4g}]" for n, v in e["lag"].items()) or "none"
            pairs = "; ".join(" ~ ".join(p) for p in e["trading_pairs"]) or "none"
            lines.append(
                f"- {key}: effects {', '.join(e['effects'])}; identified {', '.join(e['identified'])}; "
                f"lag (90 %) {lag}; pairs that trade: {pairs}"
            )
        if r["truth"]:
            lines.append(f"- truth: {', '.join(f'{k} {v:.4g}' for k, v in r['truth'].items())}")
        lines.append(f"- diagnose: {d['seconds']:.0f} s on {r['fit_seconds']:.0f} s of driving")
    return "\n".join(lines) + "\n"


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--quick", action="store_true", help="300 simulations, one round; 60 s simulated drives")
    ap.add_argument("--cases", nargs="+", default=list(CASES), choices=list(CASES), metavar="NAME")
    args = ap.parse_args(argv)
    tag = "_quick" if args.quick else ""
    RESULTS.mkdir(exist_ok=True)
    path = RESULTS / f"real_loop{tag}.json"
    # The cases not run now keep their rows (in CASES' order).
    kept = {r["case"]: r for r in json.loads(path.read_text())} if path.exists() else {}
    for name in args.cases:
        with tempfile.TemporaryDirectory() as tmp:
            kept[name] = run_case(name, args.quick, Path(tmp))
        rows = [kept[c] for c in CASES if c in kept]
        # Written as each case finishes: an interrupted run keeps what it measured.
        (RESULTS / f"real_loop{tag}.json").write_text(json.dumps(rows, indent=2, default=float) + "\n")
        (RESULTS / f"real_loop{tag}.md").write_text(markdown(rows))
    print(markdown(rows))
    return 0


if __name__ == "__main__":
    sys.exit(main())
