"""C2ST of NPE (1 round), APT and TSNPE (10 rounds) on the sbibm tasks, beside the published figures.

Usage:
    python benchmarks/sbi_tasks.py            # full grid (long on a CPU)
    python benchmarks/sbi_tasks.py --quick    # two_moons, NPE+APT at 10³, 2 observations

Writes ``benchmarks/results/sbi_tasks.json`` after every finished cell (nothing is lost if the
run is interrupted), ``benchmarks/results/sbi_tasks.md`` with the table and ``sbi_tasks.png``
with the figure (`_grid_plot.py`).

Protocol (differences from sbibm are stated, not hidden):
* ``--observations sbibm`` (default): sbibm's own observations 1..n_obs and its reference
  posterior samples, read from the sbibm wheel (downloaded without dependencies into a cache at
  run time, see ``benchmarks/_sbibm.py``), scored with sbibm's C2ST (scikit-learn MLP, 5-fold;
  needs ``pip install -e '.[bench]'``). ``--observations ours``: the project's own tasks'
  observations and reference posteriors, scored with ``vdsbi.diagnostics.c2st`` (JAX);
* C2ST on ``--num-samples`` (default 10 000, as sbibm) posterior vs reference samples;
* NPE is amortised: ONE network per (task, budget), trained once and evaluated at every
  observation (sbibm retrains per observation); ``train_s`` is that single training time;
* APT is run per observation: 10 rounds of budget/10 simulations; ``train_s`` is the mean
  wall time per observation (simulation + training, all rounds).
* ``--methods tsnpe``: the library's other sequential estimator (`vdsbi.inference.apt` with
  ``truncate=True``, Deistler et al. 2022): the same 10 rounds, proposals from the prior truncated
  to the current posterior's HPD region, maximum likelihood on all rounds' data (no atomic
  loss); scored against sbibm's SNPE figure, like APT.

Cells are stored per observation (``per_observation``: C2ST, APT training, sampling and C2ST
seconds) with each run's commit, uncommitted changes, device and load average (``runs``). A
stored cell with the same config is resumed: APT runs only the observations it lacks, so
pieces (``--first-obs``/``--n-obs``, one heavy-lock hold each) build one cell; NPE (one network)
reruns whole unless all requested observations are stored. ``--force`` replaces the cell;
``--redo`` reruns the requested observations of a sequential cell and replaces only those.
"""

import argparse
import fcntl
import json
import os
import subprocess
import sys
import time

import jax
import numpy as np

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
import _sbibm  # noqa: E402
from _config import RETIRED, flat_config, make_config  # noqa: E402
from _grid_plot import plot_grid  # noqa: E402
from tasks import get_task  # noqa: E402

from vdsbi.diagnostics import c2st  # noqa: E402
from vdsbi.inference import Execution, IdentityEmbedding, NPEConfig, RoundSchedule, apt  # noqa: E402
from vdsbi.runtime import release_compiled_programs  # noqa: E402

PUBLISHED = {  # sbibm (Lueckmann et al. 2021), mean C2ST over 10 observations, sbi + NSF
    ("two_moons", "npe"): (0.725, 0.606, 0.542),
    ("two_moons", "apt"): (0.643, 0.554, 0.530),
    ("slcp", "npe"): (0.975, 0.901, 0.831),
    ("slcp", "apt"): (0.965, 0.845, 0.666),
    ("gaussian_mixture", "npe"): (0.731, 0.661, 0.555),
    ("gaussian_mixture", "apt"): (0.697, 0.583, 0.533),
    ("gaussian_linear_uniform", "npe"): (0.696, 0.553, 0.509),
    ("gaussian_linear_uniform", "apt"): (0.631, 0.527, 0.507),
}
BUDGETS = (1_000, 10_000, 100_000)
TASKS = ("two_moons", "slcp", "gaussian_mixture", "gaussian_linear_uniform")
HERE = os.path.dirname(os.path.abspath(__file__))


#: ``--methods fmpe``: the flow-matching estimator, amortised like NPE (one network per task and
#: budget, prior simulations only) and so held against sbibm's NPE figures. Settings chosen on
#: the held-out NLL of fresh simulations, never on reference posteriors; the full cosine course
#: runs.
FMPE = {"estimator": "fmpe", "batch_size": 256, "learning_rate": 2e-3, "lr_schedule": "cosine"}
FMPE.update(max_epochs=400, patience=400)
#: APT's penalty on the flow's mass outside the box (why: `config_for`).
APT = {"leak_weight": 10.0, "leak_rows": 64}
PUBLISHED.update({(t, "fmpe"): PUBLISHED[(t, "npe")] for t in TASKS})
PUBLISHED.update({(t, "tsnpe"): PUBLISHED[(t, "apt")] for t in TASKS})
#: methods run per observation (10 rounds each); the others are amortised (one network per cell)
SEQUENTIAL = ("apt", "tsnpe")


def config_for(budget: int, method: str = "npe", **overrides) -> NPEConfig:
    """The benchmark's settings at ``budget`` for ``method`` (``overrides``: other fields, by
    `flat_config`'s names).

    ``theta_map="affine"`` (the flow on θ, as sbi): on two_moons it scored better than the
    library's default ``"logit"``, which vehicle identification keeps.

    TSNPE, and APT at 10³, count their patience in epochs, as sbi's SNPE-C (the method sbibm's
    SNPE figures come from): the library's default scales a continued round's patience by its
    share of new data, which at 10 rounds × 100 leaves the last rounds two epochs. APT at 10⁴
    and above keeps the default, which with weight averaging bounds a round's time.

    NPE and APT average their weights over one epoch (``average_epochs=1``), so that early
    stopping does not stop on validation noise; TSNPE keeps the library's default (off).

    APT penalises the flow's mass outside the box (``leak_weight=10`` on 64 strided rows of
    each batch): with the flow on θ the atomic loss compares densities only at atoms inside
    the box, so the mass outside drifts unseen and at 10⁵ can leak away. At 10⁵ it also
    penalises that mass at x_o itself (``leak_at_observation=True``), since the batch penalty
    draws only at the training batch's contexts.
    """
    base = dict(
        batch_size=128 if budget <= 10_000 else 512,
        learning_rate=5e-4,
        patience=20,
        max_epochs=500,
        theta_map="affine",
        patience_unit="epochs" if method == "tsnpe" or (method == "apt" and budget < 10_000) else "new_data",
        average_epochs=1.0 if method in ("npe", "apt") else 0.0,
    )
    own = {"fmpe": FMPE, "apt": APT}.get(method, {})
    if method == "apt" and budget >= 100_000:
        own = {**own, "leak_at_observation": True}
    return make_config(**{**base, **own, **overrides})


class _Observations:
    """Observation ``i``, its reference samples and the C2ST: sbibm's, or the project's tasks'."""

    def __init__(self, task, source, c2st_jobs=1):
        self.task, self.source, self.c2st_jobs = task, source, c2st_jobs

    def x(self, i):
        if self.source == "sbibm":
            return _sbibm.observation(self.task.name, i)
        return self.task.observation(i)[1]

    def score(self, key, i, samples, num_samples):
        if self.source == "sbibm":
            ref = _sbibm.reference_posterior_samples(self.task.name, i)[:num_samples]
            return _sbibm.c2st(ref, np.asarray(samples), n_jobs=self.c2st_jobs)
        return c2st(key, self.task.reference_posterior_samples(i, num_samples), samples)


def _rounds(state):
    """Per round: epochs, best epoch, patience (epochs), wall seconds and, for TSNPE, how the
    truncated prior was drawn (proposal, acceptance, draws filled in from the wider proposal);
    for APT, the posterior's mass inside the box (``box_mass``)."""
    keys = ("epochs", "best_epoch", "patience", "train_s")
    extra = ("region_proposal", "acceptance", "num_filled", "box_mass")
    return [{k: h.get(k) for k in keys} | {k: h[k] for k in extra if k in h} for h in state.history]


def _provenance():
    """Commit, uncommitted changes under vdsbi/ and benchmarks/, device, load average, UTC time."""

    def git(*a):
        r = subprocess.run(["git", *a], cwd=HERE, capture_output=True, text=True)
        return r.stdout.rstrip() if r.returncode == 0 else None

    d = jax.devices()[0]
    return {
        "commit": git("rev-parse", "--short", "HEAD"),
        "dirty": (
            git("status", "--porcelain", "--untracked-files=no", "--", "../vdsbi", ".") or ""
        ).splitlines(),
        "device": f"{d.platform}:{d.device_kind}",
        "loadavg": [round(v, 2) for v in os.getloadavg()],
        "utc": time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime()),
    }


def train_posterior(task, method, budget, cfg, key, x_o, obs_id=None):
    """``(posterior, state)`` as the grid trains it: NPE/FMPE amortised (one round of ``budget``
    from ``key``), APT/TSNPE for observation ``obs_id`` (10 rounds of budget/10, ``key`` folded
    with ``obs_id``)."""
    seq = method in SEQUENTIAL
    rounds = 10 if seq else 1

    def progress(state):  # a 10⁵ observation runs 10-45 min here: say where it is
        h = state.history[-1]
        where = f"obs {obs_id} " if seq else ""
        print(
            f"    {task.name} {method} {budget} {where}round {state.round}/{rounds}: "
            f"{h['epochs']} epochs (best {h['best_epoch']}), {h['train_s']:.0f} s"
            + (f", posterior {h['box_mass']:.1%} in the box" if "box_mass" in h else ""),
            flush=True,
        )

    return apt(
        jax.random.fold_in(key, obs_id) if seq else key,
        task.simulate,
        task.prior,
        x_o,
        embedding=IdentityEmbedding(task.dim_x),
        schedule=RoundSchedule(
            rounds=rounds, sims_per_round=budget // 10 if seq else budget, truncate=method == "tsnpe"
        ),
        config=cfg,
        execution=Execution(on_round_end=progress),
    )


def run_cell(
    task_name, method, budget, obs_ids, num_samples, seed, source="sbibm", overrides=None, c2st_jobs=1
):
    """One (task, method, budget) cell at observations ``obs_ids``: a dict with one record per
    observation (``per_observation``) and the run's provenance (``runs``); see `summarise`."""
    task = get_task(task_name)
    obs = _Observations(task, source, c2st_jobs)
    cfg = config_for(budget, method, **(overrides or {}))
    key = jax.random.fold_in(jax.random.key(seed), budget)
    run = {"obs_ids": list(obs_ids), **_provenance()}
    records = []
    if method in ("npe", "fmpe"):
        t0 = time.perf_counter()
        post, state = train_posterior(task, method, budget, cfg, key, obs.x(1))
        run.update(train_s=time.perf_counter() - t0, rounds=_rounds(state), invalid=int(state.num_invalid))
        print(f"  {task_name} {method} {budget}: trained in {run['train_s']:.1f} s", flush=True)
    for i in obs_ids:
        x_o, rec = obs.x(i), {"obs_id": i}
        if method in SEQUENTIAL:
            release_compiled_programs()  # a long grid stays under the memory-map limit
            t0 = time.perf_counter()
            post, state = train_posterior(task, method, budget, cfg, key, x_o, i)
            rec.update(
                train_s=time.perf_counter() - t0, rounds=_rounds(state), invalid=int(state.num_invalid)
            )
        t0 = time.perf_counter()
        samples = np.asarray(post.sample(jax.random.fold_in(key, 1000 + i), num_samples, x=x_o))
        rec["sample_s"] = time.perf_counter() - t0
        t0 = time.perf_counter()
        rec["c2st"] = float(obs.score(jax.random.fold_in(key, 2000 + i), i, samples, num_samples))
        rec.update(c2st_s=time.perf_counter() - t0, commit=run["commit"], loadavg=list(os.getloadavg()))
        train = f" train {rec['train_s']:.1f} s," if "train_s" in rec else ""
        print(
            f"  {task_name} {method} {budget} obs {i}:{train} c2st={rec['c2st']:.3f} "
            f"(sampling {rec['sample_s']:.1f} s, c2st {rec['c2st_s']:.1f} s)",
            flush=True,
        )
        records.append(rec)
    run["loadavg_end"] = [round(v, 2) for v in os.getloadavg()]
    cell = {"task": task_name, "method": method, "budget": budget, "config": flat_config(cfg)}
    return summarise({**cell, "per_observation": records, "runs": [run]})


def summarise(cell):
    """Recompute the cell's summary fields from its per-observation records and runs."""
    recs = sorted(cell["per_observation"], key=lambda r: r["obs_id"])
    scores = [r["c2st"] for r in recs]
    runs = cell["runs"]
    if cell["method"] in SEQUENTIAL:
        device_of = {i: run["device"] for run in runs for i in run["obs_ids"]}  # a later run wins
        timed = [(device_of.get(r["obs_id"], "?"), r["train_s"]) for r in recs]
        invalid = sum(r.get("invalid", 0) for r in recs)
        rounds = [r["rounds"] for r in recs]
    else:  # amortised: one training per run (one run per NPE cell, see `merge`)
        timed = [(run["device"], run["train_s"]) for run in runs]
        invalid = sum(run.get("invalid", 0) for run in runs)
        rounds = [run["rounds"] for run in runs]
    times = [t for _, t in timed]
    # A cell may join pieces run on other devices (a GPU's observation trains several times
    # faster): the mean over all says little then, so each device's mean is kept as well.
    by_device = {d: float(np.mean([t for e, t in timed if e == d])) for d in sorted({d for d, _ in timed})}
    return {
        **cell,
        "per_observation": recs,
        "c2st_mean": float(np.mean(scores)),
        "c2st_sd": float(np.std(scores, ddof=1)) if len(scores) > 1 else 0.0,
        "n_obs": len(scores),
        "obs_ids": [r["obs_id"] for r in recs],
        "train_s": float(np.mean(times)),
        "train_s_by_device": by_device,
        "c2st": scores,
        "num_invalid_simulations": int(invalid),
        "published": PUBLISHED[(cell["task"], cell["method"])][BUDGETS.index(cell["budget"])],
        "rounds": rounds,
        "commit": sorted({run["commit"] for run in runs if run.get("commit")}),
        "device": sorted({run["device"] for run in runs}),
        "loadavg": [[run["loadavg"][0], run["loadavg_end"][0]] for run in runs],  # 1-min, start/end
    }


def same_config(stored, config):
    """Whether a stored cell's (flat) config is ``config``: a field added after the cell ran
    counts as equal when ``config`` keeps its default, and a field removed since (`RETIRED`)
    when the cell ran it at the value that made it a no-op (the estimator is then unchanged)."""
    defaults = flat_config(NPEConfig())
    stored = {k: v for k, v in stored.items() if not (k in RETIRED and v == RETIRED[k])}
    return all(stored.get(k, defaults[k]) == v for k, v in config.items()) and set(stored) <= set(config)


def merge(old, new):
    """``new`` merged into ``old`` (same task, method, budget): APT observations are independent
    runs, so pieces run at other observations with the same config join the cell (``new``
    replaces observations present in both). NPE is one amortised network per cell, and a
    config change means another estimator: then ``new`` replaces ``old`` whole."""
    if old is None or "per_observation" not in old:
        return new
    if new["method"] not in SEQUENTIAL or not same_config(old["config"], new["config"]):
        return new
    ids = set(new["obs_ids"])
    recs = [r for r in old["per_observation"] if r["obs_id"] not in ids] + new["per_observation"]
    return summarise({**new, "per_observation": recs, "runs": old["runs"] + new["runs"]})


def todo(old, method, config, obs_ids):
    """Observations of ``obs_ids`` still to run, given the stored cell ``old`` (resume)."""
    if old is None or "per_observation" not in old or not same_config(old["config"], config):
        return list(obs_ids)
    missing = [i for i in obs_ids if i not in old["obs_ids"]]
    return missing if (method in SEQUENTIAL or not missing) else list(obs_ids)


def table(results) -> str:
    by = {(r["task"], r["method"], r["budget"]): r for r in results}
    stale = _stale(results)
    methods = ["npe", "apt"] + sorted({r["method"] for r in results} - {"npe", "apt"})
    head = "| task | method | " + " | ".join(f"{b:.0e}" for b in BUDGETS) + " |"
    lines = [head, "|---|---|" + "---|" * len(BUDGETS)]
    for t in TASKS:
        for m in methods:
            cells = []
            for j, b in enumerate(BUDGETS):
                pub = PUBLISHED.get((t, m), (None,) * len(BUDGETS))[j]
                ref = "" if pub is None else f" (sbibm {pub:.3f})"
                r = by.get((t, m, b))
                if r is None:
                    cells.append(f"not run{ref}")
                else:
                    mark = "" if pub is None else (" ✓" if r["c2st_mean"] <= pub else " ✗")
                    dagger = " †" if _key(r) in stale else ""
                    cells.append(
                        f"{r['c2st_mean']:.3f}±{r['c2st_sd']:.3f} n={r['n_obs']}{ref}{mark}{dagger} "
                        f"[{_times(r)}]"
                    )
            lines.append(f"| {t} | {m} | " + " | ".join(cells) + " |")
    if stale:
        lines.append(
            "\n† run with other settings than `config_for` gives now (the cell's `config` says which)."
        )
    return "\n".join(lines)


def _times(cell) -> str:
    """The cell's training seconds: ``"346s"``, or per device where pieces ran on several."""
    by_device = cell.get("train_s_by_device", {})
    if len(by_device) < 2:
        return f"{cell['train_s']:.0f}s"
    return ", ".join(f"{t:.0f}s {d.split(':')[0]}" for d, t in by_device.items())


def _stale(results) -> set:
    """Keys of the cells run with other settings than `config_for` gives now (the † cells)."""
    return {_key(r) for r in results if not current(r)}


def current(cell) -> bool:
    """Whether a stored cell ran with the settings `config_for` gives its method and budget now."""
    return same_config(cell["config"], flat_config(config_for(cell["budget"], cell["method"])))


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--quick", action="store_true")
    ap.add_argument("--tasks", nargs="+", default=list(TASKS))
    ap.add_argument("--methods", nargs="+", default=["npe", "apt"])
    ap.add_argument("--budgets", nargs="+", type=int, default=list(BUDGETS))
    ap.add_argument("--n-obs", type=int, default=10)
    ap.add_argument("--first-obs", type=int, default=1, help="observations first..first+n_obs-1")
    ap.add_argument("--observations", choices=["sbibm", "ours"], default="sbibm")
    ap.add_argument("--num-samples", type=int, default=10_000)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument(
        "--patience-unit",
        choices=["epochs", "new_data"],
        help="SequentialSettings.patience_unit (default: its default)",
    )
    ap.add_argument(
        "--set",
        nargs="+",
        default=[],
        metavar="FIELD=VALUE",
        help="other config fields (`flat_config`'s names), e.g. --set num_atoms=5 (use another --out for variants)",
    )
    ap.add_argument("--force", action="store_true", help="rerun and replace stored cells (else resume)")
    ap.add_argument(
        "--redo",
        action="store_true",
        help="sequential cells: rerun the requested observations even where stored, replacing them "
        "(after a change that alters only some observations; the rest of the cell stays)",
    )
    ap.add_argument("--c2st-jobs", type=int, default=1, help="parallel C2ST folds (same result as 1)")
    ap.add_argument(
        "--table", action="store_true", help="only rewrite the .md table and the .png figure from the JSON"
    )
    ap.add_argument("--out", default=os.path.join(HERE, "results", "sbi_tasks.json"))
    ap.add_argument(
        "--merge-from",
        metavar="JSON",
        help="only join to --out the cells of another results file that ran with the current settings",
    )
    args = ap.parse_args()
    overrides = {} if args.patience_unit is None else {"patience_unit": args.patience_unit}
    overrides.update(_parse_overrides(args.set))
    if args.quick:
        args.tasks, args.budgets, args.n_obs = ["two_moons"], [1_000], 2
    os.makedirs(os.path.dirname(args.out), exist_ok=True)
    if args.table:
        return _write_md(args.out, _load(args.out))
    if _source(args.out) not in (None, args.observations):  # never mix the two protocols
        raise SystemExit(f"{args.out} holds {_source(args.out)!r} observations; pass another --out")
    if args.merge_from:
        return _merge_from(args.merge_from, args.out, args.observations)
    obs_ids = list(range(args.first_obs, args.first_obs + args.n_obs))
    cells = [(b, m, t) for b in sorted(args.budgets) for m in args.methods for t in args.tasks]
    for b, m, t in cells:
        stored = None if args.force else {_key(r): r for r in _load(args.out)}.get((t, m, b))
        ids = todo(stored, m, flat_config(config_for(b, m, **overrides)), obs_ids)
        if args.redo and m in SEQUENTIAL:
            ids = list(obs_ids)
        if not ids:  # resume: finished observations are skipped
            continue
        print(f"cell {t} {m} {b} observations {ids}", flush=True)
        # A sequential cell is saved observation by observation (pieces, see `merge`): an
        # interrupted 10⁴ cell (5-40 min here) resumes at its first missing observation.
        pieces = [[i] for i in ids] if m in SEQUENTIAL else [ids]
        for j, piece in enumerate(pieces):
            cell = run_cell(
                t, m, b, piece, args.num_samples, args.seed, args.observations, overrides, args.c2st_jobs
            )
            results = _save(args.out, cell, args.observations, replace=args.force and j == 0)
        print(table(results), flush=True)


def _merge_from(src, out, source):
    """The cells of ``src`` (e.g. a variant whose settings became `config_for`'s) joined to
    ``out`` by `merge`, as if run there; a cell with other settings is skipped, and said so."""
    if _source(src) != source:  # never mix the two protocols (``out`` is checked by `main`)
        raise SystemExit(f"{src} holds {_source(src)!r} observations, not {source!r}")
    for cell in _load(src):
        if not current(cell):
            print(f"skipped {' '.join(map(str, _key(cell)))}: other settings than config_for's")
            continue
        _save(out, cell, source)
        print(f"joined {' '.join(map(str, _key(cell)))} observations {cell['obs_ids']}")
    print(table(_load(out)))


def _parse_overrides(items):
    """``["num_atoms=5", ...]`` -> ``{"num_atoms": 5}``, each value typed as its field's default."""
    defaults = flat_config(NPEConfig())
    out = {}
    for item in items:
        name, sep, value = item.partition("=")
        if not sep or name not in defaults:
            raise SystemExit(f"--set wants FIELD=VALUE with a config field (`flat_config`), got {item!r}")
        kind = type(defaults[name])
        out[name] = value if defaults[name] is None else (value == "True" if kind is bool else kind(value))
    return out


def _key(r):
    return (r["task"], r["method"], r["budget"])


def _source(path):
    if not os.path.exists(path):
        return None
    with open(path) as f:
        return json.load(f).get("observations", "ours")


def _load(path):
    if not os.path.exists(path):
        return []
    with open(path) as f:
        return json.load(f).get("results", [])


def _write_md(path, results):
    """The table (``.md``) and the figure (``.png``) of ``results`` beside ``path``."""
    stem = os.path.splitext(path)[0]
    with open(stem + ".md.tmp", "w") as f:
        f.write("# sbibm tasks: C2ST (mean±sd over n observations) [training wall time]\n\n")
        f.write(table(results) + "\n")
    os.replace(stem + ".md.tmp", stem + ".md")
    plot_grid(stem + ".tmp.png", results, PUBLISHED, BUDGETS, TASKS, _stale(results))
    os.replace(stem + ".tmp.png", stem + ".png")


def _save(path, result, source, replace=False):
    """Merge one finished cell (or piece of a cell, see `merge`) into the JSON under a lock, so
    several workers (each given other --tasks/--budgets/--first-obs) can fill the same grid
    without losing cells; ``replace``: the stored cell is dropped instead."""
    with open(path + ".lock", "w") as lock:
        fcntl.flock(lock, fcntl.LOCK_EX)
        stored = {_key(r): r for r in _load(path)}
        stored[_key(result)] = result if replace else merge(stored.get(_key(result)), result)
        methods = ["npe", "apt"] + sorted({m for _, m, _ in stored} - {"npe", "apt"})
        order = {
            (t, m, b): i
            for i, (b, m, t) in enumerate((b, m, t) for b in BUDGETS for m in methods for t in TASKS)
        }
        results = sorted(stored.values(), key=lambda r: order.get(_key(r), len(order)))
        # The cells' own devices, not this process's: a merge may join cells run elsewhere.
        meta = {
            "device": ", ".join(sorted({run["device"] for r in results for run in r["runs"]})),
            "config": {str(b): flat_config(config_for(b)) for b in BUDGETS},
            "protocol": __doc__,
        }
        with open(path + ".tmp", "w") as f:
            json.dump({"results": results, "observations": source, "meta": meta}, f, indent=1)
        os.replace(path + ".tmp", path)
        _write_md(path, results)
    return results


if __name__ == "__main__":
    main()
