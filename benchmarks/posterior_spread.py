"""How a sequential posterior misses on an sbibm task: spread, shift and its region's coverage.

Usage:
    python benchmarks/posterior_spread.py --task gaussian_linear_uniform --method tsnpe \
        --budget 10000 --obs 3 [--set truncation_widen=1.5]

Runs one cell of `sbi_tasks.py` at one sbibm observation (same seeds and settings) and compares
the posterior's draws with sbibm's reference draws: per-parameter standard deviation ratio
(posterior / reference; below 1 is overconfident), mean shift in reference standard
deviations, and the share of reference draws outside the flow's 1 - 10⁻⁴ HPD region (TSNPE's
truncation level; it should be ~10⁻⁴), with each round's proposal and acceptance and the C2ST.
Prints them and writes ``benchmarks/results/posterior_spread/<task>_<method>_<budget>_obs<i>.json``.
"""

import argparse
import json
import os
import sys

import jax
import jax.numpy as jnp
import numpy as np

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
import _sbibm  # noqa: E402
from sbi_tasks import HERE, _parse_overrides, _provenance, config_for, train_posterior  # noqa: E402

from vdsbi.inference._posterior import _log_prob  # noqa: E402
from vdsbi.tasks import get_task  # noqa: E402


def spread(task_name, method, budget, i, overrides, seed=0, num=10_000):
    """The comparison for one observation (keys as `sbi_tasks.run_cell`, so the same runs)."""
    task = get_task(task_name)
    cfg = config_for(budget, method, **overrides)
    key = jax.random.fold_in(jax.random.key(seed), budget)
    x_o = _sbibm.observation(task_name, i)
    ref = np.asarray(_sbibm.reference_posterior_samples(task_name, i)[:num], np.float32)
    post, state = train_posterior(task, method, budget, cfg, key, x_o, i)
    draws = np.asarray(post.sample(jax.random.fold_in(key, 1000 + i), num, x=x_o))
    lp_draws = np.asarray(_log_prob(post.flow, jnp.asarray(draws), x_o))
    lp_ref = np.asarray(_log_prob(post.flow, jnp.asarray(ref), x_o))
    return {
        "task": task_name,
        "method": method,
        "budget": budget,
        "obs_id": i,
        "overrides": overrides,
        "std_ratio": (draws.std(0) / ref.std(0)).tolist(),
        "mean_shift_sd": ((draws.mean(0) - ref.mean(0)) / ref.std(0)).tolist(),
        "ref_outside_region": float(np.mean(lp_ref < np.quantile(lp_draws, 1e-4))),
        "rounds": [
            {k: h.get(k) for k in ("round", "epochs", "best_epoch", "region_proposal", "acceptance")}
            for h in state.history
        ],
        "c2st": float(_sbibm.c2st(ref, draws, n_jobs=2)),
        **_provenance(),
    }


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--task", default="gaussian_linear_uniform")
    ap.add_argument("--method", default="tsnpe", choices=["npe", "apt", "tsnpe"])
    ap.add_argument("--budget", type=int, default=10_000)
    ap.add_argument("--obs", type=int, default=3)
    ap.add_argument("--set", nargs="+", default=[], metavar="FIELD=VALUE")
    args = ap.parse_args()
    overrides = _parse_overrides(args.set)
    r = spread(args.task, args.method, args.budget, args.obs, overrides)
    fmt = " ".join
    print(f"{args.task} {args.method} {args.budget} obs {args.obs} {overrides or ''}")
    print("std ratio      ", fmt(f"{v:.2f}" for v in r["std_ratio"]))
    print("mean shift (sd)", fmt(f"{v:+.2f}" for v in r["mean_shift_sd"]))
    print(f"reference draws outside the 1 - 1e-4 region: {r['ref_outside_region']:.4f}")
    print("box/ellipsoid acceptance per round:", fmt(f"{h['acceptance'] or 1:.4f}" for h in r["rounds"]))
    print(f"C2ST {r['c2st']:.3f}")
    tag = "_".join(f"{k}{v}" for k, v in overrides.items())
    name = f"{args.task}_{args.method}_{args.budget}_obs{args.obs}{'_' + tag if tag else ''}.json"
    out = os.path.join(HERE, "results", "posterior_spread", name)
    os.makedirs(os.path.dirname(out), exist_ok=True)
    with open(out, "w") as f:
        json.dump(r, f, indent=1)


if __name__ == "__main__":
    main()
