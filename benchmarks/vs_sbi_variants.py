"""Seed-to-seed spread of ours (config variants) and sbi on ONE vs-sbi cell's simulations.

Usage (needs ``pip install -e '.[bench]'``):
    python benchmarks/vs_sbi_variants.py --variant base --seeds 0 1 2
    python benchmarks/vs_sbi_variants.py --variant affine --over '{"theta_map": "affine"}' --seeds 0 1 2
    python benchmarks/vs_sbi_variants.py --sbi --seeds 1 2
    python benchmarks/vs_sbi_variants.py --variant wide50 --wide 50 --seeds 0   # see --wide

The simulations are those of ``benchmarks/vs_sbi.py`` (``--sim-seed`` 0 = the same draws); the
training seed varies (seed 0 reproduces the vs_sbi cell). ``--over``: `NPEConfig` fields over
``sbi_tasks.config_for``. Each (variant, seed) appends one JSON line (C2ST at sbibm's
observations 1..n, training seconds including compilation, epochs, best epoch, best validation
loss, load average) to ``benchmarks/results/vs_sbi_variants.jsonl``; ``--summary`` prints the
per-variant means.
"""

import argparse
import collections
import json
import os
import sys
import time

import jax
import numpy as np

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
import _sbibm  # noqa: E402
import vs_sbi  # noqa: E402
from sbi_tasks import config_for  # noqa: E402

from vdsbi.inference import BoxPrior, IdentityEmbedding, Posterior, npe  # noqa: E402
from vdsbi.tasks import get_task  # noqa: E402

OUT = os.path.join(os.path.dirname(os.path.abspath(__file__)), "results", "vs_sbi_variants.jsonl")


def train_ours(task, theta, x, budget, seed, over, wide):
    """Ours; with ``wide`` > 0 trained on a box ``wide`` times wider (the logit is then nearly
    affine over the true box: a probe of the θ map without code changes), samples outside the
    true box rejected."""
    key = jax.random.key(seed)
    prior = task.prior
    if wide:
        c, h = 0.5 * (prior.low + prior.high), 0.5 * (prior.high - prior.low)
        prior = BoxPrior(c - wide * h, c + wide * h)
    t0 = time.perf_counter()
    flow, info = npe(
        key, prior, theta, x, embedding=IdentityEmbedding(task.dim_x), config=config_for(budget, **over)
    )
    jax.block_until_ready(flow)
    train_s = time.perf_counter() - t0
    lo, hi = np.asarray(task.prior.low), np.asarray(task.prior.high)

    def sample(x_o, n):
        s = np.asarray(Posterior(flow, x_o).sample(jax.random.fold_in(key, 7), 3 * n if wide else n))
        s = s[np.all((s >= lo) & (s <= hi), axis=1)]
        return s[:n]

    return sample, train_s, (info["epochs"], info["best_epoch"], info["best_val_loss"])


def summary(path):
    by = collections.defaultdict(list)
    for line in open(path):
        r = json.loads(line)
        by[(r["task"], r["budget"], r["variant"])].append(r)
    for (task, budget, variant), rs in by.items():
        m = np.array([r["c2st"] for r in rs])
        sd = np.std(m.mean(1), ddof=1) if len(rs) > 1 else 0.0
        print(
            f"{task} {budget:.0e} {variant:>12} seeds={len(rs)} per-obs {' '.join(f'{c:.3f}' for c in m.mean(0))} "
            f"mean {m.mean():.3f} sd(seed means) {sd:.3f} train {np.mean([r['train_s'] for r in rs]):.1f} s"
        )


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--variant", default="base")
    ap.add_argument("--over", default="{}", help="JSON: NPEConfig fields over config_for")
    ap.add_argument("--wide", type=float, default=0.0)
    ap.add_argument("--seeds", nargs="+", type=int, default=[0])
    ap.add_argument("--sbi", action="store_true", help="sbi's NPE instead of ours")
    ap.add_argument("--task", default="two_moons")
    ap.add_argument("--budget", type=int, default=10_000)
    ap.add_argument("--sim-seed", type=int, default=0)
    ap.add_argument("--n-obs", type=int, default=3)
    ap.add_argument("--out", default=OUT)
    ap.add_argument("--summary", action="store_true")
    args = ap.parse_args()
    if args.summary:
        return summary(args.out)
    task = get_task(args.task)
    theta, x = vs_sbi.simulations(task, args.budget, args.sim_seed)
    over = json.loads(args.over)
    for seed in args.seeds:
        if args.sbi:
            sample, train_s = vs_sbi.train_sbi(task, theta, x, seed)
            epochs = None
        else:
            sample, train_s, epochs = train_ours(task, theta, x, args.budget, seed, over, args.wide)
        scores = []
        for i in range(1, args.n_obs + 1):
            x_o, ref = _sbibm.observation(args.task, i), _sbibm.reference_posterior_samples(args.task, i)
            scores.append(_sbibm.c2st(ref, sample(x_o, 10_000)))
        rec = {
            "variant": "sbi" if args.sbi else args.variant,
            "over": over,
            "wide": args.wide,
            "task": args.task,
            "budget": args.budget,
            "sim_seed": args.sim_seed,
            "seed": seed,
            "c2st": scores,
            "mean": float(np.mean(scores)),
            "train_s": train_s,
            "epochs": epochs,
            "load": os.getloadavg()[0],
            "commit": vs_sbi._commit(),
        }
        print(json.dumps(rec), flush=True)
        with open(args.out, "a") as f:
            f.write(json.dumps(rec) + "\n")


if __name__ == "__main__":
    main()
