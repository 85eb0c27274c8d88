"""The C2ST of exact posterior samples: how low the grid's protocol can go.

For each task whose posterior can be sampled exactly (two_moons, gaussian_mixture,
gaussian_linear_uniform: ``benchmarks/tasks``' samplers, `AbstractTask.posterior_samples`), draw
``--num-samples`` posterior samples at sbibm's observations and score them against sbibm's
reference posterior samples with sbibm's C2ST, exactly as ``sbi_tasks.py`` scores an estimator.
A perfect estimator scores this on average; a cell of the grid that misses sbibm's figure by
less than this floor's spread is within the protocol's noise, and a published figure below
the floor was partly luck of the classifier.

Usage (needs ``pip install -e '.[bench]'``):
    python benchmarks/c2st_floor.py --c2st-jobs 2     # three tasks, observations 1-10
    python benchmarks/c2st_floor.py --quick           # two_moons, 1 observation, 1000 samples

Writes ``benchmarks/results/c2st_floor.json`` after every observation (a re-run resumes) and the
tables to ``benchmarks/results/c2st_floor.md``: the floor, and every cell of
``results/sbi_tasks.json`` on these tasks less the floor at the same observations (a re-run with
nothing left to draw rewrites it from the grid as it stands).
"""

import argparse
import json
import os
import sys
import time
import zlib

import jax
import numpy as np

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
import _sbibm  # noqa: E402
from sbi_tasks import PUBLISHED, _load  # noqa: E402
from tasks import get_task  # noqa: E402

HERE = os.path.dirname(os.path.abspath(__file__))
TASKS = ("gaussian_linear_uniform", "two_moons", "gaussian_mixture")
GRID = os.path.join(HERE, "results", "sbi_tasks.json")


def floor_c2st(key, task_name: str, obs: int, num_samples: int, c2st_jobs: int) -> dict:
    """One observation: exact posterior samples at sbibm's ``x_o`` against sbibm's reference."""
    task = get_task(task_name)
    if not task.exact_posterior:
        raise ValueError(f"{task_name} has no exact posterior sampler")
    x_o, ref = _sbibm.observation(task_name, obs), _sbibm.reference_posterior_samples(task_name, obs)
    ref = ref[:num_samples]  # equal classes: with fewer samples than the reference, C2ST reads imbalance
    t0 = time.perf_counter()
    samples = task.posterior_samples(jax.random.fold_in(key, obs), np.ravel(x_o), num_samples)
    score = _sbibm.c2st(ref, samples, n_jobs=c2st_jobs)
    return {"obs_id": obs, "c2st": score, "seconds": time.perf_counter() - t0}


def table(results: dict) -> str:
    lines = [
        "| task | exact samples: C2ST mean ± sd | min – max | n | sbibm 10⁵ NPE / SNPE |",
        "|---|---|---|---|---|",
    ]
    for t, recs in results.items():
        c = np.array([r["c2st"] for r in recs])
        if not c.size:
            continue
        sd = c.std(ddof=1) if c.size > 1 else 0.0
        npe, snpe = PUBLISHED[(t, "npe")][-1], PUBLISHED[(t, "apt")][-1]
        lines.append(
            f"| {t} | {c.mean():.3f} ± {sd:.3f} | {c.min():.3f} – {c.max():.3f} | {c.size} | {npe:.3f} / {snpe:.3f} |"
        )
    return "\n".join(lines)


def excess_table(floor: dict, grid: list) -> str:
    """The grid's cells on these tasks, each observation's C2ST less the floor at that observation
    (paired, so the classifier's noise at one observation largely cancels), beside sbibm's
    published figure less the mean floor (their observations' own scores are not published)."""
    lines = [
        "| task | method | budget | C2ST | above the floor, paired (± se) | sbibm less the mean floor |",
        "|---|---|---|---|---|---|",
    ]
    for cell in grid:
        by_obs = {r["obs_id"]: r["c2st"] for r in floor.get(cell["task"], [])}
        d = [r["c2st"] - by_obs[r["obs_id"]] for r in cell["per_observation"] if r["obs_id"] in by_obs]
        if len(d) < 2:
            continue
        se = np.std(d, ddof=1) / np.sqrt(len(d))
        pub = cell["published"] - np.mean(list(by_obs.values()))
        lines.append(
            f"| {cell['task']} | {cell['method']} | {cell['budget']:.0e} | {cell['c2st_mean']:.3f} (n={len(d)}) "
            f"| {np.mean(d):+.4f} ± {se:.4f} | {pub:+.4f} |"
        )
    return "\n".join(lines)


def _save(path: str, results: dict, meta: dict) -> None:
    with open(path + ".tmp", "w") as f:
        json.dump({"results": results, "meta": meta}, f, indent=1)
    os.replace(path + ".tmp", path)
    md = os.path.splitext(path)[0] + ".md"
    with open(md + ".tmp", "w") as f:
        f.write("# C2ST of exact posterior samples against sbibm's reference (the protocol's floor)\n\n")
        f.write(table(results) + "\n")
        f.write(f"\nThe grid's cells (`{os.path.relpath(GRID, HERE)}`) against the floor:\n\n")
        f.write(excess_table(results, _load(GRID)) + "\n")
    os.replace(md + ".tmp", md)


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--quick", action="store_true")
    ap.add_argument("--tasks", nargs="+", default=list(TASKS), choices=TASKS)
    ap.add_argument("--n-obs", type=int, default=10)
    ap.add_argument("--num-samples", type=int, default=10_000)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--c2st-jobs", type=int, default=1, help="parallel C2ST folds (same result as 1)")
    ap.add_argument("--out", default=os.path.join(HERE, "results", "c2st_floor.json"))
    args = ap.parse_args()
    if args.quick:
        args.tasks, args.n_obs, args.num_samples = ["two_moons"], 1, 1_000
    stored = {}
    if not args.quick and os.path.exists(args.out):
        with open(args.out) as f:
            old = json.load(f)
        if old["meta"]["num_samples"] == args.num_samples and old["meta"]["seed"] == args.seed:
            stored = old["results"]  # resume: same protocol, finished observations kept
    meta = {"num_samples": args.num_samples, "seed": args.seed, "protocol": __doc__}
    key = jax.random.key(args.seed)
    for t in args.tasks:
        recs = stored.setdefault(t, [])
        for obs in range(1, args.n_obs + 1):
            if any(r["obs_id"] == obs for r in recs):
                continue
            recs.append(
                floor_c2st(
                    jax.random.fold_in(key, zlib.crc32(t.encode()) % 2**31),
                    t,
                    obs,
                    args.num_samples,
                    args.c2st_jobs,
                )
            )
            print(f"{t} obs {obs}: c2st {recs[-1]['c2st']:.4f} ({recs[-1]['seconds']:.0f} s)", flush=True)
            if not args.quick:
                _save(args.out, stored, meta)
    print(table(stored))
    if not args.quick:
        _save(args.out, stored, meta)  # the grid may have grown since: its table is rewritten
        print(excess_table(stored, _load(GRID)))


if __name__ == "__main__":
    main()
