"""Where training time goes: NPE split into compilation and epochs, step throughput, APT by round.

Usage:
    python benchmarks/train_profile.py --npe two_moons:10000 slcp:1000   # NPE on vs-sbi cells
    python benchmarks/train_profile.py --steps two_moons slcp            # steps/s per loss, batch
    python benchmarks/train_profile.py --apt two_moons                   # APT 10⁴, obs 1, 10 rounds
    python benchmarks/train_profile.py --quick                           # small versions, no file

Sections are merged into ``benchmarks/results/train_profile.json`` (so each can run in its own
hold of the heavy-job lock) and the NPE table is written to ``train_profile.md``. Every entry
records the commit, the load average and the device.

``--npe TASK:BUDGET``: one `npe` fit with ``sbi_tasks.config_for(BUDGET)`` on the simulations of
``benchmarks/vs_sbi.py`` (the same cell, seed 0), timed as ``vs_sbi.py`` times it, each cell in a
fresh process (nothing compiled yet, no persistent compilation cache). Compilation
seconds (tracing + lowering + XLA) are read from JAX's monitoring events, per function; the
epochs from ``on_epoch_end`` timestamps: ``first_epoch_s`` runs from the call to the end of
epoch 1 (data split, flow initialisation, the compilations of the step and validation loops),
``steady_epoch_s`` is the median epoch after it.

``--steps``: compiled-step throughput (``train_steps`` in blocks of 32, after compilation) of
the maximum-likelihood and atomic losses at each batch size, without and with the weight
average (``+average``), and the first call's seconds.

``--apt``: one APT run (observation 1, 10 rounds of budget/10, the grid's APT settings) with per-round simulations,
epochs, wall seconds, and how many times the step / validation loops were traced.
"""

import argparse
import collections
import json
import os
import subprocess
import sys
import time

import jax
import numpy as np

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
import vs_sbi  # noqa: E402
from sbi_tasks import config_for  # noqa: E402

from vdsbi.inference import (  # noqa: E402
    TRACE_COUNTS,
    AtomicLoss,
    IdentityEmbedding,
    MaximumLikelihoodLoss,
    apt,
    build_flow,
    data_mesh,
    init_opt_state,
    make_optimizer,
    npe,
    replicate,
    stack_batches,
    train_steps,
)
from vdsbi.tasks import get_task  # noqa: E402

HERE = os.path.dirname(os.path.abspath(__file__))
_COMPILE_EVENTS = {
    "/jax/core/compile/jaxpr_trace_duration": "trace",
    "/jax/core/compile/jaxpr_to_mlir_module_duration": "lower",
    "/jax/core/compile/backend_compile_duration": "xla",
}
_EVENTS: list = []


def _listener(event, secs, **kw):
    if event in _COMPILE_EVENTS:
        _EVENTS.append((_COMPILE_EVENTS[event], str(kw.get("fun_name", "?")), secs))


jax.monitoring.register_event_duration_secs_listener(_listener)


def _compile_summary(events) -> dict:
    """Seconds by stage and by function (the step and validation loops, the flow's
    initialisation, and everything else together)."""
    by_stage = collections.Counter()
    by_fun = collections.Counter()
    for stage, name, secs in events:
        by_stage[stage] += secs
        key = next((k for k in ("train_steps", "eval_steps", "make", "<lambda>") if k in name), "other")
        by_fun["init" if key in ("make", "<lambda>") else key] += secs
    return {"total_s": sum(by_stage.values()), "by_stage": dict(by_stage), "by_function": dict(by_fun)}


def npe_profile(task_name: str, budget: int, seed: int = 0) -> dict:
    task = get_task(task_name)
    theta, x = vs_sbi.simulations(task, budget, seed)
    config = config_for(budget)
    stamps = []
    _EVENTS.clear()
    t0 = time.perf_counter()
    flow, info = npe(
        jax.random.key(seed),
        task.prior,
        theta,
        x,
        embedding=IdentityEmbedding(task.dim_x),
        config=config,
        on_epoch_end=lambda *_: stamps.append(time.perf_counter()),
    )
    jax.block_until_ready(flow)
    total = time.perf_counter() - t0
    epoch_s = np.diff(stamps)
    n_train = budget - max(1, round(config.validation_fraction * budget))
    steps = n_train // info["batch_size"]
    steady = float(np.median(epoch_s)) if epoch_s.size else float("nan")
    return {
        "total_s": total,
        "compile": _compile_summary(_EVENTS),
        "epochs": info["epochs"],
        "best_epoch": info["best_epoch"],
        "best_val_loss": info["best_val_loss"],
        "first_epoch_s": stamps[0] - t0,
        "steady_epoch_s": steady,
        "later_epochs_s": float(epoch_s.sum()),
        "steps_per_epoch": steps,
        "steady_steps_per_s": steps / steady,
        "batch_size": info["batch_size"],
        **_context(),
    }


def steps_per_second(task, loss, batch_size, seconds=3.0, steps=32, average=False) -> dict:
    """Throughput of ``train_steps`` (blocks of ``steps``) after one compiling call; ``average``:
    with the weight average of ``NPEConfig.average_epochs`` updated after every step."""
    key = jax.random.key(0)
    theta = np.asarray(task.prior.sample(key, 4096), np.float32)
    x = np.asarray(task.simulate(jax.random.key(1), theta)[0], np.float32)
    flow = build_flow(key, task.prior, IdentityEmbedding(task.dim_x), theta, x, config_for(10_000))
    opt, mesh = make_optimizer(5e-4, 0.0, 5.0), data_mesh()
    # placed as `fit` places them: an uncommitted input would compile a second time
    flow = replicate(flow, mesh)
    state = replicate(init_opt_state(flow, opt), mesh)
    idx = np.random.default_rng(0).integers(0, len(theta), (steps, batch_size))
    batches = stack_batches((theta[idx], x[idx], np.ones(idx.shape, bool)), mesh)
    keys = jax.random.split(key, steps)
    live = np.ones(steps, bool)
    avg = (flow, replicate(jax.numpy.asarray(0.99), mesh)) if average else None

    def call(flow, state, avg):
        out = train_steps(flow, state, batches, keys, loss, opt, live, avg)
        out[2].block_until_ready()
        return out[0], out[1], None if avg is None else (out[3], avg[1])

    t0 = time.perf_counter()
    flow, state, avg = call(flow, state, avg)
    first = time.perf_counter() - t0
    t0, n = time.perf_counter(), 0
    while time.perf_counter() - t0 < seconds:
        flow, state, avg = call(flow, state, avg)
        n += steps
    return {"steps_per_s": n / (time.perf_counter() - t0), "first_call_s": first}


def apt_rounds(task, budget, config) -> dict:
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
    return {"budget": budget, "total_s": time.perf_counter() - t0, "rounds": rows, **_context()}


def _context() -> dict:
    commit = subprocess.run(
        ["git", "-C", HERE, "rev-parse", "--short", "HEAD"], capture_output=True, text=True
    )
    dirty = subprocess.run(
        ["git", "-C", HERE, "status", "--porcelain", "--", "../vdsbi"], capture_output=True, text=True
    )
    d = jax.devices()[0]
    return {
        "commit": commit.stdout.strip() + ("+dirty" if dirty.stdout.strip() else ""),
        "load": os.getloadavg()[0],
        "device": f"{d.platform}:{d.device_kind}",
    }


def npe_table(npe_cells: dict) -> str:
    lines = [
        "| cell | total s | compile s (step / validation / init / other) | first epoch s | epochs "
        "(best) | steady s/epoch | steps/epoch | steps/s | commit | load |",
        "|---|---|---|---|---|---|---|---|---|---|",
    ]
    for name, c in npe_cells.items():
        f = c["compile"]["by_function"]
        parts = " / ".join(f"{f.get(k, 0.0):.1f}" for k in ("train_steps", "eval_steps", "init", "other"))
        lines.append(
            f"| {name} | {c['total_s']:.1f} | {c['compile']['total_s']:.1f} ({parts}) | {c['first_epoch_s']:.1f} "
            f"| {c['epochs']} ({c['best_epoch']}) | {c['steady_epoch_s']:.3f} | {c['steps_per_epoch']} "
            f"| {c['steady_steps_per_s']:.0f} | {c['commit']} | {c['load']:.1f} |"
        )
    return "\n".join(lines)


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--quick", action="store_true")
    ap.add_argument("--npe", nargs="*", default=[], metavar="TASK:BUDGET")
    ap.add_argument("--steps", nargs="*", default=[], metavar="TASK")
    ap.add_argument("--apt", nargs="*", default=[], metavar="TASK")
    ap.add_argument("--batch-sizes", nargs="+", type=int, default=[128, 256, 512])
    ap.add_argument("--budget", type=int, default=10_000, help="APT budget")
    ap.add_argument("--out", default=os.path.join(HERE, "results", "train_profile.json"))
    args = ap.parse_args()
    if args.quick:
        args.npe, args.steps, args.apt, args.batch_sizes, args.budget = (
            ["two_moons:1000"],
            ["two_moons"],
            [],
            [128],
            1_000,
        )
    out = json.load(open(args.out)) if os.path.exists(args.out) and not args.quick else {}
    out = {k: v for k, v in out.items() if k in ("npe", "steps", "apt")}  # older layouts dropped
    for cell in args.npe:
        if len(args.npe) > 1 and not args.quick:  # each cell cold, as vs_sbi.py times it
            subprocess.run([sys.executable, __file__, "--npe", cell, "--out", args.out], check=True)
            out["npe"] = json.load(open(args.out))["npe"]
            continue
        name, budget = cell.split(":")
        res = npe_profile(name, int(budget))
        out.setdefault("npe", {})[f"{name}@{int(budget)}"] = res
        print(f"NPE {cell}: {json.dumps(res)}", flush=True)
    for name in args.steps:
        task = get_task(name)
        for loss in (MaximumLikelihoodLoss(), AtomicLoss(num_atoms=10)):
            for b in args.batch_sizes:
                for average in (False, True):  # what the weight average adds to a step
                    res = {**steps_per_second(task, loss, b, average=average), **_context()}
                    label = f"{type(loss).__name__}{'+average' if average else ''}"
                    out.setdefault("steps", {})[f"{name}/{label}@{b}"] = res
                    print(f"{name} {label} batch {b}: {res['steps_per_s']:.1f} steps/s", flush=True)
    for name in args.apt:
        res = apt_rounds(get_task(name), args.budget, config_for(args.budget, "apt"))
        out.setdefault("apt", {})[f"{name}@{args.budget}"] = res
        print(f"{name} APT {args.budget}: {res['total_s']:.1f} s", flush=True)
    if args.quick:
        return
    os.makedirs(os.path.dirname(args.out), exist_ok=True)
    with open(args.out + ".tmp", "w") as f:
        json.dump(out, f, indent=1)
    os.replace(args.out + ".tmp", args.out)
    if out.get("npe"):
        with open(os.path.splitext(args.out)[0] + ".md", "w") as f:
            f.write(
                "# NPE training time split (`benchmarks/train_profile.py --npe`)\n\n"
                + npe_table(out["npe"])
                + "\n"
            )


if __name__ == "__main__":
    main()
