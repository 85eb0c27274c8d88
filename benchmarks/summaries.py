"""Handcrafted statistics vs the 1D-CNN embedding, and SBC calibration of the amortized posterior.

    python benchmarks/summaries.py [--quick] [--sims N] [--test N] [--lr-schedule cosine] ...

Both estimators are amortized (one NPE round on prior simulations, the same simulations for
both), then evaluated on held-out (θ, x) pairs from the prior: per parameter the RMSE of the
posterior mean, the mean posterior std, the 90 % coverage; SBC ranks with KS p-values and
expected coverage at 50/80/95 %. Training uses the vehicle's `IdentifySettings` config (the one
Table II uses) unless options override it. Writes benchmarks/results/summaries.json (each
embedding's SBC KS p-values and coverage under its ``calibration``) and summaries.md.
"""

from __future__ import annotations

import argparse
import json
import os
import time
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np
from _config import flat_config, make_config

from vdsbi.diagnostics import expected_coverage, sbc_ks_pvalues, sbc_ranks
from vdsbi.inference import OBSERVATIONS, IdentifySettings, identify
from vdsbi.inference._vehicle import seed_prior
from vdsbi.simulator import PARAM_NAMES, SEED_CHANNELS, default_vehicle, make_model, seed_profile
from vdsbi.simulator.measurement import SensorNoise, StiffnessMixtureNoise, StochasticSimulator

ROOT = Path(__file__).resolve().parent.parent
LEVELS = (0.5, 0.8, 0.9, 0.95)


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--quick", action="store_true")
    ap.add_argument("--sims", type=int, default=None)
    ap.add_argument("--test", type=int, default=None, help="held-out simulations (default 500)")
    ap.add_argument("--posterior-samples", type=int, default=500)
    ap.add_argument("--embeddings", default="stats,cnn")
    # training overrides; None keeps IdentifySettings' config
    ap.add_argument("--max-epochs", type=int, default=None)
    ap.add_argument("--patience", type=int, default=None)
    ap.add_argument("--lr-schedule", choices=("constant", "cosine"), default=None)
    ap.add_argument("--theta-map", choices=("logit", "affine"), default=None)
    ap.add_argument("--tail-bound", type=float, default=None, help="spline interval [-B, B] of the flow")
    ap.add_argument("--tag", default="", help="suffix for the output files")
    args = ap.parse_args(argv)
    n_sims = args.sims or (400 if args.quick else 5000)
    n_test = args.test or (20 if args.quick else 500)
    n_post = 100 if args.quick else args.posterior_samples
    out_b = ROOT / "benchmarks" / "results"
    out_b.mkdir(parents=True, exist_ok=True)

    vehicle, inputs = default_vehicle(), seed_profile()
    key = jax.random.key(7)
    k_mix, k_train, k_test, k_th, k_rest = jax.random.split(key, 5)
    simulator = StochasticSimulator(
        make_model(vehicle),
        inputs,
        SEED_CHANNELS,
        (10.0, 11.0),
        SensorNoise.seed(),
        StiffnessMixtureNoise(k_mix),
    )
    prior = seed_prior()
    theta_test = prior.sample(k_th, n_test)
    t0 = time.perf_counter()
    ys_test, ok_test = simulator(k_test, theta_test)
    sim_test_s = time.perf_counter() - t0
    ok_test = np.asarray(ok_test)
    u = jnp.stack([inputs.steer, inputs.torque_front, inputs.torque_rear], -1).astype(jnp.float32)
    overrides = {
        "max_epochs": 10 if args.quick else args.max_epochs,
        "patience": args.patience,
        "lr_schedule": args.lr_schedule,
        "theta_map": args.theta_map,
        "tail_bound": args.tail_bound,
    }
    overrides = {k: v for k, v in overrides.items() if v is not None}
    configs = {  # each embedding's IdentifySettings default, with the overrides
        emb: make_config(**{**flat_config(IdentifySettings(embedding=OBSERVATIONS[emb]).config), **overrides})
        for emb in args.embeddings.split(",")
    }
    results = {
        "settings": {
            "sims": n_sims,
            "test": n_test,
            "posterior_samples": n_post,
            "rounds": 1,
            "config": {emb: flat_config(c) for emb, c in configs.items()},
        },
        "load_average_at_start": os.getloadavg()[0],
        "embeddings": {},
    }
    md = [f"# Summaries vs CNN ({n_sims} prior simulations, {int(ok_test.sum())} held-out sets)", ""]
    for emb in args.embeddings.split(","):
        settings = IdentifySettings(
            rounds=1,
            sims_per_round=n_sims,
            embedding=OBSERVATIONS[emb],
            num_samples=n_post,
            config=configs[emb],
        )
        t0 = time.perf_counter()
        posterior, _, state = identify(k_train, simulator, prior, ys_test[0], settings)
        train_s = time.perf_counter() - t0
        # The held-out sets as the estimator sees them (what `identify` does to its observation).
        x_test = np.asarray(jax.vmap(lambda r: OBSERVATIONS[emb](r, u))(ys_test))
        t0 = time.perf_counter()
        keys = jax.random.split(k_rest, n_test)
        sample_one = lambda k, x: posterior.sample(k, n_post, x=x)
        samples = np.stack([np.asarray(sample_one(keys[i], x_test[i])) for i in range(n_test)])
        sample_s = time.perf_counter() - t0
        truths = np.asarray(theta_test)[ok_test]
        samples = samples[ok_test]
        scale = np.where(np.array([n.startswith("C_") for n in PARAM_NAMES]), 1e5, 1.0)
        mean = samples.mean(1)
        rmse = np.sqrt(((mean - truths) ** 2).mean(0)) / scale
        std = samples.std(1).mean(0) / scale
        cov = expected_coverage(samples, truths, LEVELS)
        ranks = sbc_ranks(samples, truths)
        ks = sbc_ks_pvalues(ranks, n_post)
        results["embeddings"][emb] = {
            "rmse": dict(zip(PARAM_NAMES, rmse.tolist())),
            "mean_std": dict(zip(PARAM_NAMES, std.tolist())),
            "coverage_90": dict(zip(PARAM_NAMES, cov[LEVELS.index(0.9)].tolist())),
            "epochs": [h["epochs"] for h in state.history],
            "best_epoch": [h["best_epoch"] for h in state.history],
            "wall_s": {"training_incl_simulation": train_s, "sampling": sample_s},
            "units": "l_f, h_cog in m; stiffness in 1e5 N or N/rad",
            "calibration": {
                "ks_pvalues": dict(zip(PARAM_NAMES, ks.tolist())),
                "coverage": {str(lv): dict(zip(PARAM_NAMES, cov[i].tolist())) for i, lv in enumerate(LEVELS)},
                "num_test": int(ok_test.sum()),
                "num_posterior_samples": n_post,
            },
        }
        md += [
            f"## {emb}",
            "",
            "| | " + " | ".join(PARAM_NAMES) + " |",
            "|---" * 7 + "|",
            "| RMSE of mean | " + " | ".join(f"{v:.4f}" for v in rmse) + " |",
            "| mean post. std | " + " | ".join(f"{v:.4f}" for v in std) + " |",
            "| 90 % coverage | " + " | ".join(f"{v:.2f}" for v in cov[LEVELS.index(0.9)]) + " |",
            "| SBC KS p | " + " | ".join(f"{v:.3f}" for v in ks) + " |",
            *[
                f"| coverage @{int(lv * 100)} % | " + " | ".join(f"{v:.2f}" for v in cov[i]) + " |"
                for i, lv in enumerate(LEVELS)
            ],
            "",
            f"training (incl. simulation) {train_s:.0f} s, sampling {sample_s:.1f} s",
            "",
        ]
        print("\n".join(md[-12:]), flush=True)
    if {"stats", "cnn"} <= set(results["embeddings"]):
        r = results["embeddings"]
        wins = {n: r["cnn"]["rmse"][n] < r["stats"]["rmse"][n] for n in PARAM_NAMES}
        results["cnn_better_rmse"] = wins
        md += [
            "CNN lower RMSE than statistics: "
            + ", ".join(f"{n}: {'yes' if w else 'no'}" for n, w in wins.items())
        ]
    results["simulation_test_s"] = sim_test_s
    suffix = ("_quick" if args.quick else "") + args.tag
    (out_b / f"summaries{suffix}.json").write_text(json.dumps(results, indent=2))
    (out_b / f"summaries{suffix}.md").write_text("\n".join(md) + "\n")
    print("\n".join(md))
    return results


if __name__ == "__main__":
    main()
