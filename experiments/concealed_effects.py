"""Proof of mismatch discovery on recordings with concealed effects.

Makes recordings in which one effect, two effects or none are concealed, WRITES THEM AS FILES
(recording.csv, vehicle.json with noise_std; the truth in a separate truth.json that the
diagnosis never reads), runs `vdsbi.discovery.diagnose_mismatch` on the two files alone, and scores
what it found against truth.json.

Generator (documented so the ranges can be judged):
  * vehicle: mass U[1200, 2000] kg, wheelbase U[2.5, 2.9] m, other constants of
    `default_vehicle()`;
  * θ: l_f U[0.4, 0.6]·L, h_cog U[0.35, 0.7] m, C_kappa U[8, 25] × static axle load,
    C_alpha U[5, 15] × static axle load (per axle, independently);
  * maneuver: `random_profile` (20 s, 200 Hz), initial speed U[12, 25] m/s; where an effect that
    acts only at speed is concealed (`FAST_EFFECTS`: downforce), U[35, 50] m/s with the steer
    scaled to ask for up to 1.5 μ·g at that speed; draws in which the car slows below 4 m/s or a
    wheel exceeds 250 rad/s are redrawn;
  * effects: each parameter from its effect's `typical` range; for ranges symmetric about 0
    the magnitude is U[a/3, a] with a random sign (the lower third is excluded so the effect is
    not vanishingly small), one-sided ranges U[low, high];
  * sensor noise: additive white Gaussian, std ax, ay U[0.05, 0.15] m/s², yaw_rate
    U[0.002, 0.006] rad/s, omega U[0.05, 0.15] rad/s, vx U[0.02, 0.08] m/s; vx recorded in half of
    the recordings; the std is written to vehicle.json's noise_std;
  * simulated with the simulator's default solver (RK4, 2.5 ms), or with ``--generator adaptive``
    by diffrax Tsit5 at rtol = atol = 1e-9 (numerics independent of the diagnosis's RK4).

Suites (``--suite``):
  * library (default): one effect of the library per recording (``--per-effect`` each), clean
    ones, and ``--pairs`` random pairs;
  * multi: the fixed pairs and triples of `MULTI` (including the pairs the old search, pairs
    among the three best singles, missed), drawn as above;
  * outside: physics outside the library made by `outside_physics.py` (its docstring documents
    the generator), one recording per kind, plus ``--clean`` clean ones; scored by whether the
    tool named a right library effect or described it by a right discovered term
    (`outside_physics.RIGHT`).

Usage:
    python experiments/concealed_effects.py [--quick] [--suite library|multi|outside]
        [--data DIR] [--out DIR] [--per-effect 3]

Partial results are written after every recording; a restart skips finished recordings.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
import traceback
from pathlib import Path

import jax
import numpy as np
import pandas as pd

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "experiments"))

import outside_physics  # noqa: E402

from vdsbi.discovery import diagnose_mismatch, effect_names  # noqa: E402
from vdsbi.simulator import CHANNELS, PARAM_NAMES, Inputs, Vehicle, default_vehicle, random_profile, simulate  # noqa: E402
from vdsbi.simulator._vehicle import VEHICLE_KEYS  # noqa: E402
from vdsbi.simulator.effects import EFFECTS, EffectSettings  # noqa: E402
from vdsbi.simulator.solvers import Solver  # noqa: E402

NOISE_RANGES = {
    "ax": (0.05, 0.15),
    "ay": (0.05, 0.15),
    "yaw_rate": (0.002, 0.006),
    "omega_front": (0.05, 0.15),
    "omega_rear": (0.05, 0.15),
    "vx": (0.02, 0.08),
}


#: Effects that act only at speed, and the initial speeds (m/s) of the drives that conceal them.
FAST_EFFECTS, FAST_SPEEDS, SLOW_SPEEDS = ("downforce",), (35.0, 50.0), (12.0, 25.0)
#: The fast drives' steer asks for up to this many μ·g at the initial speed (the slow drives'
#: 0.06 rad would spin a car at 40 m/s), so they corner near the limit, where downforce acts.
FAST_GRIP_ASKED = 1.5


def draw_effect(rng, name):
    eff = EFFECTS[name]
    out = {}
    for p, (lo, hi) in zip(eff.param_names, eff.typical):
        if lo < 0 < hi and abs(lo + hi) < 1e-12:
            a = hi
            out[p] = float(rng.uniform(a / 3, a) * rng.choice([-1, 1]))
        else:
            out[p] = float(rng.uniform(lo, hi))
    return out


def case_list(per_effect: int, clean: int, pairs: int, seed: int, only=None):
    rng = np.random.default_rng(seed)
    names = effect_names() if not only else tuple(only)
    all_pairs = [(a, b) for i, a in enumerate(names) for b in names[i + 1 :]]
    pair_idx = rng.choice(len(all_pairs), size=pairs, replace=False)
    cases = []
    rounds = max(per_effect, clean, pairs)
    for r in range(rounds):
        if r < clean:
            cases.append(())
        if r < per_effect:
            cases += [(e,) for e in names]
        if r < pairs:
            cases.append(all_pairs[pair_idx[r]])
    for _ in range(rounds, clean):
        cases.append(())
    return cases


#: The multi suite: pairs (the first three are those the pair search among the top three singles
#: missed or was tested on) and triples.
MULTI = (
    ("aero_drag", "imu_lever_arm"),
    ("imu_misalignment", "wheel_radius_error"),
    ("aero_drag", "imu_misalignment"),
    ("sensor_bias", "wheel_radius_error"),
    ("road_grade", "steering_lag"),
    ("torque_gain", "sensor_scale"),
    ("rolling_resistance", "road_bank", "steering_lag"),
    ("aero_drag", "imu_lever_arm", "sensor_bias"),
)


def make_case(i: int, effects: tuple, seed: int, duration: float, folder: Path, solver=None, kind=None):
    """Write recording.csv, vehicle.json and truth.json of case i; `kind` (outside suite) is
    physics outside the library (`outside_physics`), applied on top of `effects`."""
    rng = np.random.default_rng([seed, i])
    d = default_vehicle()
    consts = {k: float(getattr(d, k)) for k in VEHICLE_KEYS}
    consts["mass"] = float(rng.uniform(1200, 2000))
    consts["wheelbase"] = float(rng.uniform(2.5, 2.9))
    load = consts["mass"] * 9.81 / 2
    L = consts["wheelbase"]
    with_vx = bool(rng.random() < 0.5)
    channels = [c for c in CHANNELS if c != "vx" or with_vx]
    noise = {c: float(rng.uniform(*NOISE_RANGES[c])) for c in channels}
    veh = Vehicle(**consts, noise_std=noise)
    solver_kw = {} if solver is None else {"solver": solver}
    for attempt in range(50):  # noqa: B007
        theta = np.array(
            [
                rng.uniform(0.4, 0.6) * L,
                rng.uniform(0.35, 0.7),
                rng.uniform(8, 25) * load,
                rng.uniform(8, 25) * load,
                rng.uniform(5, 15) * load,
                rng.uniform(5, 15) * load,
            ]
        )
        params = {e: draw_effect(rng, e) for e in effects}
        key = jax.random.key(int(rng.integers(2**31)))
        fast = any(e in FAST_EFFECTS for e in effects)
        v0 = float(rng.uniform(*(FAST_SPEEDS if fast else SLOW_SPEEDS)))
        # neutral steer: a_y ≈ v²·δ/L
        steer = FAST_GRIP_ASKED * consts["friction"] * 9.81 * L / v0**2 if fast else 0.06
        inputs = random_profile(key, duration, max_steer=steer)
        acting = inputs if kind is None else outside_physics.applied_inputs(kind, inputs)
        with jax.enable_x64(True), outside_physics.patched_tyres(kind, consts["mass"]):
            enabled = EffectSettings(enabled=list(effects), params=params)
            ys, ok = simulate(theta, acting, veh, v0=v0, effects=enabled, **solver_kw)
        if kind is not None:
            ys = outside_physics.recorded_readings(kind, ys, float(inputs.dt))
        if ok and np.all(np.isfinite(ys)) and ys[:, 5].min() > 4.0 and np.abs(ys[:, 3:5]).max() < 250:
            break
    else:
        raise RuntimeError(f"case {i}: no valid draw")
    ys = ys + rng.standard_normal(ys.shape) * np.array([noise.get(c, 0.0) for c in CHANNELS])
    folder.mkdir(parents=True, exist_ok=True)
    cols = {
        "t": np.asarray(inputs.ts),
        "steer": np.asarray(inputs.steer),
        "torque_front": np.asarray(inputs.torque_front),
        "torque_rear": np.asarray(inputs.torque_rear),
    }
    cols.update({c: ys[:, CHANNELS.index(c)] for c in channels})
    pd.DataFrame(cols).to_csv(folder / "recording.csv", index=False, float_format="%.10g")
    (folder / "vehicle.json").write_text(json.dumps(veh.to_dict(), indent=2))
    truth = {
        "outside": kind,
        "effects": list(effects),
        "params": params,
        "theta": dict(zip(PARAM_NAMES, theta.tolist())),
        "v0": v0,
        "attempts": attempt + 1,
    }
    (folder / "truth.json").write_text(json.dumps(truth, indent=2))


#: Oracle detectability: a signal with known shape and known θ is found by the likelihood-ratio
#: test at α = 0.01 with 95 % power when λ ≥ (z_0.99 + z_0.95)² ≈ 16. Below it even that oracle
#: misses often, so a draw with λ < 16 carries (next to) no trace of its effect.
ORACLE_LAMBDA = 16.0


def effect_signal(folder: Path, solver=None) -> float:
    """λ = Σ ((y_effect − y_base)/σ)² over the recorded channels: the concealed effects'
    noise-free signal at the true θ, inputs and start (the generator's knowledge, never the
    diagnosis's). Refitting θ absorbs part of it, so it bounds what any test can detect."""
    truth = json.loads((folder / "truth.json").read_text())
    if not truth["effects"]:
        return 0.0
    veh = Vehicle.from_dict(json.loads((folder / "vehicle.json").read_text()))
    rec = pd.read_csv(folder / "recording.csv")
    t = rec["t"].to_numpy()
    inputs = Inputs(
        t0=float(t[0]),
        dt=float(np.round(t[1] - t[0], 9)),
        steer=rec["steer"].to_numpy(),
        torque_front=rec["torque_front"].to_numpy(),
        torque_rear=rec["torque_rear"].to_numpy(),
    )
    theta = np.array([truth["theta"][k] for k in PARAM_NAMES])
    kw = {"v0": truth["v0"], **({} if solver is None else {"solver": solver})}
    with jax.enable_x64(True):
        enabled = EffectSettings(enabled=truth["effects"], params=truth["params"])
        y_eff, _ = simulate(theta, inputs, veh, effects=enabled, **kw)
        y_base, _ = simulate(theta, inputs, veh, **kw)
    sig = np.array([veh.noise_std.get(c, np.inf) for c in CHANNELS])
    return float(np.sum(((np.asarray(y_eff) - np.asarray(y_base)) / sig) ** 2))


def score(truth: dict, rep: dict, seconds: float) -> dict:
    t_eff = tuple(truth["effects"])
    chosen = tuple(rep["chosen"])
    top = rep["effects"][0]
    mag = {}
    for e in t_eff:
        tv = np.array(list(truth["params"][e].values()))
        est = rep["effect_params"].get(e)
        if est is None:
            mag[e] = None
        else:
            ev = np.array([est[k] for k in truth["params"][e]])
            mag[e] = float(np.linalg.norm(ev - tv) / np.linalg.norm(tv))
    before, after = rep["fit"]["before"], rep["fit"]["after"]
    # after the library fix and the discovered terms, where the report claims them
    claimed = rep.get("explanation") == "discovered term"
    fixed = rep["fit"]["after_terms"] if claimed else after
    terms = [{"key": t["key"], "formula": t["formula"]} for t in rep.get("discovered_terms", [])]
    return {
        "outside": truth.get("outside"),
        "explanation": rep.get("explanation"),
        "terms": terms,
        "right_physics": right_physics(truth, chosen, terms if claimed else []),
        "terms_claimed": claimed,
        "ambiguous": rep.get("ambiguous", []),
        "search_steps": rep.get("search_steps"),
        "verdict": rep.get("verdict"),
        "heldout_chi2_fixed": {c: v["chi2_dof"] for c, v in fixed.items()},
        "max_chi2_fixed": max(v["chi2_dof"] for v in fixed.values()),
        # against the predictive variance (noise + the fit's parameter uncertainty), as the
        # report's claim rule measures it
        "max_chi2_fixed_predictive": max(v.get("chi2_dof_predictive", v["chi2_dof"]) for v in fixed.values()),
        "max_chi2_after_predictive": max(v.get("chi2_dof_predictive", v["chi2_dof"]) for v in after.values()),
        "truth": list(t_eff),
        "detected": rep["mismatch_detected"],
        "p_value": rep["p_value"],
        "p_value_after": rep["p_value_after"],
        "chosen": list(chosen),
        "top1": top["effects"],
        "top1_correct": set(top["effects"]) == set(t_eff),
        "named_correct": set(chosen) == set(t_eff),
        "magnitude_rel_error": mag,
        "truth_params": truth["params"],
        "est_params": rep["effect_params"],
        "heldout_chi2_before": {c: v["chi2_dof"] for c, v in before.items()},
        "heldout_chi2_after": {c: v["chi2_dof"] for c, v in after.items()},
        "heldout_nrmse_before": {c: v["nrmse"] for c, v in before.items()},
        "heldout_nrmse_after": {c: v["nrmse"] for c, v in after.items()},
        "max_chi2_after": max(v["chi2_dof"] for v in after.values()),
        "mean_chi2_before": float(np.mean([v["chi2_dof"] for v in before.values()])),
        "mean_chi2_after": float(np.mean([v["chi2_dof"] for v in after.values()])),
        "theta_true": truth["theta"],
        "theta_after": rep["theta"]["after"],
        "theta_q05_q95_after": rep["theta_q05_q95"]["after"],
        "separability": rep["separability"],
        "seconds": seconds,
    }


def right_physics(truth: dict, chosen, terms) -> bool:
    """Library cases: the chosen effects are the truth. Outside cases: a right library effect
    was named or a right term discovered (`outside_physics.RIGHT`)."""
    kind = truth.get("outside")
    if kind is None:
        return set(chosen) == set(truth["effects"])
    lib, right_terms = outside_physics.RIGHT[kind]
    return bool(set(chosen) & lib or {t["key"] for t in terms} & right_terms)


def interval_misses(results: list[dict]) -> tuple[int, int, list[str]]:
    """(truths inside the after-fit's 90 % intervals, truths scored, the misses in words) over
    θ of every recording."""
    inside, total, misses = 0, 0, []
    for i, r in enumerate(results):
        for name, (lo, hi) in (r.get("theta_q05_q95_after") or {}).items():
            truth = r["theta_true"][name]
            total += 1
            if lo <= truth <= hi:
                inside += 1
            else:
                case = r.get("outside") or "+".join(r["truth"]) or "clean"
                misses.append(f"#{i} {case}: {name} {truth:.4g} outside [{lo:.4g}, {hi:.4g}]")
    return inside, total, misses


def _coverage(results: list[dict]) -> dict:
    inside, total, misses = interval_misses(results)
    return {
        "theta_inside_90_after": (inside / total) if total else None,
        "theta_inside_90_after_count": f"{inside} of {total}",
        "theta_outside_90_after": misses,
    }


def summarise_outside(results: list[dict]) -> dict:
    """Figures of the outside suite (recordings with physics outside the library)."""
    out = [r for r in results if r.get("outside")]
    clean = [r for r in results if not r.get("outside") and not r["truth"]]
    frac = lambda a, b: (a / b) if b else None
    claims = [r for r in out if r["explanation"] == "library"]
    return {
        "n_outside": len(out),
        "detection_rate": frac(sum(r["detected"] for r in out), len(out)),
        "false_alarms": f"{sum(r['detected'] for r in clean)} of {len(clean)}",
        "terms_on_clean": sum(bool(r["terms"]) for r in clean),
        "right_physics_named_or_described": frac(sum(r["right_physics"] for r in out), len(out)),
        "library_claims_with_heldout_chi2_le_1.1": f"{sum(r['max_chi2_after'] <= 1.1 for r in claims)} of {len(claims)}",
        "heldout_chi2_fixed_le_1.2": frac(sum(r["max_chi2_fixed"] <= 1.2 for r in out), len(out)),
        "heldout_chi2_fixed_le_1.2_predictive": frac(
            sum(r.get("max_chi2_fixed_predictive", r["max_chi2_fixed"]) <= 1.2 for r in out), len(out)
        ),
        "library_claims_with_predictive_chi2_le_1.1": f"{sum(r.get('max_chi2_after_predictive', 9) <= 1.1 for r in claims)} of {len(claims)}",
        "explanations": {
            k: sum(r["explanation"] == k for r in out)
            for k in ("library", "discovered term", "unexplained", "none")
        },
        "seconds_max": max((r["seconds"] for r in results), default=None),
        **_coverage(results),
    }


def markdown_outside(results: list[dict], summary: dict) -> str:
    L = ["# Physics outside the library: what the tool named or wrote", ""]
    L.append(
        "Generated by `experiments/concealed_effects.py --suite outside` (generator: `experiments/outside_physics.py`)."
    )
    L += ["", "| figure | measured |", "|---|---|"]
    L += [f"| {k} | {v} |" for k, v in summary.items() if k != "theta_outside_90_after"]
    L += _miss_lines(summary)
    L += [
        "",
        "| truth | detected (p) | chosen (library) | discovered term(s) | explanation | right | held-out max χ²/dof before → library → with terms | same, predictive: library → with terms | s |",
    ]
    L.append("|---|---|---|---|---|---|---|---|---|")
    for r in results:
        truth = r.get("outside") or "+".join(r["truth"]) or "clean"
        terms = "; ".join(t["formula"] for t in r["terms"]) or "—"
        L.append(
            f"| {truth} | {r['detected']} ({r['p_value']:.3g}) | {'+'.join(r['chosen']) or 'none'} | {terms} | "
            f"{r['explanation']} | {r['right_physics']} | {max(r['heldout_chi2_before'].values()):.2f} → "
            f"{r['max_chi2_after']:.2f} → {r['max_chi2_fixed']:.2f} | "
            f"{r.get('max_chi2_after_predictive', float('nan')):.2f} → "
            f"{r.get('max_chi2_fixed_predictive', float('nan')):.2f} | {r['seconds']:.0f} |"
        )
    return "\n".join(L) + "\n"


def _miss_lines(summary: dict) -> list[str]:
    misses = summary.get("theta_outside_90_after") or []
    if not misses:
        return []
    return ["", "θ truths outside the after-fit's 90 % interval:", "", *[f"- {m}" for m in misses]]


def summarise(results: list[dict]) -> dict:
    eff_cases = [r for r in results if r["truth"]]
    clean = [r for r in results if not r["truth"]]
    singles = [r for r in results if len(r["truth"]) == 1]
    pairs = [r for r in results if len(r["truth"]) == 2]
    lab = lambda e: "+".join(e) if e else "none"
    labels = ["none", *effect_names()]
    conf: dict = {}
    for r in results:
        t = lab(r["truth"]) if len(r["truth"]) < 2 else "pair"
        c = lab(r["chosen"]) if len(r["chosen"]) < 2 else "pair:" + lab(r["chosen"])
        conf.setdefault(t, {}).setdefault(c, 0)
        conf[t][c] += 1
    per_effect = {}
    for e in labels:
        rs = [r for r in results if r["truth"] == ([] if e == "none" else [e])]
        if not rs:
            continue
        mags = [r["magnitude_rel_error"].get(e) for r in rs if e != "none"]
        per_effect[e] = {
            "n": len(rs),
            "detected": sum(r["detected"] for r in rs),
            "named_correct": sum(r["named_correct"] for r in rs),
            "top1_correct": sum(r["top1_correct"] for r in rs),
            "magnitude_rel_error": mags,
            "magnitude_within_25pct": sum(m is not None and m <= 0.25 for m in mags),
            "heldout_mean_chi2_before": [round(r["mean_chi2_before"], 3) for r in rs],
            "heldout_mean_chi2_after": [round(r["mean_chi2_after"], 3) for r in rs],
            "heldout_max_chi2_after": [round(r["max_chi2_after"], 3) for r in rs],
            "chosen": [lab(r["chosen"]) for r in rs],
            "seconds": [round(r["seconds"], 1) for r in rs],
        }
    frac = lambda a, b: (a / b) if b else None
    traced = [r for r in eff_cases if r.get("signal", np.inf) >= ORACLE_LAMBDA]
    return {
        "n_recordings": len(results),
        "detection_rate": frac(sum(r["detected"] for r in eff_cases), len(eff_cases)),
        # only draws whose effect leaves a trace an oracle would find (λ ≥ ORACLE_LAMBDA)
        "detection_rate_oracle_detectable": frac(sum(r["detected"] for r in traced), len(traced)),
        "signals": [r.get("signal") for r in eff_cases],
        "undetected_signal": [
            {"truth": r["truth"], "signal": r.get("signal"), "p_value": r["p_value"]}
            for r in eff_cases
            if not r["detected"]
        ],
        "false_alarms": f"{sum(r['detected'] for r in clean)} of {len(clean)}",
        "false_alarm_rate": frac(sum(r["detected"] for r in clean), len(clean)),
        "top1_accuracy_single": frac(sum(r["top1_correct"] for r in singles), len(singles)),
        "named_accuracy_single": frac(sum(r["named_correct"] for r in singles), len(singles)),
        "pairs_both_named": f"{sum(r['named_correct'] for r in pairs)} of {len(pairs)}",
        "pairs": [{"truth": r["truth"], "chosen": r["chosen"], "top1": r["top1"]} for r in pairs],
        "triples_all_named": f"{sum(r['named_correct'] for r in results if len(r['truth']) == 3)} of "
        f"{sum(len(r['truth']) == 3 for r in results)}",
        "multi": [
            {
                "truth": r["truth"],
                "chosen": r["chosen"],
                "ambiguous": r.get("ambiguous", []),
                "max_chi2_after": r["max_chi2_after"],
                "seconds": r["seconds"],
            }
            for r in results
            if len(r["truth"]) >= 2
        ],
        "magnitude_within_25pct": frac(
            sum(m is not None and m <= 0.25 for r in eff_cases for m in r["magnitude_rel_error"].values()),
            sum(len(r["magnitude_rel_error"]) for r in eff_cases),
        ),
        "heldout_chi2_after_le_1.1_all_channels": frac(
            sum(r["max_chi2_after"] <= 1.1 for r in eff_cases), len(eff_cases)
        ),
        "heldout_mean_chi2_before_median": float(np.median([r["mean_chi2_before"] for r in eff_cases]))
        if eff_cases
        else None,
        "heldout_mean_chi2_after_median": float(np.median([r["mean_chi2_after"] for r in eff_cases]))
        if eff_cases
        else None,
        "seconds_median": float(np.median([r["seconds"] for r in results])),
        "seconds_max": float(np.max([r["seconds"] for r in results])),
        "within_5_min": f"{sum(r['seconds'] <= 300 for r in results)} of {len(results)}",
        **_coverage(results),
        "confusion_matrix": conf,
        "per_effect": per_effect,
    }


def markdown(summary: dict, targets: dict) -> str:
    L = ["# Concealed effects: mismatch discovery on recordings with known hidden physics", ""]
    L.append("Generated by `experiments/concealed_effects.py` (see its docstring for the generator).")
    L.append("")
    L.append("| figure | measured | target |")
    L.append("|---|---|---|")
    for k, tgt in targets.items():
        L.append(f"| {k} | {summary.get(k)} | {tgt} |")
    missed = summary.get("undetected_signal") or []
    if missed:
        sig = sorted(x for x in summary.get("signals", []) if x is not None)
        L += [
            "",
            "Undetected, with the concealed effect's noise-free signal λ at the true θ "
            "(`effect_signal`; refitting θ absorbs part of it):",
            "",
        ]
        L += [f"- {'+'.join(r['truth'])}: λ = {r['signal']:.3g}, p = {r['p_value']:.3g}" for r in missed]
        if sig:
            L.append(
                f"- λ over all {len(sig)} recordings with an effect: min {sig[0]:.3g}, median "
                f"{sig[len(sig) // 2]:.3g}"
            )
    L += _miss_lines(summary)
    L += ["", "## Per effect", ""]
    L.append(
        "| truth | n | detected | named | top-1 | magnitude rel. error | held-out mean χ²/dof before → after | max after | chosen | s |"
    )
    L.append("|---|---|---|---|---|---|---|---|---|---|")
    for e, d in summary["per_effect"].items():
        mags = ", ".join("—" if m is None else f"{m:.2f}" for m in d["magnitude_rel_error"]) or "—"
        chi = ", ".join(
            f"{a}→{b}" for a, b in zip(d["heldout_mean_chi2_before"], d["heldout_mean_chi2_after"])
        )
        L.append(
            f"| {e} | {d['n']} | {d['detected']} | {d['named_correct']} | {d['top1_correct']} | {mags} | "
            f"{chi} | {', '.join(map(str, d['heldout_max_chi2_after']))} | {', '.join(d['chosen'])} | "
            f"{', '.join(map(str, d['seconds']))} |"
        )
    L += ["", "## Pairs", ""]
    for p in summary["pairs"]:
        L.append(
            f"- truth {'+'.join(p['truth'])}: chosen {'+'.join(p['chosen']) or 'none'}, top-1 {'+'.join(p['top1']) or 'none'}"
        )
    if summary.get("multi"):
        L += ["", "## Several effects (forward search)", ""]
        L.append("| truth | chosen | all named | ambiguity reported | held-out max χ²/dof after | s |")
        L.append("|---|---|---|---|---|---|")
        for m in summary["multi"]:
            ok = set(m["truth"]) == set(m["chosen"])
            amb = "; ".join(m["ambiguous"]) or "—"
            L.append(
                f"| {'+'.join(m['truth'])} | {'+'.join(m['chosen']) or 'none'} | {ok} | {amb} | "
                f"{m['max_chi2_after']:.2f} | {m['seconds']:.0f} |"
            )
    L += ["", "## Confusion matrix (truth → chosen)", ""]
    for t, row in summary["confusion_matrix"].items():
        L.append(f"- {t}: " + ", ".join(f"{c} ×{n}" for c, n in sorted(row.items(), key=lambda x: -x[1])))
    return "\n".join(L) + "\n"


TARGETS = {
    "detection_rate": "≥ 0.95",
    "detection_rate_oracle_detectable": "≥ 0.95 (draws with oracle λ ≥ 16)",
    "false_alarms": "≤ 1 of 4 clean",
    "top1_accuracy_single": "≥ 0.90",
    "named_accuracy_single": "(chosen = truth)",
    "pairs_both_named": "≥ 2 of 3",
    "magnitude_within_25pct": "all",
    "heldout_chi2_after_le_1.1_all_channels": "all",
    "heldout_mean_chi2_before_median": "",
    "heldout_mean_chi2_after_median": "≤ 1.1",
    "seconds_median": "≤ 300",
    "seconds_max": "≤ 300",
    "within_5_min": "all",
    "theta_inside_90_after": "≥ 0.85",
    "theta_inside_90_after_count": "",
}


def plan(args):
    """(cases [(effects, outside kind or None)], duration s, diagnose options, results name)."""
    if args.quick:
        # Quick: 8 s, one RK4 step (5 ms) throughout, so one set of compiled kernels serves all,
        # and the search restricted to a few effects.
        kw = {"num_draws": 100, "final_dt": 0.005}
        if args.suite == "outside":
            kw["candidates"] = ("sensor_bias", "sensor_scale", "imu_misalignment")
            return [((), None), ((), "gyro_scale")], 8.0, kw, "concealed_effects_outside_quick"
        if args.suite == "multi":
            kw["candidates"] = ("road_grade", "rolling_resistance", "sensor_bias", "wheel_radius_error")
            return [(("sensor_bias", "wheel_radius_error"), None)], 8.0, kw, "concealed_effects_multi_quick"
        kw["candidates"] = ("road_grade", "rolling_resistance", "imu_misalignment", "sensor_bias")
        return [((), None), (("sensor_bias",), None)], 8.0, kw, "concealed_effects_quick"
    if args.suite == "multi":
        return [(e, None) for e in MULTI], 20.0, {}, "concealed_effects_multi"
    if args.suite == "outside":
        kinds = [k for _ in range(args.repeats) for k in outside_physics.KINDS]
        cases = [((), None)] * args.clean + [((), k) for k in kinds]
        return cases, 20.0, {}, "concealed_effects_outside"
    cases = case_list(args.per_effect, args.clean, args.pairs, args.seed, args.only)
    name = "concealed_effects" if not args.only else "concealed_effects_" + "_".join(args.only)
    return [(e, None) for e in cases], 20.0, {}, name


def write_results(results: list[dict], planned: int, out: Path, name: str, suite: str) -> None:
    if suite == "outside":
        summary = summarise_outside(results)
    else:
        summary = summarise([r for r in results if not r.get("outside")])
    summary["complete"] = len(results) == planned
    summary["cases_planned"] = planned
    (out / f"{name}.json").write_text(
        json.dumps({"summary": summary, "cases": results}, indent=1, default=float)
    )
    text = markdown_outside(results, summary) if suite == "outside" else markdown(summary, TARGETS)
    (out / f"{name}.md").write_text(text)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument(
        "--quick", action="store_true", help="2 short recordings (clean, sensor_bias), 4 candidate effects"
    )
    ap.add_argument("--data", default="/tmp/vdsbi_concealed", help="where recordings are written")
    ap.add_argument("--out", default=str(ROOT / "experiments" / "results"), help="results folder")
    ap.add_argument("--per-effect", type=int, default=3)
    ap.add_argument("--clean", type=int, default=6)
    ap.add_argument("--pairs", type=int, default=3)
    ap.add_argument("--seed", type=int, default=20240601)
    ap.add_argument("--limit", type=int, default=None, help="stop after this many recordings")
    ap.add_argument(
        "--generator",
        choices=("rk4", "adaptive"),
        default="rk4",
        help="rk4: the simulator's default solver (same numerics as the diagnosis); adaptive: "
        "diffrax Tsit5 at rtol = atol = 1e-9, so the recordings do not share the diagnosis's "
        "discretisation",
    )
    ap.add_argument("--suite", choices=("library", "multi", "outside"), default="library")
    ap.add_argument("--only", nargs="+", default=None, help="library suite: only these effects")
    ap.add_argument("--repeats", type=int, default=1, help="outside suite: recordings per kind")
    # a process-wide JAX setting: only for the script run, never when a caller (a test) imports main
    ap.add_argument("--compile-cache", action=argparse.BooleanOptionalAction, default=argv is None)
    args = ap.parse_args(argv)
    if args.compile_cache:
        jax.config.update("jax_compilation_cache_dir", str(Path(args.data).parent / "vdsbi_jax_cache"))
        jax.config.update("jax_persistent_cache_min_compile_time_secs", 2.0)
    data = Path(args.data) / ("quick" if args.quick else "full")
    if args.suite != "library":
        data = data.with_name(f"{data.name}_{args.suite}")
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    cases, duration, kw, name = plan(args)
    solver = None
    if args.generator == "adaptive":
        solver = Solver(dt=None, rtol=1e-9, atol=1e-9)
        data, name = data.with_name(data.name + "_adaptive"), name + "_adaptive"
    if args.limit:
        cases = cases[: args.limit]
    results = []
    for i, (effects, kind) in enumerate(cases):
        tag = f"outside_{kind}" if kind else "+".join(effects) or "none"
        folder = data / f"case_{i:03d}_{tag}"
        done = folder / "result.json"
        if done.exists():
            r = json.loads(done.read_text())
            if kind is None and "signal" not in r:  # results from before the oracle signal
                r["signal"] = effect_signal(folder, solver)
                done.write_text(json.dumps(r, indent=1, default=float))
            results.append(r)
            continue
        if not (folder / "recording.csv").exists():
            make_case(i, effects, args.seed, duration, folder, solver, kind)
        t0 = time.perf_counter()
        try:
            res = diagnose_mismatch(folder / "recording.csv", folder / "vehicle.json", plots=False, **kw)
        except Exception:
            traceback.print_exc()
            continue
        secs = time.perf_counter() - t0
        (folder / "report.json").write_text(json.dumps(res.report, indent=1, default=float))
        truth = json.loads((folder / "truth.json").read_text())  # read only to score
        r = score(truth, res.report, secs)
        r["case"] = folder.name
        if kind is None:
            r["signal"] = effect_signal(folder, solver)
        done.write_text(json.dumps(r, indent=1, default=float))
        results.append(r)
        # A long run compiles many kernels; free them (they reload from the persistent
        # cache) or the process runs out of memory mappings for LLVM's JIT.
        jax.clear_caches()
        print(
            f"[{i + 1}/{len(cases)}] {folder.name}: detected={r['detected']} p={r['p_value']:.3g} "
            f"chosen={'+'.join(r['chosen']) or 'none'} mag={r['magnitude_rel_error']} "
            f"chi2 {r['mean_chi2_before']:.2f}->{r['mean_chi2_after']:.2f} ({secs:.0f} s)",
            flush=True,
        )
        write_results(results, len(cases), out, name, args.suite)
    if results:
        write_results(results, len(cases), out, name, args.suite)
    if results and args.suite == "outside":
        print(json.dumps(summarise_outside(results), indent=1))
    elif results:
        s = summarise(results)
        print(json.dumps({k: s[k] for k in TARGETS if k in s}, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
