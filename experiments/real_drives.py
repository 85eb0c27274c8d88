"""Every real drive in ../shared/real: vdsbi's default `identify` on the first 70 % of the drive,
scored on the rest against the hand-written least-squares fit.

    python experiments/real_drives.py [--quick] [--drives NAME ...] [--sims N] [--rounds N]

Besides every drive, `STRESS` variants of a shared drive as unseen cars come (sampled at 25 Hz,
the steer logged 0.2 s before the car responds).

Protocol, per drive (torque columns dropped: the longitudinal motion follows the measured speed,
as for most real logs): `vdsbi.api.identify` with its defaults on the first 70 % of the
recording; the rest is cut into the same 10-s windows (5 Hz low-pass, each window from its own
measured state) and scored by NRMSE of yaw rate and a_y for
- vdsbi's exported estimate (what `vdsbi export` writes),
- `linear_baseline`: the linear single-track least-squares fit an engineer would write (numpy and
  scipy only; l_f and I_z from the lab or the data sheet), fitted on identify's training windows,
  with and without a fitted steer delay;
and the share of the held-out samples inside vdsbi's 90 % predictive band, l_f's 95 % interval
against the lab's value, the combinations the drive determines, and identify's wall time.

Writes experiments/results/real_drives{_quick}.json and .md.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))

import linear_baseline  # noqa: E402

from vdsbi import api  # noqa: E402
from vdsbi.io import build_recording, load_drive  # noqa: E402
from vdsbi.problem import ProblemSettings, make_problem  # noqa: E402
from vdsbi.problem.validation import band_coverage, channel_scores, predict, predictive_band  # noqa: E402
from vdsbi.simulator.effects import get_effect  # noqa: E402

REAL = Path(__file__).resolve().parents[2] / "shared" / "real"
RESULTS = Path(__file__).parent / "results"
#: Reference values the recordings' sources give (estimates, not ground truth): l_f, I_z.
REFERENCE = {
    "vw_gti": {"l_f": 1.264, "I_z": 2763.0, "source": "the source lab"},
    "comma_rav4": {"l_f": 1.166, "I_z": 2952.0, "source": "openpilot (a heuristic)"},
}
CHANNELS = ("yaw_rate", "ay")
TRAIN_FRACTION = 0.7
#: Stress variants of a shared drive, as the unseen cars come: name -> (drive, rate Hz, steer lag s).
#: The recording is sampled at `rate` (every n-th row) and its steer advanced by `lag`, so the car
#: responds `lag` s after the logged steer.
STRESS = {"vw_gti_high_speed_2 @ 25 Hz, steer 0.2 s early": ("vw_gti_high_speed_2", 25.0, 0.2)}


def reference(name: str, folder: Path | None = None) -> dict:
    """The drive folder's reference.json (a simulated drive's truth), else `REFERENCE`."""
    if folder is not None and (folder / "reference.json").is_file():
        return json.loads((folder / "reference.json").read_text())
    return next(v for k, v in REFERENCE.items() if name.startswith(k))


def without_torques(rec, t0: float, t1: float):
    """[t0, t1] s of `rec` without its torque columns (as most real logs come); the file's rate is
    kept, so the noise is estimated as for the file."""
    part = rec.slice(t0, t1)
    return dataclasses.replace(
        part, torque_front=None, torque_rear=None, source=f"{rec.source} [{t0:.1f}, {t1:.1f}] s"
    )


def nrmse(problem, pred, mask) -> dict[str, float]:
    """Held-out NRMSE of the channels compared here, by the code identify scores with."""
    scores = channel_scores(problem, pred, mask)
    return {c: scores[c]["nrmse"] for c in CHANNELS if c in scores}


def baseline(train, test, ref: dict, delays) -> dict:
    """The linear single-track fit on `train`'s training windows, predicted on `test`'s windows and
    passed through the problem's filter; the steer delay chosen from `delays` by the training cost."""
    import jax

    car = linear_baseline.Car(
        train.vehicle.mass, ref["l_f"], train.vehicle.wheelbase - ref["l_f"], ref["I_z"]
    )
    step = max(1, int(round(0.02 / train.dt)))  # the baseline integrates at 50 Hz

    def windows(p, mask, d):
        out = []
        for w in range(p.num_windows):
            k = p.t_out[w][mask[w]]
            if not len(k):
                continue
            n = min(p.t.shape[1], int(np.searchsorted(p.t[w], k[-1])) + 1)
            t = p.t[w, :n:step]
            steer = np.interp(t - d, p.t[w, :n], p.u[w, :n, 0])
            out.append((w, t, p.speed[w, :n:step], steer))
        return out

    def targets(p, mask, w, t):
        return [np.interp(t, p.t_out[w][mask[w]], p.y[w, mask[w], p.channels.index(c)]) for c in CHANNELS]

    best = None
    for d in delays:
        wins = [
            (t, v, s, *targets(train, train.train, w, t)) for w, t, v, s in windows(train, train.train, d)
        ]
        cf, cr = linear_baseline.fit(car, wins)
        cost = 0.0
        for t, v, s, r, ay in wins:
            pr, pa = linear_baseline.simulate(car, cf, cr, t, v, s, r[0])
            cost += np.sum(((pr - r) / np.std(r)) ** 2) + np.sum(((pa - ay) / np.std(ay)) ** 2)
        if best is None or cost < best[0]:
            best = (cost, d, cf, cr)
    _, d, cf, cr = best
    pred = np.zeros(test.y.shape)
    for w, t, v, s in windows(test, test.valid, d):
        pr, pa = linear_baseline.simulate(car, cf, cr, t, v, s, test.r0[w])
        full = np.stack([np.interp(test.t[w], t, x) for x in (pr, pa)], -1)
        full = np.asarray(jax.vmap(test.decimator)(full[None]))[0] if test.decimator is not None else full
        for i, c in enumerate(CHANNELS):
            if c in test.channels:
                pred[w, :, test.channels.index(c)] = full[: test.y.shape[1], i]
    return {"C_alpha_f": cf, "C_alpha_r": cr, "delay": d, "nrmse": nrmse(test, pred, test.train)}


def kinematic_ay(test) -> float:
    """Held-out NRMSE of a_y predicted as the measured v·yaw rate: what a perfect yaw-rate model
    would give in steady cornering. Above 1 (worse than predicting 0), the held-out a_y is not
    the lateral dynamics' (noise, bank, body roll) and no single-track model can score there."""
    r = test.y[..., test.channels.index("yaw_rate")]
    v = np.stack([np.interp(test.t_out[w], test.t[w], test.speed[w]) for w in range(test.num_windows)])
    pred = np.zeros(test.y.shape)
    pred[..., test.channels.index("ay")] = v * r
    return channel_scores(test, pred, test.train)["ay"]["nrmse"]


def stressed(rec, rate: float, lag: float):
    """`rec` sampled at `rate` Hz with its steer advanced by `lag` s (the last `lag` s hold the
    last value)."""
    step = max(1, int(round(1.0 / (rate * rec.dt))))
    steer = np.interp(rec.t + lag, rec.t, rec.steer)
    cols = {"t": rec.t, "steer": steer, **rec.channels}
    if rec.has_torques:
        cols |= {"torque_front": rec.torque_front, "torque_rear": rec.torque_rear}
    return build_recording(
        {k: v[::step] for k, v in cols.items()}, f"{rec.source} ({rate:g} Hz, steer {lag:g} s early)"
    )


def run_one(name: str, args, out: Path, true_delay: float | None = None) -> dict:
    """One drive's row; with `true_delay` (a simulated drive's), also the least-squares fit at it."""
    import jax

    drive, rate, lag = STRESS.get(name, (name, None, 0.0))
    rec, veh = load_drive(args.real / drive / "recording.csv", args.real / drive / "vehicle.json")
    if rate is not None:
        rec = stressed(rec, rate, lag)
    cut = rec.t[0] + TRAIN_FRACTION * rec.duration
    first, rest = without_torques(rec, rec.t[0], cut), without_torques(rec, cut, rec.t[-1])
    t0 = time.perf_counter()
    res = api.identify(
        first,
        veh,
        api.IdentifyOptions(budget=api.Budget(rounds=args.rounds, sims=args.sims)),
        out_dir=out / name.split()[0] / str(rate),
        progress=api.Progress(say=print),
    )
    wall = time.perf_counter() - t0
    s = res.summary
    names, effects = list(s["parameters"]), tuple(s["effects"])
    est = np.array([s["parameters"][n]["estimate"] for n in names])
    eff = {e: {p: float(est[names.index(f"{e}.{p}")]) for p in get_effect(e).param_names} for e in effects}
    test = make_problem(rest, veh, ProblemSettings(longitudinal="speed", max_window=10.0, held_out=0.0))
    pred, ok = predict(test, est[:6], effects, eff)
    noise = np.array([s["noise_model"][c]["residual_rms"] for c in test.channels])
    band = predictive_band(jax.random.key(0), test, res.predictive, noise, effects)
    ref = reference(name, args.real / drive)
    lf = s["parameters"]["l_f"]
    row = {
        "drive": name,
        "seconds": {"drive": round(rec.duration, 1), "identify_on": round(first.duration, 1)},
        "used": {k: s["problem"].get(k) for k in ("train_seconds", "lateral_information_share")},
        "test_seconds": round(float(test.train.sum()) * test.compared_dt, 1),
        "wall_s": round(wall, 1),
        "effects": list(effects),
        "estimate": {n: float(v) for n, v in zip(names, est)},
        "interval95": {n: [p["q025"], p["q975"]] for n, p in s["parameters"].items()},
        "ours": nrmse(test, pred, test.train) if ok else None,
        "band_coverage": band_coverage(test, band, test.train),
        "l_f": {
            "estimate": lf["estimate"],
            "q025": lf["q025"],
            "q975": lf["q975"],
            "identified": lf.get("identified"),
            "reference": ref["l_f"],
            "reference_source": ref["source"],
        },
        "combinations": s["combinations"],
        "not_identified": s["not_identified"],
        "model_error": [n for n, p in s["parameters"].items() if "model_error" in p],
        "npe_check": s["npe_check"],
        "noise_model": s["noise_model"],
    }
    row["kinematic_ay"] = kinematic_ay(test)
    row["ls"] = baseline(res.problem, test, ref, [0.0])
    row["ls_delay"] = baseline(res.problem, test, ref, np.arange(0.0, 0.31, 0.02))
    if true_delay is not None:
        row["ls_true_delay"] = baseline(res.problem, test, ref, [true_delay])
    return row


def markdown(rows: list[dict]) -> str:
    f = lambda d, c: "–" if not d or c not in d else f"{d[c]:.3f}"
    L = ["# Real drives: vdsbi identify (defaults) on the first 70 %, scored on the rest", ""]
    L += [
        "| drive | held-out NRMSE yaw rate / a_y: vdsbi estimate | LS fit | LS fit + steer delay | "
        "a_y as measured v·yaw rate | inside 90 % band (yaw rate / a_y) | l_f 95 % [m] vs reference | "
        "understeer gradient [deg/g] | identify wall s |",
        "|---|---|---|---|---|---|---|---|---|",
    ]
    for r in rows:
        lf, us = r["l_f"], r["combinations"]["understeer_gradient"]
        cov = r["band_coverage"]
        lf_txt = (
            "not identified"
            if lf["identified"] is False
            else f"{lf['estimate']:.3f} [{lf['q025']:.3f}, {lf['q975']:.3f}]"
        ) + f" vs {lf['reference']}"
        pct = lambda v: "–" if v is None else f"{v:.0%}"
        L.append(
            f"| {r['drive']} | {f(r['ours'], 'yaw_rate')} / {f(r['ours'], 'ay')} | "
            f"{f(r['ls']['nrmse'], 'yaw_rate')} / {f(r['ls']['nrmse'], 'ay')} | "
            f"{f(r['ls_delay']['nrmse'], 'yaw_rate')} / {f(r['ls_delay']['nrmse'], 'ay')} "
            f"(d = {r['ls_delay']['delay']:.2f} s) | {r['kinematic_ay']:.3f} | {pct(cov.get('yaw_rate'))} / {pct(cov.get('ay'))} | {lf_txt} | "
            f"{us['median']:.2f} [{us['q025']:.2f}, {us['q975']:.2f}]"
            f"{'' if us.get('identified', True) else ' (not identified)'} | {r['wall_s']:.0f} |"
        )
    L.append("")
    L.append(
        "a_y as measured v·yaw rate: the held-out a_y NRMSE of the kinematic prediction a perfect "
        "yaw-rate model would make; above 1 the held-out a_y is not the lateral dynamics' (noise, "
        "bank, roll) and no single-track model can predict it."
    )
    L.append("")
    for r in rows:
        L.append(f"## {r['drive']}")
        L.append("")
        L.append(
            f"effects: {', '.join(r['effects']) or 'none'}; not identified: {', '.join(r['not_identified']) or 'none'}"
        )
        L.append("")
        u = r["used"]
        share = u.get("lateral_information_share")
        L.append(
            f"the estimate is fitted on {u['train_seconds']} s of usable driving in the first 70 % "
            f"({r['seconds']['identify_on']} s)"
            + (
                ""
                if share is None
                else f"; the windows carry {share:.0%} of its lateral information (Σ a_lat²)"
            )
        )
        L.append("")
        L.append("estimate: " + ", ".join(f"{k} {v:.4g}" for k, v in r["estimate"].items()))
        g = r["combinations"]["yaw_rate_gain"]
        L.append(
            f"; yaw-rate gain at {g['at']} m/s: {g['median']:.3f} [{g['q025']:.3f}, {g['q975']:.3f}] 1/s"
        )
        L.append("")
        npe = r["npe_check"]
        L.append(
            f"NPE vs likelihood posterior (training part): D² of the NPE mean {npe['mahalanobis2_of_npe_mean']:.1f} "
            f"(50 % region: ≤ {npe['chi2_50pct']:.1f}); agree: {npe['agree']}; reported: {npe['reported']}"
        )
        L.append("")
        L.append(
            "noise model: "
            + "; ".join(
                f"{c} residual {v['residual_rms']:.3g} = {v['model_error_ratio']:.1f}× sensor, τ {v['autocorrelation_time']:.1f}"
                for c, v in r["noise_model"].items()
            )
        )
        L.append("")
    return "\n".join(L) + "\n"


def write_rows(stem: str, rows: list[dict], markdown) -> None:
    """results/<stem>.json (the rows) and results/<stem>.md (`markdown(rows)`, also printed)."""
    RESULTS.mkdir(exist_ok=True)
    (RESULTS / f"{stem}.json").write_text(json.dumps(rows, indent=2, default=float) + "\n")
    (RESULTS / f"{stem}.md").write_text(markdown(rows))
    print(markdown(rows))


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--quick", action="store_true", help="one short drive, 300 simulations (a smoke test)")
    ap.add_argument("--drives", nargs="*", default=None)
    ap.add_argument("--sims", type=int, default=None)
    ap.add_argument("--rounds", type=int, default=None)
    ap.add_argument(
        "--out", type=Path, default=None, help="folder for identify's runs (default: a temporary one)"
    )
    ap.add_argument("--real", type=Path, default=REAL, help="folder of drives (default ../shared/real)")
    ap.add_argument("--rows", type=Path, default=None, help="write the rows here (JSON) and stop")
    ap.add_argument(
        "--merge", type=Path, nargs="*", default=None, help="tabulate rows written by --rows runs"
    )
    args = ap.parse_args(argv)
    if args.merge is not None:
        write_rows("real_drives", [r for f in args.merge for r in json.loads(f.read_text())], markdown)
        return 0
    drives = args.drives or [
        *sorted(p.name for p in args.real.iterdir() if (p / "recording.csv").is_file()),
        *(k for k, (d, _, _) in STRESS.items() if (args.real / d / "recording.csv").is_file()),
    ]
    if args.quick:
        drives = args.drives or ["comma_rav4"]
        args.sims, args.rounds = args.sims or 300, args.rounds or 1
    args.sims, args.rounds = args.sims or 1000, args.rounds or 2
    import tempfile

    tag = "_quick" if args.quick else ""
    with tempfile.TemporaryDirectory() as tmp:
        out = args.out or Path(tmp)
        rows = [run_one(d, args, out) for d in drives]
    if args.rows is not None:
        args.rows.write_text(json.dumps(rows, indent=2, default=float) + "\n")
        return 0
    write_rows(f"real_drives{tag}", rows, markdown)
    return 0


if __name__ == "__main__":
    sys.exit(main())
