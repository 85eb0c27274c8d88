"""Where APT training time goes: steps/s per loss and batch size, and one APT run round by round.

Usage:
    python benchmarks/train_profile.py                 # two_moons and slcp, APT at 10⁴
    python benchmarks/train_profile.py --quick         # two_moons, APT at 10³

Writes ``benchmarks/results/train_profile.json``: for each task, compiled-step throughput
(``steps_per_s``, after compilation) of the maximum-likelihood and atomic losses at each batch
size, and for one APT run (observation 1, 10 rounds) per round: simulations, epochs, best
epoch, wall seconds, and how many times the compiled step/eval functions were traced.
"""

import argparse
import json
import os
import time

import jax
import numpy as np

from vdsbi.inference import (
    TRACE_COUNTS,
    AtomicLoss,
    IdentityEmbedding,
    MaximumLikelihoodLoss,
    NPEConfig,
    apt,
    build_flow,
    data_mesh,
    init_opt_state,
    make_optimizer,
    stack_batches,
    train_steps,
)
from vdsbi.tasks import get_task

HERE = os.path.dirname(os.path.abspath(__file__))


def steps_per_second(task, loss, batch_size, seconds=3.0, steps=32):
    """Throughput of ``train_steps`` (blocks of ``steps``) after one compiling call."""
    key = jax.random.key(0)
    theta = np.asarray(task.prior.sample(key, 4096), np.float32)
    x = np.asarray(task.simulate(jax.random.key(1), theta)[0], np.float32)
    flow = build_flow(key, task.prior, IdentityEmbedding(task.dim_x), theta, x, NPEConfig())
    opt = make_optimizer(5e-4, 0.0, 5.0)
    state = init_opt_state(flow, opt)
    idx = np.random.default_rng(0).integers(0, len(theta), (steps, batch_size))
    batches = stack_batches((theta[idx], x[idx], np.ones(idx.shape, bool)), data_mesh())
    keys = jax.random.split(key, steps)
    flow, state, m = train_steps(flow, state, batches, keys, loss, opt)
    m.block_until_ready()
    t0, n = time.perf_counter(), 0
    while time.perf_counter() - t0 < seconds:
        flow, state, m = train_steps(flow, state, batches, keys, loss, opt)
        m.block_until_ready()
        n += steps
    return n / (time.perf_counter() - t0)


def apt_rounds(task, budget, config):
    """One APT run (10 rounds) at observation 1: per-round epochs, wall time and traces."""
    _, x_o = task.observation(1)
    rows, last = [], [time.perf_counter(), dict(TRACE_COUNTS)]

    def on_round_end(state):
        h = state.history[-1]
        now, traces = time.perf_counter(), dict(TRACE_COUNTS)
        new = {k: traces.get(k, 0) - last[1].get(k, 0) for k in traces}
        rows.append(
            {
                "round": h["round"],
                "num_train": int((~state.is_val).sum()),
                "epochs": h["epochs"],
                "best_epoch": h["best_epoch"],
                "batch_size": h["batch_size"],
                "wall_s": now - last[0],
                "new_traces": {k: v for k, v in new.items() if v},
            }
        )
        print(f"  round {rows[-1]}", flush=True)
        last[:] = [now, traces]

    t0 = time.perf_counter()
    apt(
        jax.random.key(0),
        task.simulate,
        task.prior,
        x_o,
        embedding=IdentityEmbedding(task.dim_x),
        rounds=10,
        sims_per_round=budget // 10,
        config=config,
        on_round_end=on_round_end,
    )
    return {"budget": budget, "total_s": time.perf_counter() - t0, "rounds": rows}


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--quick", action="store_true")
    ap.add_argument("--tasks", nargs="+", default=["two_moons", "slcp"])
    ap.add_argument("--batch-sizes", nargs="+", type=int, default=[128, 256, 512])
    ap.add_argument("--budget", type=int, default=10_000)
    ap.add_argument("--out", default=os.path.join(HERE, "results", "train_profile.json"))
    args = ap.parse_args()
    if args.quick:
        args.tasks, args.batch_sizes, args.budget = ["two_moons"], [128], 1_000
    out = {"devices": [f"{d.platform}:{d.device_kind}" for d in jax.devices()], "tasks": {}}
    for name in args.tasks:
        task = get_task(name)
        thr = {}
        for loss in (MaximumLikelihoodLoss(), AtomicLoss(num_atoms=10)):
            for b in args.batch_sizes:
                thr[f"{type(loss).__name__}@{b}"] = steps_per_second(task, loss, b)
                print(f"{name} {type(loss).__name__} batch {b}: {thr[f'{type(loss).__name__}@{b}']:.1f} steps/s", flush=True)
        out["tasks"][name] = {"steps_per_s": thr, "apt": apt_rounds(task, args.budget, NPEConfig(max_epochs=500))}
        print(f"{name} APT {args.budget}: {out['tasks'][name]['apt']['total_s']:.1f} s", flush=True)
    if not args.quick:
        os.makedirs(os.path.dirname(args.out), exist_ok=True)
        with open(args.out, "w") as f:
            json.dump(out, f, indent=1)


if __name__ == "__main__":
    main()
