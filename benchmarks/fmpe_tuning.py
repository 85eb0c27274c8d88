"""Tune FMPE on held-out simulations (never on the reference posteriors of the scored observations).

Usage:
    python benchmarks/fmpe_tuning.py --task two_moons --budget 10000 --variant base
    python benchmarks/fmpe_tuning.py --task slcp --budget 10000 --variant wide \\
        --over '{"fmpe_hidden": 256}'
    python benchmarks/fmpe_tuning.py --task two_moons --budget 10000 --variant nsf --over '{"estimator": "nsf"}'
    python benchmarks/fmpe_tuning.py --quick     # two_moons at 10³, a few epochs

Trains on ``budget`` prior simulations (``--sim-seed``) with ``sbi_tasks.config_for(budget,
estimator="fmpe", **over)`` and scores ``-mean log q(θ | x)`` on ``--test`` FRESH prior
simulations (another seed): the expected KL to the true posterior up to a constant, so variants
(and the spline flow) compare on one scale whatever their training loss. The flow-matching
validation loss is not comparable across ``fmpe_time_power``, which reweights it. Appends one
JSON line per variant to ``benchmarks/results/fmpe_tuning.jsonl``.
"""

import argparse
import copy
import json
import os
import sys
import time

import jax
import jax.numpy as jnp
import numpy as np

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
import _sbibm  # noqa: E402
from sbi_tasks import config_for  # noqa: E402

from vdsbi.inference import IdentityEmbedding, Posterior, npe  # noqa: E402
from vdsbi.tasks import get_task  # noqa: E402

OUT = os.path.join(os.path.dirname(os.path.abspath(__file__)), "results", "fmpe_tuning.jsonl")


def simulations(task, n, seed):
    k_theta, k_sim = jax.random.split(jax.random.key(seed))
    theta = task.prior.sample(k_theta, n)
    x, valid = task.simulate(k_sim, theta)
    keep = np.asarray(valid, bool) & np.all(np.isfinite(np.asarray(x)), axis=1)
    return np.asarray(theta)[keep], np.asarray(x)[keep]


@jax.jit
def _nll(flow, theta, x):
    return -jax.vmap(flow.log_prob)(theta, x)


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--task", default="two_moons")
    ap.add_argument("--budget", type=int, default=10_000)
    ap.add_argument("--variant", default="base")
    ap.add_argument("--over", default="{}", help="NPEConfig fields (JSON) over the benchmark config")
    ap.add_argument("--seed", type=int, default=0, help="training seed")
    ap.add_argument("--sim-seed", type=int, default=0)
    ap.add_argument("--test", type=int, default=2000, help="fresh simulations scored")
    ap.add_argument(
        "--eval-steps", nargs="*", type=int, default=[], help="also score with these ODE step counts"
    )
    ap.add_argument(
        "--step-c2st", action="store_true", help="C2ST of --eval-steps samples against the finest's"
    )
    ap.add_argument("--quick", action="store_true")
    ap.add_argument("--out", default=OUT)
    args = ap.parse_args()
    over = {"estimator": "fmpe", **json.loads(args.over)}
    if args.quick:
        args.budget, args.test, over["max_epochs"] = 1000, 200, 3
    task = get_task(args.task)
    theta, x = simulations(task, args.budget, args.sim_seed)
    theta_t, x_t = simulations(task, args.test, 10_000 + args.sim_seed)
    cfg = config_for(args.budget, **over)
    t0 = time.perf_counter()
    flow, info = npe(
        jax.random.key(args.seed), task.prior, theta, x, embedding=IdentityEmbedding(task.dim_x), config=cfg
    )
    jax.block_until_ready(flow)
    train_s = time.perf_counter() - t0
    nll = np.asarray(_nll(flow, jnp.asarray(theta_t), jnp.asarray(x_t)))
    by_steps, c2st_by_steps = {}, {}
    finest = None
    for steps in sorted(args.eval_steps, reverse=True):  # the same network, other ODE steps
        other = copy.copy(flow)
        object.__setattr__(other, "ode_steps", steps)
        by_steps[steps] = float(np.mean(np.asarray(_nll(other, jnp.asarray(theta_t), jnp.asarray(x_t)))))
        if args.step_c2st:  # samples at a fresh simulated x against the finest step count's
            s = np.asarray(Posterior(other).sample(jax.random.key(2 + steps), 10_000, x=x_t[0]))
            if finest is None:
                finest = s
            else:
                c2st_by_steps[steps] = _sbibm.c2st(finest, s)
    post = Posterior(flow)
    t0 = time.perf_counter()
    jax.block_until_ready(post.sample(jax.random.key(1), 10_000, x=x_t[0]))
    row = {
        "task": args.task,
        "budget": args.budget,
        "variant": args.variant,
        "over": over,
        "seed": args.seed,
        "test_nll": float(np.mean(nll)),
        "test_nll_se": float(np.std(nll) / np.sqrt(nll.size)),
        "test_nll_by_ode_steps": by_steps,
        "c2st_vs_finest_by_ode_steps": c2st_by_steps,
        "train_s": train_s,
        "sample_10k_s": time.perf_counter() - t0,
        "epochs": info["epochs"],
        "best_epoch": info["best_epoch"],
        "best_val_loss": info["best_val_loss"],
        "load": os.getloadavg()[0],
    }
    print(json.dumps(row), flush=True)
    if not args.quick:
        with open(args.out, "a") as f:
            f.write(json.dumps(row) + "\n")


if __name__ == "__main__":
    main()
