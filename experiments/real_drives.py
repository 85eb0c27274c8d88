"""The real VW GTI drives (../shared/real/) identified over the whole drive, proven on held-out driving.

    python experiments/real_drives.py [--quick] [--rounds N] [--sims N] [--drives NAME ...]
                                      [--modes speed torque] [--no-diagnose]

For each drive and mode ("speed": torque columns dropped, the longitudinal motion follows the
measured speed; "torque": the file's *commanded* torques drive the wheels), `vdsbi.api.identify`
runs on the first 70 % of the usable driving and is scored on the last 30 % (held-out windows,
each started from its own measured state, channels low-passed at 5 Hz as identify compares them).
Beside it, on the same held-out windows and filter: the source lab's values (l_f 1.264 m,
C_αf 80 / C_αr 120 kN/rad linear) in our model, and `linear_baseline` — the least-squares
linear single-track model an engineer would write (numpy/scipy, independent of vdsbi) — fitted
on the same training windows. NRMSE = RMS error / std of the measurement. `vdsbi.api.diagnose`
then says what it finds on the drive (speed mode).

Writes experiments/results/real_drives{_quick}.json/.md and, per drive and mode,
experiments/results/real_drives{_quick}/<drive>_<mode>/ (identify's files, overlay.png).
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
from vdsbi.problem import ProblemSettings, make_problem, predict  # noqa: E402

REAL = Path(__file__).resolve().parents[2] / "shared" / "real"
RESULTS = Path(__file__).parent / "results"
DRIVES = ("vw_gti_high_speed_2", "vw_gti_low_speed")
#: Source lab's values (../shared/real/README.md): estimates, not ground truth.
LAB = {"l_f": 1.264, "C_alpha_f": 80e3, "C_alpha_r": 120e3}
LAB_IZ = 2763.0
CHANNELS = ("yaw_rate", "ay")


def drop_torques(rec):
    cols = {"t": rec.t, "steer": rec.steer, **rec.channels}
    return build_recording(cols, rec.source + " (torque columns dropped)")


def by_channel(problem, pred) -> dict[str, np.ndarray]:
    """(W, K) arrays of the compared channels of interest, keyed by name."""
    return {c: pred[..., problem.channels.index(c)] for c in CHANNELS if c in problem.channels}


def nrmse(problem, pred: dict) -> dict[str, float]:
    mask = problem.held
    out = {}
    for c, p in pred.items():
        y = problem.y[..., problem.channels.index(c)][mask]
        out[c] = float(np.sqrt(np.mean((p[mask] - y) ** 2)) / np.std(y))
    return out


def baseline(problem, rec, vehicle) -> tuple[dict, np.ndarray]:
    """Fit the linear single-track model on the training windows, predict every window, and pass
    its prediction through the problem's filter; returns (fitted values, (W, K, C) prediction)."""
    car = linear_baseline.Car(vehicle.mass, LAB["l_f"], vehicle.wheelbase - LAB["l_f"], LAB_IZ)
    train_windows = []
    raw = _raw_channels(problem, rec)
    for w, win in enumerate(problem.windows):
        if win.role != "train":
            continue
        n = _valid_len(problem, w)
        train_windows.append(
            (
                problem.t[w, :n],
                problem.speed[w, :n],
                problem.u[w, :n, 0],
                raw["yaw_rate"][w, :n],
                raw["ay_lp"][w, :n],
            )
        )
    cf, cr = linear_baseline.fit(car, train_windows)
    pred = np.zeros((problem.num_windows, problem.t.shape[1], len(problem.channels)))
    for w in range(problem.num_windows):
        r, ay = linear_baseline.simulate(
            car, cf, cr, problem.t[w], problem.speed[w], problem.u[w, :, 0], raw["r0"][w]
        )
        for i, c in enumerate(problem.channels):
            pred[w, :, i] = {"yaw_rate": r, "ay": ay}[c]
    import jax

    filtered = np.asarray(jax.vmap(problem.decimator)(pred))
    return {"C_alpha_f": cf, "C_alpha_r": cr}, filtered


def _valid_len(problem, w) -> int:
    win = problem.windows[w]
    return int(round((win.t1 - win.t0) / problem.dt)) + 1


def _raw_channels(problem, rec) -> dict:
    """The measured yaw rate and a 0.2-s moving average of ay at the model rate (the baseline's
    fitting targets, as an engineer would smooth ay against its vibration)."""
    n = max(1, int(round(0.2 * rec.rate)))
    out = {}
    for key, name in (("yaw_rate", "yaw_rate"), ("ay_lp", "ay")):
        x = rec.channels[name]
        if key == "ay_lp":
            x = np.convolve(np.pad(x, (n // 2, n - 1 - n // 2), mode="edge"), np.ones(n) / n, mode="valid")
        out[key] = np.stack([_window_series(rec, problem, w, x) for w in range(problem.num_windows)])
    out["r0"] = problem.r0
    return out


def _window_series(rec, problem, w, x):
    i0 = int(np.searchsorted(rec.t, problem.windows[w].t0 - 1e-9))
    seg = x[i0 : i0 + problem.t.shape[1]]
    return np.concatenate([seg, np.repeat(seg[-1:], problem.t.shape[1] - len(seg))])


def overlay(path, problem, preds: dict[str, np.ndarray]) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    held = [w for w, win in enumerate(problem.windows) if win.role == "held"]
    chans = [c for c in CHANNELS if c in problem.channels]
    fig, axes = plt.subplots(len(chans), 1, figsize=(11, 2.6 * len(chans)), sharex=True, squeeze=False)
    colours = {
        "ours (refined)": "C0",
        "ours (posterior mean)": "C1",
        "lab values": "C2",
        "linear LS baseline": "C3",
    }
    for k, c in enumerate(chans):
        ax, i = axes[k, 0], problem.channels.index(c)
        for j, w in enumerate(held):
            v = problem.held[w]
            t = problem.t_out[w][v]
            ax.plot(
                t,
                problem.y[w, v, i],
                color="k",
                lw=0.8,
                label="recording (5 Hz low-pass)" if j == 0 else None,
            )
            for name, p in preds.items():
                ax.plot(t, p[c][w, v], color=colours[name], lw=1.0, label=name if j == 0 else None)
        ax.set_ylabel({"yaw_rate": "yaw rate [rad/s]", "ay": "a_y [m/s²]"}[c])
        ax.grid(alpha=0.3)
    axes[0, 0].legend(loc="upper right", fontsize=7, ncol=4)
    axes[0, 0].set_title("held-out driving (never seen by any fit)", fontsize=9, loc="left")
    axes[-1, 0].set_xlabel("t [s]")
    fig.tight_layout()
    fig.savefig(path, dpi=100)
    plt.close(fig)


def run_one(name: str, mode: str, args, out: Path) -> dict:
    rec, veh = load_drive(REAL / name / "recording.csv", REAL / name / "vehicle.json")
    if mode == "speed":
        rec = drop_torques(rec)
    t0 = time.perf_counter()
    res = api.identify(
        rec,
        veh,
        rounds=args.rounds,
        sims=args.sims,
        embedding=args.embedding,
        seed=args.seed,
        out_dir=out,
        longitudinal=mode,
        bandwidth=5.0,
        compare=LAB,
        log=print,
    )
    wall = time.perf_counter() - t0
    s = res.summary
    window = 10.0 if mode == "speed" else 20.0
    names = list(s["parameters"])
    mean = np.array([s["parameters"][n]["mean"] for n in names])
    refined = np.array([s["refined"]["values"][n] for n in names]) if "refined" in s else mean
    ref = np.array([LAB.get(n, m) for n, m in zip(names, refined)])
    estimates = {"ours (posterior mean)": mean, "ours (refined)": refined, "lab values": ref}
    scored, overlays = {}, {}
    # The comparison grid: identify's own problem (same windows, same 5 Hz filter), and the same
    # with the detected slide kept in (every held-out second scored).
    for limit in ("exclude", "keep"):
        settings = ProblemSettings(longitudinal=mode, max_window=window, bandwidth=5.0, limit_handling=limit)
        problem = make_problem(rec, veh, settings)
        preds = {
            k: by_channel(problem, _predict(problem, v, names, s["effects"])) for k, v in estimates.items()
        }
        speed_problem = problem
        if mode == "torque":
            # The same windows (same recording, same segments), followed by the measured speed.
            speed_problem = make_problem(rec, veh, dataclasses.replace(settings, longitudinal="speed"))
        base_fit, base_pred = baseline(speed_problem, rec, veh)
        preds["linear LS baseline"] = by_channel(speed_problem, base_pred)
        scored[limit] = {k: nrmse(problem, v) for k, v in preds.items()}
        overlays[limit] = (problem, preds)
    problem, preds = overlays["exclude"]
    overlay(out / "overlay.png", problem, {k: v for k, v in preds.items() if k != "ours (posterior mean)"})
    return {
        "drive": name,
        "mode": mode,
        "wall_s": wall,
        "parameters": s["parameters"],
        "refined": s.get("refined"),
        "not_identified": s["not_identified"],
        "effects": s["effects"],
        "windows": s["problem"]["windows"],
        "rejected": problem.description["rejected"],
        "held_out_nrmse": scored["exclude"],
        "held_out_nrmse_slides_kept": scored["keep"],
        "baseline_fit": base_fit,
        "validation": s["validation"],
        "ppc": s["ppc"],
        "warnings": s.get("warnings", []),
    }


def _predict(problem, values, names, effects):
    pred, _ = predict(problem, values[:6], effects, _effect_values(names, values))
    return pred


def _effect_values(names, values) -> dict:
    out: dict = {}
    for n, v in zip(names[6:], values[6:]):
        e, p = n.split(".")
        out.setdefault(e, {})[p] = float(v)
    return out


def diagnose_one(name: str, out: Path) -> dict:
    rec, veh = load_drive(REAL / name / "recording.csv", REAL / name / "vehicle.json")
    t0 = time.perf_counter()
    res = api.diagnose(drop_torques(rec), veh, out, longitudinal="speed", quiet=False)
    rep = res.report
    return {
        "wall_s": time.perf_counter() - t0,
        "p_value": rep["p_value"],
        "chosen": rep["chosen"],
        "verdict": rep["verdict"],
        "held_out_chi2_dof": {
            c: [rep["fit"]["before"][c]["chi2_dof"], rep["fit"]["after"][c]["chi2_dof"]]
            for c in rep["fit"]["before"]
        },
    }


def markdown(rows: list[dict], diag: dict) -> str:
    out = ["# Real VW GTI drives: whole drive, held-out validation", ""]
    for r in rows:
        out += [f"## {r['drive']}, {r['mode']}-driven ({r['wall_s']:.0f} s)", ""]
        out.append(
            f"effects in θ: {', '.join(r['effects']) or 'none'}; not identified: {', '.join(r['not_identified']) or 'none'}"
        )
        excluded = [x for x in r.get("rejected", []) if str(x[2]).startswith("limit handling")]
        for a, b, why in excluded:
            out.append(f"\nexcluded {a:.1f}–{b:.1f} s: {why}")
        refined = (r.get("refined") or {}).get("values", {})
        out += ["", "| param | ours mean | 95 % interval | ours refined | lab |", "|---|---|---|---|---|"]
        for n, p in r["parameters"].items():
            lab = LAB.get(n, "")
            if p.get("identified") is False:
                out.append(
                    f"| {n} | not identified | (prior {p['prior'][0]:.4g}–{p['prior'][1]:.4g}) | | {lab} |"
                )
            else:
                ref = f"{refined[n]:.4g}" if n in refined else ""
                out.append(f"| {n} | {p['mean']:.4g} | {p['q025']:.4g}–{p['q975']:.4g} | {ref} | {lab} |")
        out += [
            "",
            "| held-out NRMSE | yaw rate | a_y (5 Hz) | yaw rate, slide kept | a_y, slide kept |",
            "|---|---|---|---|---|",
        ]
        kept = r.get("held_out_nrmse_slides_kept", {})
        for k, v in r["held_out_nrmse"].items():
            w = kept.get(k, {})
            cells = [v.get("yaw_rate"), v.get("ay"), w.get("yaw_rate"), w.get("ay")]
            out.append(f"| {k} | " + " | ".join("" if c is None else f"{c:.3f}" for c in cells) + " |")
        out += [""]
    for name, d in diag.items():
        out += [
            f"## diagnose {name} (speed-driven)",
            "",
            f"- p = {d['p_value']:.3g}; chosen: {d['chosen'] or 'none'}; {d['verdict']}",
        ]
        for c, (b, a) in d["held_out_chi2_dof"].items():
            out.append(f"- {c}: held-out χ²/dof {b:.3g} → {a:.3g}")
        out.append("")
    return "\n".join(out)


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--quick", action="store_true", help="1 round × 200 simulations, one drive, speed mode")
    p.add_argument("--rounds", type=int, default=3)
    p.add_argument("--sims", type=int, default=2000)
    p.add_argument("--embedding", default="stats", choices=("stats", "cnn"))
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--drives", nargs="*", default=list(DRIVES))
    p.add_argument("--modes", nargs="*", default=["speed", "torque"])
    p.add_argument("--no-diagnose", action="store_true")
    p.add_argument("--out", default=str(RESULTS))
    args = p.parse_args(argv)
    if args.quick:
        args.rounds, args.sims, args.drives, args.modes, args.no_diagnose = (
            1,
            200,
            args.drives[:1],
            ["speed"],
            True,
        )
    tag = "_quick" if args.quick else ""
    root = Path(args.out) / f"real_drives{tag}"
    rows, diag = [], {}
    for name in args.drives:
        if not (REAL / name).exists():
            print(f"skip {name}: not found")
            continue
        for mode in args.modes:
            target = root / f"{name}_{mode}"
            if target.exists():
                import shutil

                shutil.rmtree(target)
            rows.append(run_one(name, mode, args, target))
            _write(root, tag, rows, diag)
        if not args.no_diagnose:
            target = root / f"{name}_diagnose"
            if target.exists():
                import shutil

                shutil.rmtree(target)
            diag[name] = diagnose_one(name, target)
            _write(root, tag, rows, diag)
    print(markdown(rows, diag))
    return 0


def _write(root: Path, tag: str, rows, diag) -> None:
    root.parent.mkdir(parents=True, exist_ok=True)
    (root.parent / f"real_drives{tag}.json").write_text(
        json.dumps({"runs": rows, "diagnose": diag}, indent=1, default=float)
    )
    (root.parent / f"real_drives{tag}.md").write_text(markdown(rows, diag) + "\n")


if __name__ == "__main__":
    raise SystemExit(main())
