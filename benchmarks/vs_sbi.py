"""Side by side with the ``sbi`` toolkit: NPE (NSF, defaults, CPU torch) and ours on the SAME simulations.

Usage (needs ``pip install -e '.[bench]'``):
    python benchmarks/vs_sbi.py                       # two_moons, slcp at 10³ and 10⁴
    python benchmarks/vs_sbi.py --quick               # two_moons at 10³, one observation
    python benchmarks/vs_sbi.py --tasks slcp --budgets 10000   # one cell (resumes the JSON)

For each (task, budget): ``budget`` prior draws and their simulations are made once (our JAX
simulators of the sbibm tasks, fixed seed); sbi's ``NPE(density_estimator="nsf")`` with
``train()`` at its defaults, and ours (``vdsbi.inference.npe``, the settings of
``benchmarks/sbi_tasks.py``), are trained on them. Both are amortised: one network per cell,
sampled at sbibm's observations 1..n (``--n-obs``) and scored against sbibm's reference
posterior samples with sbibm's C2ST (scikit-learn MLP, 5-fold). ``*_train_s`` is the training
wall time (ours includes JIT compilation in a fresh process, no persistent compilation cache;
``ours_compile_s`` is the part of it spent tracing, lowering and compiling, from JAX's
monitoring events); ``ours_warm_train_s`` is the same training repeated at once in the same
process (same data and seed, so the same flow, its programs already compiled: what a second
fit of the same shapes costs, e.g. the next drive or task in the same process). The target
is judged on the cold time; sampling and C2ST are not timed. Each cell records the 1-minute load average
before each side's training and the commit. ``--force`` re-runs named cells (sbi's side too:
its time varies with the machine's load, so both sides run in the same process, back to back).

Ours runs the grid's NPE settings without the weight averaging (``OURS``): averaging over one
epoch lets training run on, and this table is about speed at sbi's accuracy. Ours uses
``theta_map="affine"`` (the flow on θ, as sbi).

Writes ``benchmarks/results/vs_sbi.json`` after every cell (finished cells are skipped on a
re-run), and the table to ``benchmarks/results/vs_sbi.md``.
"""

import argparse
import json
import os
import subprocess
import sys
import time

import jax
import numpy as np

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
import _sbibm  # noqa: E402
from _config import flat_config  # noqa: E402
from sbi_tasks import config_for  # noqa: E402
from tasks import get_task  # noqa: E402

from vdsbi.inference import IdentityEmbedding, Posterior, npe  # noqa: E402

HERE = os.path.dirname(os.path.abspath(__file__))
OURS = {"average_epochs": 0.0}  # the grid's NPE settings less the weight averaging (see above)


def simulations(task, budget, seed):
    key = jax.random.fold_in(jax.random.key(seed), budget)
    k_theta, k_x = jax.random.split(key)
    theta = task.prior.sample(k_theta, budget)
    x, valid = task.simulate(k_x, theta)
    assert bool(np.all(np.asarray(valid))), "the sbibm tasks have no invalid simulations"
    return np.asarray(theta, np.float32), np.asarray(x, np.float32)


def train_sbi(task, theta, x, seed):
    """sbi's NPE with a neural spline flow, everything else at sbi's defaults; returns a sampler."""
    import torch
    from sbi.inference import NPE
    from sbi.utils import BoxUniform

    torch.manual_seed(seed)
    prior = BoxUniform(
        torch.as_tensor(np.asarray(task.prior.low)), torch.as_tensor(np.asarray(task.prior.high))
    )
    inference = NPE(prior=prior, density_estimator="nsf", show_progress_bars=False)
    t0 = time.perf_counter()
    inference.append_simulations(torch.as_tensor(theta), torch.as_tensor(x)).train()
    train_s = time.perf_counter() - t0
    posterior = inference.build_posterior()

    def sample(x_o, n):
        with torch.no_grad():
            s = posterior.sample((n,), x=torch.as_tensor(x_o)[None], show_progress_bars=False)
        return s.numpy()

    return sample, train_s


_COMPILE_EVENTS = (
    "/jax/core/compile/jaxpr_trace_duration",
    "/jax/core/compile/jaxpr_to_mlir_module_duration",
    "/jax/core/compile/backend_compile_duration",
)
_COMPILE_S: list = []  # seconds of every tracing, lowering and XLA compilation since cleared
jax.monitoring.register_event_duration_secs_listener(
    lambda event, secs, **_: _COMPILE_S.append(secs) if event in _COMPILE_EVENTS else None
)


def train_ours(task, theta, x, budget, seed):
    """Ours; returns a sampler, training seconds, epochs and the seconds of them spent compiling."""
    key = jax.random.key(seed)
    _COMPILE_S.clear()
    t0 = time.perf_counter()
    flow, info = npe(
        key, task.prior, theta, x, embedding=IdentityEmbedding(task.dim_x), config=config_for(budget, **OURS)
    )
    jax.block_until_ready(flow)
    train_s = time.perf_counter() - t0
    compile_s = sum(_COMPILE_S)

    def sample(x_o, n):
        return np.asarray(Posterior(flow, x_o).sample(jax.random.fold_in(key, 7), n))

    return sample, train_s, info["epochs"], compile_s


def run_cell(task_name, budget, n_obs, num_samples, seed):
    import torch

    commit = _commit()  # of the code this process imported, not of HEAD when the cell ends
    task = get_task(task_name)
    theta, x = simulations(task, budget, seed)
    load_sbi = os.getloadavg()[0]
    sbi_sample, sbi_s = train_sbi(task, theta, x, seed)
    print(f"  sbi trained in {sbi_s:.1f} s (load {load_sbi:.2f})", flush=True)
    load_ours = os.getloadavg()[0]
    ours_sample, ours_s, epochs, compile_s = train_ours(task, theta, x, budget, seed)
    print(
        f"  ours trained in {ours_s:.1f} s ({epochs} epochs, {compile_s:.1f} s compiling, load {load_ours:.2f})",
        flush=True,
    )
    _, warm_s, warm_epochs, warm_compile_s = train_ours(task, theta, x, budget, seed)
    print(f"  ours again, compiled: {warm_s:.1f} s ({warm_compile_s:.1f} s compiling)", flush=True)
    if warm_epochs != epochs:  # the same fit must repeat exactly, else the two times differ in work
        raise RuntimeError(f"the repeated fit ran {warm_epochs} epochs, the first {epochs}")
    ours, theirs = [], []
    for i in range(1, n_obs + 1):
        x_o, ref = _sbibm.observation(task_name, i), _sbibm.reference_posterior_samples(task_name, i)
        ours.append(_sbibm.c2st(ref, ours_sample(x_o, num_samples)))
        theirs.append(_sbibm.c2st(ref, sbi_sample(x_o, num_samples)))
        print(f"  obs {i}: c2st ours {ours[-1]:.3f}  sbi {theirs[-1]:.3f}", flush=True)
    return {
        "task": task_name,
        "budget": budget,
        "ours_c2st": float(np.mean(ours)),
        "sbi_c2st": float(np.mean(theirs)),
        "ours_train_s": ours_s,
        "sbi_train_s": sbi_s,
        "speedup": sbi_s / ours_s,
        "ours_warm_train_s": warm_s,
        "ours_warm_compile_s": warm_compile_s,
        "speedup_warm": sbi_s / warm_s,
        "ours_c2st_per_obs": ours,
        "sbi_c2st_per_obs": theirs,
        "ours_epochs": epochs,
        "ours_compile_s": compile_s,
        "load_sbi": load_sbi,
        "load_ours": load_ours,
        "commit": commit,
        "ours_config": flat_config(config_for(budget, **OURS)),
        "n_obs": n_obs,
        "torch_threads": torch.get_num_threads(),
    }


def _commit() -> str:
    """HEAD's short hash, ``+dirty`` when the package has uncommitted changes."""
    git = ["git", "-C", HERE]
    head = subprocess.run(
        [*git, "rev-parse", "--short", "HEAD"], capture_output=True, text=True
    ).stdout.strip()
    dirty = subprocess.run([*git, "status", "--porcelain", "--", "../vdsbi"], capture_output=True, text=True)
    return head + ("+dirty" if dirty.stdout.strip() else "")


def table(cells) -> str:
    lines = [
        "| task | budget | ours C2ST | sbi C2ST | ours train s (compiling) | sbi train s | sbi/ours time "
        "| ours again, compiled: s (sbi/ours) | load sbi/ours | commit |",
        "|---|---|---|---|---|---|---|---|---|---|",
    ]
    for c in cells:
        mark = "✓" if c["ours_c2st"] <= c["sbi_c2st"] else "✗"
        comp = f" ({c['ours_compile_s']:.1f})" if "ours_compile_s" in c else ""
        load = f"{c['load_sbi']:.1f}/{c['load_ours']:.1f}" if "load_sbi" in c else "–"
        warm = f"{c['ours_warm_train_s']:.1f} ({c['speedup_warm']:.1f}×)" if "speedup_warm" in c else "–"
        lines.append(
            f"| {c['task']} | {c['budget']:.0e} | {c['ours_c2st']:.3f} {mark} | {c['sbi_c2st']:.3f} "
            f"| {c['ours_train_s']:.1f}{comp} | {c['sbi_train_s']:.1f} | {c['speedup']:.1f}× "
            f"| {warm} | {load} | {c.get('commit', '–')} |"
        )
    return "\n".join(lines)


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--quick", action="store_true")
    ap.add_argument("--tasks", nargs="+", default=["two_moons", "slcp"])
    ap.add_argument("--budgets", nargs="+", type=int, default=[1_000, 10_000])
    ap.add_argument("--n-obs", type=int, default=3)
    ap.add_argument("--num-samples", type=int, default=10_000)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--out", default=os.path.join(HERE, "results", "vs_sbi.json"))
    ap.add_argument("--force", action="store_true", help="re-run the named cells (replace them)")
    args = ap.parse_args()
    if args.quick:
        args.tasks, args.budgets, args.n_obs, args.num_samples = ["two_moons"], [1_000], 1, 2_000
    cells = [] if args.quick or not os.path.exists(args.out) else json.load(open(args.out))["cells"]
    todo = [
        (name, budget)
        for budget in args.budgets
        for name in args.tasks
        if args.force or not any(c["task"] == name and c["budget"] == budget for c in cells)
    ]
    if len(todo) > 1:
        # "cold" means a fresh process: in one process a later cell reuses the earlier cells'
        # compiled programs
        for name, budget in todo:
            _run_alone(args, name, budget)
        return
    for name, budget in todo:
        print(f"cell {name} {budget}", flush=True)
        cell = run_cell(name, budget, args.n_obs, args.num_samples, args.seed)
        cells = [c for c in cells if not (c["task"] == name and c["budget"] == budget)] + [cell]
        print(table(cells), flush=True)
        if not args.quick:
            _save(args.out, cells)


def _run_alone(args, name: str, budget: int) -> None:
    """One cell in a fresh process (it reads and rewrites ``args.out`` itself)."""
    cmd = [sys.executable, os.path.abspath(__file__), "--tasks", name, "--budgets", str(budget)]
    cmd += ["--n-obs", str(args.n_obs), "--num-samples", str(args.num_samples), "--seed", str(args.seed)]
    cmd += ["--out", args.out] + (["--force"] if args.force else [])
    subprocess.run(cmd, check=True)


def _save(path, cells):
    os.makedirs(os.path.dirname(path), exist_ok=True)
    d = jax.devices()[0]
    out = {
        "cells": cells,
        "device": f"{d.platform}:{d.device_kind}",
        "num_devices": jax.device_count(),
        "protocol": __doc__,
    }
    with open(path + ".tmp", "w") as f:
        json.dump(out, f, indent=1)
    os.replace(path + ".tmp", path)
    n_obs = "/".join(str(n) for n in sorted({c["n_obs"] for c in cells}))
    with open(os.path.splitext(path)[0] + ".md", "w") as f:
        f.write(
            f"# ours vs sbi (NPE, NSF): C2ST mean over sbibm observations 1..{n_obs}, training seconds\n\n"
        )
        f.write(f"device {out['device']} ×{out['num_devices']}\n\n" + table(cells) + "\n")


if __name__ == "__main__":
    main()
