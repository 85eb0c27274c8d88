"""Observability of the seed's identification problem, by autodiff Fisher information.

    python experiments/observability.py [--quick] [--steps N] [--seeds K]

Setup (the seed's): default_vehicle(), seed_profile() (5 s), θ = SEED_TRUE_THETA, v0 = 10.5 m/s,
the seed's relative sensor noise (floored at zero crossings, see vdsbi.diagnostics._fisher),
channels (ax, ay, yaw_rate, omega_front, omega_rear).

1. Autodiff F (float64, jacfwd) and its report; the seed's Monte-Carlo score estimator for
   growing sample counts against it.
2. The seed's claims with numbers: rear vs front longitudinal stiffness on a front-driven car,
   and whether the six-parameter F is nonsingular from the five channels (plus which channel
   carries what, by leaving each out).
3. A maneuver designed to minimise the Cramér–Rao bound of C_kappa_r within the limits, and
   the bounds before and after.
4. An identification check: Levenberg–Marquardt (flat-prior MAP) fits to noisy simulated data
   from both maneuvers over several noise seeds; the empirical std of the estimates against
   the bound.
5. Hook for the SBI posterior: if experiments/results/table2.json exists (written by
   experiments/paper_table2.py), its posterior std per parameter is put beside the bound.

Writes experiments/results/observability.md and .json (suffix _quick for --quick), updating
them after every stage so a long run leaves partial results.
"""

from __future__ import annotations

import argparse
import json
import math
import time
from pathlib import Path

import jax
import numpy as np

jax.config.update("jax_enable_x64", True)

import jax.numpy as jnp  # noqa: E402

from vdsbi.diagnostics import (  # noqa: E402
    Limits,
    Maneuver,
    check_limits,
    design_maneuver,
    design_problem,
    fisher_report,
    model_fisher,
    report_markdown,
    score_fisher_mc,
)
from vdsbi.diagnostics._fisher import scaled_mean_fn  # noqa: E402
from vdsbi.estimation import laplace_covariance, levenberg_marquardt  # noqa: E402
from vdsbi.simulator import (  # noqa: E402
    CHANNELS,
    PARAM_NAMES,
    SEED_CHANNELS,
    SEED_TRUE_THETA,
    SeedManeuver,
    default_vehicle,
    make_model,
    seed_profile,
)
from vdsbi.simulator.solvers import Solver  # noqa: E402

RESULTS = Path(__file__).resolve().parent / "results"
ROOT = Path(__file__).resolve().parents[1]
V0 = 10.5
#: The seed paper's Table II posterior std, physical units (stiffness deviations × 1e5).
SEED_PAPER_STD = {
    "l_f": 0.03,
    "h_cog": 0.122,
    "C_kappa_f": 0.077e5,
    "C_kappa_r": 0.116e5,
    "C_alpha_f": 0.043e5,
    "C_alpha_r": 0.041e5,
}


def whitened_error(est, ref):
    w, v = np.linalg.eigh(ref)
    isq = v @ np.diag(w**-0.5) @ v.T
    return float(np.linalg.norm(isq @ est @ isq - np.eye(len(ref))))


def direction_std(cov_z, c):
    """Std of cᵀz for the scaled covariance."""
    c = np.asarray(c, dtype=float)
    return float(np.sqrt(c @ cov_z @ c))


def identification(key, model, inputs, v0, fisher, num_seeds, num_iters=12):
    """LM fits to x = μ(θ*) + σ·ε over `num_seeds` noise draws, started at Table I nominal."""
    idx = jnp.asarray([CHANNELS.index(c) for c in fisher.channels])
    mean = scaled_mean_fn(model, fisher.scale, inputs, jnp.asarray(v0), idx, Solver())
    mu = fisher.readings
    eps = jax.random.normal(key, (num_seeds, *mu.shape))
    xs = mu + fisher.std * eps
    z0 = jnp.ones(6)  # Table I nominal in scaled units (the truth is 0.87–1.45 of it)

    def one(x):
        fn = lambda z: ((mean(z) - x) / fisher.std).reshape(-1)
        sol = levenberg_marquardt(fn, z0, max_steps=num_iters, rtol=0.0)
        return sol.z, sol.cost, laplace_covariance(sol.jacobian)

    z, cost, cov_z = (np.asarray(a) for a in jax.jit(jax.vmap(one))(xs))
    theta = z * np.asarray(fisher.scale)
    # A fit that ended far from the data (cost ≫ its expectation T·C/2) is a failed fit.
    n_data = mu.size
    good = cost < 0.5 * n_data * 1.5
    laplace = np.sqrt(np.einsum("kpp->kp", cov_z)) * np.asarray(fisher.scale)
    return {
        "num_seeds": num_seeds,
        "num_converged": int(good.sum()),
        "start": "Table I nominal",
        "estimates_mean": dict(zip(PARAM_NAMES, theta[good].mean(0).tolist())),
        "estimates_std": dict(zip(PARAM_NAMES, theta[good].std(0, ddof=1).tolist())),
        "laplace_std_mean": dict(zip(PARAM_NAMES, laplace[good].mean(0).tolist())),
        "cost_over_half_n": (cost / (0.5 * n_data)).tolist(),
    }


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--quick", action="store_true", help="tiny budget (a smoke test, not a result)")
    ap.add_argument("--steps", type=int, default=None, help="design steps (default 150; quick 3)")
    ap.add_argument("--seeds", type=int, default=None, help="noise seeds per maneuver (default 30; quick 3)")
    ap.add_argument("--learning-rate", type=float, default=0.05)
    args = ap.parse_args()
    steps = args.steps if args.steps is not None else (3 if args.quick else 150)
    seeds = args.seeds if args.seeds is not None else (3 if args.quick else 30)
    mc_sizes = (100, 1000) if args.quick else (100, 1000, 10000, 100000)
    duration = 1.0 if args.quick else 5.0
    suffix = "_quick" if args.quick else ""
    RESULTS.mkdir(parents=True, exist_ok=True)
    out_json = RESULTS / f"observability{suffix}.json"
    out_md = RESULTS / f"observability{suffix}.md"
    out: dict = {
        "setup": {
            "vehicle": "default_vehicle()",
            "maneuver": f"seed_profile(duration={duration})",
            "theta": SEED_TRUE_THETA,
            "v0": V0,
            "noise": "seed (relative 10 % acc., 5 % rot.; floored at 0.1 × rel × channel RMS)",
            "channels": list(SEED_CHANNELS),
            "quick": args.quick,
            "design_steps": steps,
            "noise_seeds": seeds,
        }
    }
    md: list[str] = []

    def save():
        out_json.write_text(json.dumps(out, indent=2, allow_nan=True) + "\n")
        out_md.write_text("\n".join(md) + "\n")

    key = jax.random.key(0)
    vehicle = default_vehicle()
    model = make_model(vehicle)
    theta = jnp.asarray([SEED_TRUE_THETA[n] for n in PARAM_NAMES])
    inputs = (
        seed_profile(duration=duration)
        if not args.quick
        else seed_profile(duration=1.0, maneuver=SeedManeuver(torque_period=1.0))
    )

    # ------------------------------------------------------------------ 1. F and the MC estimator
    t = time.perf_counter()
    fisher = model_fisher(model, theta, inputs, V0)
    jax.block_until_ready(fisher.fim_scaled)
    t_fisher = time.perf_counter() - t
    t = time.perf_counter()
    fisher = model_fisher(model, theta, inputs, V0)
    jax.block_until_ready(fisher.fim_scaled)
    t_fisher_warm = time.perf_counter() - t
    rep = fisher_report(fisher)
    out["seed_maneuver"] = rep
    out["timing_s"] = {"autodiff_fisher_first_call": t_fisher, "autodiff_fisher_warm": t_fisher_warm}
    ref = np.asarray(fisher.fim_scaled)
    mc = []
    for n in mc_sizes:
        key, k = jax.random.split(key)
        t = time.perf_counter()
        est = np.asarray(score_fisher_mc(k, fisher.jac, fisher.std, n))
        dt = time.perf_counter() - t
        crb_mc = np.sqrt(np.diag(np.linalg.inv(est))) * np.asarray(fisher.scale)
        mc.append(
            {
                "num_samples": n,
                "whitened_error": whitened_error(est, ref),
                "expected_whitened_error": math.sqrt(42 / n),
                "crb_std_ratio_mc_over_autodiff": dict(
                    zip(PARAM_NAMES, (crb_mc / np.array([rep["crb_std"][p] for p in PARAM_NAMES])).tolist())
                ),
                "seconds": dt,
            }
        )
    out["mc_score_estimator"] = mc
    md += [
        "# Observability of the seed's identification problem (autodiff Fisher information)",
        "",
        f"Setup: default_vehicle(), {out['setup']['maneuver']}, θ = Table II truth, v0 = {V0} m/s, "
        f"seed relative noise (floored at 0.1 × rel × channel RMS), channels {', '.join(SEED_CHANNELS)}."
        + (" **QUICK RUN: 1 s maneuver, tiny budgets — not a result.**" if args.quick else ""),
        "",
        f"Autodiff F (jacfwd, float64): {t_fisher:.1f} s first call (compile), {t_fisher_warm:.2f} s warm.",
        "",
        report_markdown(rep, title="Seed maneuver").replace("# Seed maneuver", "## 1. Seed maneuver"),
        "### The seed's estimator: covariance of simulated Gaussian scores",
        "",
        "Error ‖F⁻½ F̂ F⁻½ − I‖_F against the autodiff F (expected √(P(P+1)/n) = √(42/n) for an "
        "unbiased estimator).",
        "",
        "| samples | error | expected | C_kappa_r CRB ratio (MC/autodiff) | seconds |",
        "|---|---|---|---|---|",
    ]
    for m in mc:
        md.append(
            f"| {m['num_samples']} | {m['whitened_error']:.3f} | {m['expected_whitened_error']:.3f} | "
            f"{m['crb_std_ratio_mc_over_autodiff']['C_kappa_r']:.3f} | {m['seconds']:.2f} |"
        )
    save()
    print("\n".join(md), flush=True)

    # ------------------------------------------------------------------ 2. the seed's claims
    cov_z = np.linalg.inv(ref)
    i_f, i_r = PARAM_NAMES.index("C_kappa_f"), PARAM_NAMES.index("C_kappa_r")
    c_sum, c_diff = np.zeros(6), np.zeros(6)
    c_sum[[i_f, i_r]] = 0.5
    c_diff[i_f], c_diff[i_r] = 1.0, -1.0
    # Only the two longitudinal stiffnesses unknown (others known): their 2×2 information.
    sub = ref[np.ix_([i_f, i_r], [i_f, i_r])]
    sub_cov = np.linalg.inv(sub)
    per_channel = {}
    w = fisher.jac / fisher.std[..., None]
    for ci, ch in enumerate(fisher.channels):
        keep = [j for j in range(len(fisher.channels)) if j != ci]
        f_wo = np.asarray(jnp.einsum("tcp,tcq->pq", w[:, keep], w[:, keep]))
        f_only = np.asarray(jnp.einsum("tp,tq->pq", w[:, ci], w[:, ci]))
        ev_wo = np.linalg.eigvalsh(f_wo)
        ev_only = np.linalg.eigvalsh(f_only)
        cov_wo = np.linalg.pinv(f_wo, hermitian=True)
        per_channel[ch] = {
            "without": {
                "rank": int(np.sum(ev_wo > 1e-9 * ev_wo[-1])),
                "min_eigenvalue": float(ev_wo[0]),
                "crb_relative": dict(
                    zip(
                        PARAM_NAMES,
                        (
                            np.sqrt(np.clip(np.diag(cov_wo), 0, None))
                            * np.asarray(fisher.scale)
                            / np.asarray(theta)
                        ).tolist(),
                    )
                ),
            },
            "alone": {"rank": int(np.sum(ev_only > 1e-9 * ev_only[-1]))},
        }
    rel = rep["crb_relative"]
    claims = {
        "rear_vs_front_longitudinal": {
            "crb_relative_C_kappa_f": rel["C_kappa_f"],
            "crb_relative_C_kappa_r": rel["C_kappa_r"],
            "ratio_rear_over_front": rel["C_kappa_r"] / rel["C_kappa_f"],
            "correlation_f_r": rep["correlation"][i_f][i_r],
            "std_scaled_mean_(f+r)/2": direction_std(cov_z, c_sum),
            "std_scaled_difference_f-r": direction_std(cov_z, c_diff),
            "only_these_two_unknown": {
                "crb_relative_f": float(math.sqrt(sub_cov[0, 0]) * fisher.scale[i_f] / theta[i_f]),
                "crb_relative_r": float(math.sqrt(sub_cov[1, 1]) * fisher.scale[i_r] / theta[i_r]),
                "correlation": float(sub_cov[0, 1] / math.sqrt(sub_cov[0, 0] * sub_cov[1, 1])),
            },
        },
        "six_parameter_nonsingular": {
            "rank": rep["rank"],
            "min_eigenvalue_scaled": rep["eigenvalues"][0],
            "condition_number": rep["condition_number"],
            "weakest_direction": rep["weakest_direction"],
        },
        "leave_one_channel_out": per_channel,
    }
    out["claims"] = claims
    rf = claims["rear_vs_front_longitudinal"]
    md += [
        "",
        "## 2. The seed's claims, with numbers",
        "",
        "**Rear vs front longitudinal stiffness on a front-driven car.** "
        f"CRB std: C_kappa_f {rf['crb_relative_C_kappa_f']:.2%}, C_kappa_r {rf['crb_relative_C_kappa_r']:.2%} "
        f"of their values: the rear bound is {rf['ratio_rear_over_front']:.1f}× the front one. Their correlation "
        f"is {rf['correlation_f_r']:+.2f}; std of the mean (f+r)/2 is {rf['std_scaled_mean_(f+r)/2']:.3%} and of the "
        f"difference f−r {rf['std_scaled_difference_f-r']:.3%} of nominal. With the other four parameters known: "
        f"C_kappa_f {rf['only_these_two_unknown']['crb_relative_f']:.2%}, C_kappa_r "
        f"{rf['only_these_two_unknown']['crb_relative_r']:.2%}, correlation "
        f"{rf['only_these_two_unknown']['correlation']:+.2f}.",
        "",
        f"**Six parameters from (ax, ay, yaw_rate, ω_f, ω_r).** Rank {rep['rank']['value']}/6 "
        f"(rtol {rep['rank']['rtol']:g}); smallest eigenvalue of the scaled F {rep['eigenvalues'][0]:.4g} "
        f"(weakest direction's CRB std {rep['weakest_direction_crb_std_scaled']:.1%} of nominal), condition "
        f"number {rep['condition_number']:.3g}. Weakest direction: "
        + ", ".join(f"{n} {v:+.2f}" for n, v in rep["weakest_direction"].items() if abs(v) > 0.05)
        + ".",
        "",
        "Leaving one channel out (rank of the remaining F, CRB std / value of C_kappa_r and h_cog):",
        "",
        "| channel left out | rank | C_kappa_r | h_cog | C_kappa_f | rank from this channel alone |",
        "|---|---|---|---|---|---|",
    ]
    for ch, d in per_channel.items():
        cr = d["without"]["crb_relative"]
        md.append(
            f"| {ch} | {d['without']['rank']} | {cr['C_kappa_r']:.2%} | {cr['h_cog']:.2%} | "
            f"{cr['C_kappa_f']:.2%} | {d['alone']['rank']} |"
        )
    save()
    print("\n".join(md[-(len(per_channel) + 9) :]), flush=True)

    # ------------------------------------------------------------------ 3. design
    limits = Limits(duration=duration)
    problem = design_problem(model, theta, limits, target="C_kappa_r")
    start = Maneuver.seed_like(limits)
    t0 = time.perf_counter()

    def progress(i, obj):
        if i % 10 == 0 or i == steps:
            print(
                f"  design step {i:4d}  info {float(obj.information):8.4f}  penalty {float(obj.penalty):.2e}  "
                f"[{time.perf_counter() - t0:.0f} s]",
                flush=True,
            )

    res = design_maneuver(
        problem, start, num_steps=steps, learning_rate=args.learning_rate, callback=progress
    )
    t_design = time.perf_counter() - t0
    d_inputs = res.maneuver.inputs(limits)
    d_v0 = float(res.maneuver.initial_speed(limits))
    d_fisher = model_fisher(model, theta, d_inputs, d_v0)
    d_rep = fisher_report(d_fisher)
    s_fisher = model_fisher(model, theta, start.inputs(limits), float(start.initial_speed(limits)))
    s_rep = fisher_report(s_fisher)
    chk = check_limits(model, theta, d_inputs, d_v0, limits)
    improvement = {n: rep["crb_std"][n] / d_rep["crb_std"][n] for n in PARAM_NAMES}
    out["design"] = {
        "target": "C_kappa_r",
        "limits": {k: getattr(limits, k) for k in limits.__dataclass_fields__},
        "steps": steps,
        "best_step": res.best_step,
        "seconds": t_design,
        "maneuver": res.maneuver.describe(limits),
        "history_information": res.history["information"].tolist(),
        "report": d_rep,
        "start_report": s_rep,
        "improvement_seed_over_designed": improvement,
        "limits_check": chk,
        "goal_2x_on_C_kappa_r_met": bool(improvement["C_kappa_r"] >= 2.0 and chk["respected"]),
    }
    md += [
        "",
        "## 3. Designed maneuver (minimise the C_kappa_r bound)",
        "",
        f"Adam, {steps} steps ({t_design:.0f} s), best feasible iterate at step {res.best_step}; "
        f"v0 = {d_v0:.2f} m/s. Limits respected (checked with the default 2.5 ms solver): "
        f"{chk['respected']} — max |ay| {chk['max_abs_ay']:.2f} of {chk['ay_limit']:.2f} m/s², vx "
        f"{chk['vx_range'][0]:.2f}..{chk['vx_range'][1]:.2f} in [{limits.v_min:g}, {limits.v_max:g}] m/s, |steer| "
        f"{chk['max_abs_steer']:.3f} ≤ {limits.max_steer:g} rad, drive {chk['max_drive_torque']:.0f} ≤ "
        f"{limits.max_drive:g} N·m, brake {chk['max_brake_torque']:.0f} ≤ {limits.max_brake:g} N·m "
        f"(front share {limits.brake_front_share:g}).",
        "",
        "| parameter | CRB std, seed maneuver | optimiser start | designed | improvement |",
        "|---|---|---|---|---|",
    ]
    for n in PARAM_NAMES:
        md.append(
            f"| {n} | {rep['crb_std'][n]:.4g} | {s_rep['crb_std'][n]:.4g} | {d_rep['crb_std'][n]:.4g} | "
            f"{improvement[n]:.2f}× |"
        )
    goal = improvement["C_kappa_r"]
    # Which limits the design runs into (within 3 % of the bound at some sample).
    active = []
    if chk["max_abs_ay"] >= 0.97 * chk["ay_limit"]:
        active.append("|ay| ≤ 0.6·μ·g")
    if chk["vx_range"][1] >= 0.97 * limits.v_max:
        active.append(f"vx ≤ {limits.v_max:g} m/s")
    if chk["vx_range"][0] <= 1.03 * limits.v_min:
        active.append(f"vx ≥ {limits.v_min:g} m/s")
    if chk["max_abs_steer"] >= 0.97 * limits.max_steer:
        active.append("|steer| limit")
    if chk["max_drive_torque"] >= 0.97 * limits.max_drive:
        active.append(f"drive torque ≤ {limits.max_drive:g} N·m")
    if chk["max_brake_torque"] >= 0.97 * limits.max_brake:
        active.append(
            f"brake torque ≤ {limits.max_brake:g} N·m (rear gets {1 - limits.brake_front_share:.0%}: "
            f"≤ {(1 - limits.brake_front_share) * limits.max_brake:.0f} N·m)"
        )
    out["design"]["active_limits"] = active
    md += [
        "",
        "Limits the design runs into (within 3 % of the bound): " + (", ".join(active) or "none") + ".",
        "",
        f"Goal (C_kappa_r bound improved ≥ 2× within the limits): **{'met' if out['design']['goal_2x_on_C_kappa_r_met'] else 'NOT met'}** "
        f"({goal:.2f}×).",
    ]
    save()
    print("\n".join(md[-(len(PARAM_NAMES) + 8) :]), flush=True)

    # ------------------------------------------------------------------ 4. identification check
    key, k1, k2 = jax.random.split(key, 3)
    ident = {}
    for name, (inp, v0, fis, r, k) in {
        "seed": (inputs, V0, fisher, rep, k1),
        "designed": (d_inputs, d_v0, d_fisher, d_rep, k2),
    }.items():
        t = time.perf_counter()
        res_id = identification(k, model, inp, v0, fis, seeds)
        res_id["seconds"] = time.perf_counter() - t
        res_id["ratio_empirical_std_over_crb"] = {
            n: res_id["estimates_std"][n] / r["crb_std"][n] for n in PARAM_NAMES
        }
        ident[name] = res_id
        out["identification"] = ident
        save()
        print(
            f"  identification on {name}: {res_id['num_converged']}/{seeds} converged, {res_id['seconds']:.0f} s",
            flush=True,
        )
    pred = rep["crb_std"]["C_kappa_r"] / d_rep["crb_std"]["C_kappa_r"]
    meas = ident["seed"]["estimates_std"]["C_kappa_r"] / ident["designed"]["estimates_std"]["C_kappa_r"]
    out["identification"]["C_kappa_r_shrink"] = {"predicted_by_crb": pred, "measured_by_fits": meas}
    md += [
        "",
        "## 4. Identification check (Levenberg–Marquardt MAP, flat prior)",
        "",
        f"{seeds} noise draws per maneuver from the same Gaussian noise model (σ as in F), fits started at Table I "
        "nominal, 12 LM iterations. Empirical std of the estimates over the draws vs the CRB "
        "(a ratio ≈ 1 means the bound is attained; with n draws the empirical std itself is uncertain by "
        f"≈ 1/√(2(n−1)) = {1 / math.sqrt(2 * max(seeds - 1, 1)):.0%}).",
        "",
        "| parameter | seed: CRB | seed: empirical std | ratio | designed: CRB | designed: empirical std | ratio |",
        "|---|---|---|---|---|---|---|",
    ]
    for n in PARAM_NAMES:
        a, b = ident["seed"], ident["designed"]
        md.append(
            f"| {n} | {rep['crb_std'][n]:.4g} | {a['estimates_std'][n]:.4g} | {a['ratio_empirical_std_over_crb'][n]:.2f} | "
            f"{d_rep['crb_std'][n]:.4g} | {b['estimates_std'][n]:.4g} | {b['ratio_empirical_std_over_crb'][n]:.2f} |"
        )
    md += [
        "",
        f"Converged fits: seed {ident['seed']['num_converged']}/{seeds}, designed {ident['designed']['num_converged']}/{seeds}. "
        f"C_kappa_r std shrinks by {meas:.2f}× in the fits (predicted by the bounds: {pred:.2f}×).",
    ]
    save()

    # ------------------------------------------------------------------ 5. SBI posterior (Table II)
    # HOOK: the SBI posterior std from experiments/paper_table2.py. Its setup adds the seed's
    # process noise (stiffness mixture) and a random v0 ∈ [10, 11] m/s to the sensor noise, and a
    # bounded prior, so the bound here (sensor noise only, known v0) is a lower bound for it.
    table2 = RESULTS / "table2.json"
    md += ["", "## 5. SBI posterior std beside the bound (Table II)", ""]
    rows = []
    if table2.exists() and not args.quick:
        t2 = json.loads(table2.read_text())["params"]
        out["table2"] = {
            n: {
                "posterior_std": t2[n]["std"],
                "crb_std": rep["crb_std"][n],
                "ratio": t2[n]["std"] / rep["crb_std"][n],
                "within_1.5x": bool(t2[n]["std"] <= 1.5 * rep["crb_std"][n]),
            }
            for n in PARAM_NAMES
            if n in t2
        }
        md.append(f"From {table2.relative_to(ROOT)} (SNPE-C posterior on the seed maneuver):")
        rows = [(n, out["table2"][n]["posterior_std"]) for n in out["table2"]]
    else:
        why = (
            "quick run"
            if args.quick
            else f"{table2.relative_to(ROOT)} does not exist yet (run experiments/paper_table2.py)"
        )
        out["table2"] = {"missing": why}
        md.append(f"No SBI posterior: {why}. Nothing is filled in.")
    md += [
        "",
        "| parameter | CRB std | SBI posterior std | ratio | seed paper's posterior std | ratio |",
        "|---|---|---|---|---|---|",
    ]
    sbi = dict(rows)
    for n in PARAM_NAMES:
        b = rep["crb_std"][n]
        s = sbi.get(n)
        p = SEED_PAPER_STD[n]
        md.append(
            f"| {n} | {b:.4g} | {'—' if s is None else f'{s:.4g}'} | {'—' if s is None else f'{s / b:.2f}'} | "
            f"{p:.4g} | {p / b:.2f} |"
        )
    md += [
        "",
        "Goal: SBI posterior std within 1.5× the bound. The seed paper's own Table II std is shown for "
        "reference (its setup also has process noise and random v0, and its vehicle constants are unknown).",
    ]
    out["seed_paper_posterior_std"] = SEED_PAPER_STD
    save()
    print("\n".join(md[-(len(PARAM_NAMES) + 8) :]), flush=True)
    print(f"wrote {out_md} and {out_json}")


if __name__ == "__main__":
    main()
