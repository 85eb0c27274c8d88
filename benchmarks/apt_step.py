"""Cost of one training step of the spline flow: APT's atomic loss against maximum likelihood.

    python benchmarks/apt_step.py                 # d = 2, 5, 6; one process
    python benchmarks/apt_step.py --concurrent 2  # the same, N identical processes at once

The step is ``value_and_grad`` of the loss over a batch of 128 (sbi's NSF settings: 5 layers,
10 bins, hidden 50, 10 atoms; θ on R^d as in ``benchmarks/sbi_tasks.py``), compiled, timed over
100 calls after one warm-up. ``--concurrent N`` starts N copies of this measurement at once and
reports each one's time: on a machine whose cores scale, each stays at the one-process time.
Writes ``results/apt_step.json`` (``--out``).
"""

import argparse
import json
import os
import subprocess
import sys
import time

HERE = os.path.dirname(os.path.abspath(__file__))
BATCH, ATOMS, CALLS = 128, 10, 100
DIMS = ((2, 2), (5, 8), (6, 64))  # (θ dim, x dim): two_moons, slcp, the vehicle's six at a 64-d context


def step_ms(dim: int, x_dim: int) -> dict:
    """Milliseconds per atomic and per maximum-likelihood step at one (θ, x) size."""
    import equinox as eqx
    import jax
    import jax.numpy as jnp

    from vdsbi.inference import (
        AtomicLoss,
        BoxPrior,
        ConditionalFlow,
        IdentityEmbedding,
        MaximumLikelihoodLoss,
    )

    prior = BoxPrior(-3.0 * jnp.ones(dim), 3.0 * jnp.ones(dim))
    flow = ConditionalFlow(jax.random.key(0), prior, IdentityEmbedding(x_dim), (x_dim,), theta_map="affine")
    theta = jax.random.uniform(jax.random.key(1), (BATCH, dim), minval=-2.0, maxval=2.0)
    x = jax.random.normal(jax.random.key(2), (BATCH, x_dim))
    mask = jnp.zeros(BATCH, bool)
    out = {"dim": dim, "x_dim": x_dim}
    for name, loss in (("atomic_ms", AtomicLoss(num_atoms=ATOMS)), ("ml_ms", MaximumLikelihoodLoss())):
        step = eqx.filter_jit(
            eqx.filter_value_and_grad(lambda f, loss=loss: loss(f, theta, x, mask, jax.random.key(3)))
        )
        jax.block_until_ready(step(flow))
        t0 = time.perf_counter()
        for _ in range(CALLS):
            r = step(flow)
        jax.block_until_ready(r)
        out[name] = (time.perf_counter() - t0) / CALLS * 1e3
    return out


def _commit() -> str:
    r = subprocess.run(["git", "-C", HERE, "rev-parse", "--short", "HEAD"], capture_output=True, text=True)
    return r.stdout.strip() or "unknown"


def _one_process() -> list[dict]:
    return [step_ms(d, xd) for d, xd in DIMS]


def _concurrent(n: int) -> list[list[dict]]:
    cmd = [sys.executable, __file__, "--child"]
    procs = [subprocess.Popen(cmd, stdout=subprocess.PIPE, text=True) for _ in range(n)]
    return [json.loads(p.communicate()[0].strip().splitlines()[-1]) for p in procs]


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--concurrent", type=int, default=1, help="identical processes at once")
    ap.add_argument("--child", action="store_true", help=argparse.SUPPRESS)
    ap.add_argument("--out", default=os.path.join(HERE, "results", "apt_step.json"))
    args = ap.parse_args()
    if args.child:
        return print(json.dumps(_one_process()), flush=True)
    runs = _concurrent(args.concurrent) if args.concurrent > 1 else [_one_process()]
    print(f"| d | x dim | atomic ms/step | max-likelihood ms/step | ({len(runs)} process(es) at once)")
    print("|---|---|---|---|")
    for rows in zip(*runs):
        cells = [" / ".join(f"{r[k]:.2f}" for r in rows) for k in ("atomic_ms", "ml_ms")]
        print(f"| {rows[0]['dim']} | {rows[0]['x_dim']} | {cells[0]} | {cells[1]} |")
    import jax

    record = {
        "concurrent": len(runs),
        "runs": runs,
        "batch": BATCH,
        "atoms": ATOMS,
        "device": f"{jax.devices()[0].platform} {jax.devices()[0].device_kind}",
        "cpu_count": os.cpu_count(),
        "commit": _commit(),
    }
    os.makedirs(os.path.dirname(args.out), exist_ok=True)
    stored = {}
    if os.path.exists(args.out):
        with open(args.out) as f:
            stored = json.load(f)
    stored[f"concurrent_{len(runs)}"] = record
    with open(args.out + ".tmp", "w") as f:
        json.dump(stored, f, indent=1)
    os.replace(args.out + ".tmp", args.out)


if __name__ == "__main__":
    main()
