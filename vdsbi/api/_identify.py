"""`identify`: a posterior over θ from one recording, checkpointed per round; `sample` from the
estimator it saved."""

from __future__ import annotations

import contextlib
import dataclasses
import json
import os
from collections.abc import Callable, Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from .. import __version__
from ..io import InputError, SimulationError
from ..problem import (
    Problem,
    ProblemSettings,
    grip_used,
    longitudinal_mode,
    make_problem,
    parameter_names,
    parameter_units,
    prior_box,
    simulate_draws,
    split_parameters,
    validate,
    windowed_model,
)
from ..simulator import release_compiled_programs
from ._commands import diagnose_command
from .outputs import (
    CHECKPOINT,
    ESTIMATOR,
    RUN_FILE,
    checkpoint_dir,
    summarise,
    write_outputs,
    write_text_atomically,
)
from ._progress import Progress
from ._trust import trust_warnings


@dataclasses.dataclass
class IdentifyResult:
    """What `identify` found.

    Attributes:
        posterior: the trained `vdsbi.inference.Posterior` at the recording.
        samples: (num_samples, 6) posterior draws, PARAM_NAMES order.
        summary: the content of posterior.json (parameters, channels, segment, noise, settings).
        out_dir: where the files were written, or None.
        problem: the drive's `vdsbi.problem.Problem` (windows, channels, held-out masks).
        ppc: the posterior-predictive 5/50/95 % bands on `problem`'s windows.
    """

    posterior: Any
    samples: np.ndarray
    summary: dict[str, Any]
    out_dir: Path | None = None
    problem: Any = None
    ppc: dict[str, Any] | None = None

    def table(self) -> str:
        """Per-parameter mean, std and 5/50/95 % quantiles as aligned text; a parameter the drive
        cannot inform is printed as "not identified" with its prior range, never as an estimate;
        then one line per warning (posterior not to be trusted)."""
        width = max(10, *(len(n) for n in self.summary["parameters"]))
        refined = self.summary.get("refined", {}).get("values", {})
        rows = [
            f"{'param':<{width}} {'mean':>11} {'std':>10} {'q05':>11} {'q50':>11} {'q95':>11}"
            + (f" {'refined':>11}" if refined else "")
        ]
        for name, p in self.summary["parameters"].items():
            if p.get("identified") is False:
                lo, hi = p["prior"]
                rows.append(f"{name:<{width}} not identified by this drive (prior {lo:.4g} .. {hi:.4g})")
                continue
            rows.append(
                f"{name:<{width}} {p['mean']:>11.4g} {p['std']:>10.3g} "
                f"{p['q05']:>11.4g} {p['q50']:>11.4g} {p['q95']:>11.4g}"
                + (f" {refined[name]:>11.4g}" if name in refined else "")
            )
        rows += [f"WARNING: {w['message']}" for w in self.summary.get("warnings", ())]
        return "\n".join(rows)

    def to_json(self) -> str:
        return json.dumps(self.summary, indent=2)


def identify(
    recording,
    vehicle,
    *,
    rounds: int = 2,
    sims: int = 1000,
    embedding: str = "stats",
    seed: int = 0,
    out_dir: str | os.PathLike | None = None,
    resume: bool = False,
    epochs: int | None = None,
    num_samples: int = 1000,
    segment: tuple[float, float] | None = None,
    max_duration: float | None = None,
    longitudinal: str = "auto",
    bandwidth: float | str | None = "auto",
    effects: Sequence[str] | None = None,
    compare: Mapping[str, Any] | None = None,
    refine: bool = True,
    ppc_draws: int = 100,
    progress: bool = False,
    rate: float = 200.0,
    on_round_end: Callable | None = None,
    log: Callable[[str], None] | None = None,
    names: tuple[Any, Any, Any] | None = None,
) -> IdentifyResult:
    """Posterior over θ (and enabled effects' parameters) from a whole drive.

    Stages: read the drive; make its problem (windows over every usable stretch, the last 30 %
    held out); choose the effects; train APT on the training windows; summarise; flag the
    parameters the drive cannot inform (Fisher information); refine the point estimate by least
    squares; validate both on the held-out driving;
    posterior predictive check; write the files.

    Args:
        recording: path (.csv, .parquet, bag) or a `vdsbi.io.Recording`.
        vehicle: path (.json/.yaml) or a `vdsbi.simulator.Vehicle`.
        rounds, sims: APT rounds and simulations per round.
        embedding: "stats" or "cnn".
        seed: the only source of randomness; same seed, same machine → identical samples.
        out_dir: write posterior.json, samples.csv, pairplot.png, ppc.png, estimator.npz and the
            per-round checkpoint here (None: write nothing).
        resume: continue from `out_dir`'s checkpoint (must have been made with the same settings).
        epochs: maximum training epochs per round (default: IdentifySettings' 40).
        num_samples: posterior samples kept.
        segment: (t0, t1) s to restrict the drive to (default: all of it).
        max_duration: longest window, s (default 20 in torque mode, 10 in speed mode).
        longitudinal: "torque", "speed" (follow the measured speed; for logs without torques
            or with commanded ones) or "auto" (torque when the recording has torques).
        bandwidth: low-pass cutoff, Hz, shared by measured and simulated channels ("auto": none
            with torques, 5 Hz following the speed; None: none).
        effects: effects whose parameters join θ; None adds `tyre_friction` when the drive
            uses more than half the grip (Dugoff leaves its linear range there) and
            `yaw_inertia` in speed mode with a measured yaw rate.
        compare: reference values {param: value} (e.g. a lab's) scored on the held-out part
            beside the posterior mean.
        refine: refine the posterior mean by least squares on the whole training drive
            (`vdsbi.diagnostics.refine`): the `refined` point estimate, validated beside it.
        ppc_draws: posterior draws simulated for the predictive check.
        progress: tqdm bars.
        on_round_end: extra hook called with the APT state after each round's checkpoint.
        log: where one-line messages go (default: nowhere).
        names: (recording, vehicle, out_dir) as the user knows them, for the files and the
            commands the result names (default: the arguments as given).

    Raises:
        InputError: bad recording, vehicle, settings, a non-empty `out_dir` without `resume`, or
            a drive on which almost every simulation fails.
    """
    import jax

    say = log or (lambda s: None)
    release_compiled_programs()  # a process that identifies drive after drive stays under the limit
    rec, veh = _load(recording, vehicle, rate)
    settings = _settings(rounds, sims, embedding, epochs, num_samples)
    prob = _problem(rec, veh, longitudinal, segment, max_duration, bandwidth)
    effects = _effects(prob, effects, say)
    box = prior_box(veh, effects)
    run_info = _run_info(rec, prob, settings, seed, effects)
    _describe(prob, say)
    k_id, k_ppc = jax.random.split(jax.random.key(int(seed)))
    working = contextlib.nullcontext() if out_dir is None else checkpoint_dir(out_dir, resume=resume)
    with working as out:
        state = None if out is None else _start(out, run_info, resume, say)
        posterior, samples, state = _train(
            k_id, prob, box, effects, settings, state, out, progress, on_round_end, say
        )
        summary = _summary(prob, samples, state, run_info, box, effects)
        summary["vehicle"] = veh.to_dict()  # the constants `vdsbi export` needs beside θ
        if refine:
            summary["refined"] = _refined(prob, summary, samples, box, effects, say)
        summary["validation"] = _validation(prob, summary, effects, compare)
        ppc = posterior_predictive(k_ppc, prob, samples, effects, ppc_draws)
        summary["ppc"] = _ppc_summary(prob, ppc)
        summary["warnings"] = _warnings(
            samples, summary, box, names or (recording, vehicle, out_dir), longitudinal
        )
        result = IdentifyResult(posterior, samples, summary, out, prob, ppc)
        if out is not None:
            write_outputs(out, result, prob, ppc)
    return result


def _load(recording, vehicle, rate: float):
    """(Recording, Vehicle) from paths or objects, cross-checked when both are files."""
    from ..io import load_drive, read_recording, read_vehicle

    if isinstance(recording, (str, os.PathLike)) and isinstance(vehicle, (str, os.PathLike)):
        return load_drive(recording, vehicle, rate=rate)
    rec = read_recording(recording, rate=rate) if isinstance(recording, (str, os.PathLike)) else recording
    veh = read_vehicle(vehicle) if isinstance(vehicle, (str, os.PathLike)) else vehicle
    return rec, veh


def _settings(rounds, sims, embedding, epochs, num_samples):
    """`IdentifySettings` (which checks them) with `epochs` as the training's epoch limit."""
    from ..inference import IdentifySettings

    base = IdentifySettings(embedding=embedding)  # the embedding's own training default
    cfg = base.config if epochs is None else dataclasses.replace(base.config, max_epochs=int(epochs))
    return IdentifySettings(
        rounds=int(rounds),
        sims_per_round=int(sims),
        embedding=embedding,
        num_samples=int(num_samples),
        config=cfg,
    )


def _problem(rec, veh, longitudinal: str, segment, max_duration: float | None, bandwidth) -> Problem:
    """The drive as a `Problem`: 20-s windows with torques, 10-s windows following the speed."""
    if max_duration is not None and max_duration <= 0:
        raise InputError("settings", "--max-duration", "must be > 0")
    speed = longitudinal_mode(rec, longitudinal) == "speed"
    window = max_duration if max_duration is not None else (10.0 if speed else 20.0)
    settings = ProblemSettings(
        longitudinal=longitudinal, max_window=window, segment=segment, bandwidth=bandwidth
    )
    return make_problem(rec, veh, settings)


def _effects(prob: Problem, effects, say) -> tuple[str, ...]:
    """The user's effects; by default `tyre_friction` where the drive reaches past Dugoff's
    linear range, and `yaw_inertia` in speed mode with a measured yaw rate (a real drive)."""
    from ..simulator import EFFECTS

    if effects is not None:
        unknown = [e for e in effects if e not in EFFECTS]
        if unknown:
            raise InputError(
                "settings", "--effects", f"unknown effect {unknown[0]!r}; known: {', '.join(EFFECTS)}"
            )
        return tuple(effects)
    chosen = []
    used = grip_used(prob)
    if used is not None and used > 0.5:
        say(f"the drive uses {used:.0%} of the grip μ·g: friction joins θ (tyre_friction.scale)")
        chosen.append("tyre_friction")
    if prob.longitudinal == "speed" and "yaw_rate" in prob.channels:
        # A real car's I_z is not m·l_f·l_r; left at it, the fit bends l_f to match the yaw
        # transient (on vw_gti_high_speed_2: l_f 0.90 m without, 1.38 m with; lab 1.264 m).
        say("following the measured yaw rate: the yaw inertia joins θ (yaw_inertia.dynamic_index)")
        chosen.append("yaw_inertia")
    return tuple(chosen)


def _run_info(rec, prob: Problem, settings, seed: int, effects) -> dict[str, Any]:
    """What run.json records: a checkpoint resumes only a run with the same."""
    return {
        "recording": str(rec.source),
        "seed": int(seed),
        "settings": json.loads(json.dumps(dataclasses.asdict(settings), default=str)),
        "longitudinal": prob.longitudinal,
        "windows": [[w.t0, w.t1, w.role] for w in prob.windows],
        "channels": list(prob.channels),
        "effects": list(effects),
        "rate_hz": rec.rate,
    }


def _describe(prob: Problem, say: Callable[[str], None]) -> None:
    info = prob.summary()
    say(f"{prob.longitudinal}-driven; {info['how']}; channels {', '.join(prob.channels)}")
    say(f"fitted {info['train_seconds']:.1f} s, held out {info['held_out_seconds']:.1f} s")
    for w in prob.warnings:
        say(f"warning: {w}")
    estimated = any(s.startswith("estimated") for s in prob.noise_source.values())
    say(
        "noise std "
        + ", ".join(f"{c} {v:.3g}" for c, v in zip(prob.channels, prob.sigma))
        + (" (estimated" if estimated else " (vehicle file")
        + (", after the shared low-pass)" if prob.decimator is not None else ")")
    )


def _start(out: Path, run_info: dict, resume: bool, say: Callable[[str], None]):
    """The checkpointed state to resume from (None: start afresh); writes run.json."""
    from ..inference import load_state

    state = None
    if resume and (out / CHECKPOINT).exists():
        saved = json.loads((out / RUN_FILE).read_text())
        if saved != json.loads(json.dumps(run_info)):
            diff = [k for k in run_info if saved.get(k) != json.loads(json.dumps(run_info[k]))]
            raise InputError(out / RUN_FILE, ", ".join(diff), "differs from this run's; cannot resume")
        state = load_state(out / CHECKPOINT)
        say(f"resuming after round {state.round} of {run_info['settings']['rounds']}")
    write_text_atomically(out / RUN_FILE, json.dumps(run_info, indent=2) + "\n")
    return state


def _train(key, prob: Problem, box, effects, settings, state, out, progress, on_round_end, say):
    """`vdsbi.inference.identify_problem` with progress bars, per-round checkpoints and messages."""
    from ..inference import BoxPrior, identify_problem, save_state

    bars = Progress(settings.rounds, progress)

    def round_end(st):
        if out is not None:
            save_state(out / CHECKPOINT, st)
        bars.round_end(st)
        h = st.history[-1]
        say(
            f"round {st.round}/{settings.rounds}: {h.get('num_used')} simulations used, "
            f"{h.get('epochs', '?')} epochs, best val loss {h.get('best_val_loss', float('nan')):.4g}"
            + (" (checkpoint saved)" if out is not None else "")
        )
        if on_round_end is not None:
            on_round_end(st)

    names = parameter_names(effects)
    prior = BoxPrior([box[n][0] for n in names], [box[n][1] for n in names], names=names)
    try:
        return identify_problem(
            key,
            prob,
            prior,
            settings,
            effects=effects,
            on_round_end=round_end,
            on_epoch_end=bars.epoch,
            on_simulate=bars.simulate,
            state=state,
        )
    except SimulationError as err:
        # A property of this recording, not a bug: say so in one line.
        raise InputError(
            prob.source,
            "windows",
            f"almost every simulation of this drive failed ({err}); check the time base, "
            "units of the torques and that the car keeps rolling",
        ) from None
    finally:
        bars.close()


def _summary(prob: Problem, samples: np.ndarray, state, run_info: dict, box, effects) -> dict[str, Any]:
    """posterior.json without its validation and predictive check; parameters the drive cannot
    inform are flagged `identified: false` (their posterior is the prior, not an estimate)."""
    from ..diagnostics import identifiability

    names = parameter_names(effects)
    params = summarise(samples, box, names, parameter_units(effects))
    mean = np.array([params[n]["mean"] for n in names])
    theta, ep = split_parameters(mean, effects)
    info = identifiability(prob, np.asarray(theta), box, effects=effects, effect_params=ep)
    for n, v in info.items():
        params[n]["identified"] = v["identified"]
        params[n]["crb_std"] = v["posterior_std"]
        if not v["identified"]:
            params[n]["not_identified_because"] = v["reason"]
    return {
        "vdsbi_version": __version__,
        "recording": run_info["recording"],
        "parameters": params,
        "not_identified": [n for n in names if params[n].get("identified") is False],
        "effects": list(effects),
        "problem": prob.summary(),
        "channels": list(prob.channels),
        "seed": run_info["seed"],
        "settings": run_info["settings"],
        "rounds": [{k: v for k, v in h.items() if isinstance(v, (int, float, str))} for h in state.history],
    }


def _warnings(samples: np.ndarray, summary: dict, box, names, longitudinal: str) -> list[dict[str, Any]]:
    """posterior.json's `warnings`: mass piled at the prior's edges, or a predictive band that
    misses the recording, each pointing to `vdsbi diagnose`."""
    rec, veh, out = (n if isinstance(n, (str, os.PathLike)) else None for n in names)
    if rec is None:
        rec = summary["recording"]
    ppc = summary["ppc"]
    problem = [{"kind": "recording", "message": w} for w in summary["problem"].get("warnings", ())]
    return problem + trust_warnings(
        samples,
        list(summary["parameters"]),
        box,
        summary["not_identified"],
        {"train": ppc["fraction_inside_90pct_band"], "held_out": ppc["fraction_inside_90pct_band_held_out"]},
        diagnose_command(rec, veh, out, longitudinal),
    )


def _validation(prob: Problem, summary: dict, effects, compare) -> dict[str, Any]:
    """Held-out scores of the posterior mean, and of the user's reference values (the
    parameters a reference does not give are taken from the posterior mean)."""
    names = parameter_names(effects)
    mean = np.array([summary["parameters"][n]["mean"] for n in names])
    out = {"posterior_mean": _score(prob, mean, effects)}
    if "refined" in summary:
        refined = np.array([summary["refined"]["values"][n] for n in names])
        out["refined"] = _score(prob, refined, effects)
    if compare:
        unknown = [k for k in compare if k not in names]
        if unknown:
            raise InputError(
                "settings", "--compare", f"unknown parameter {unknown[0]!r}; known: {', '.join(names)}"
            )
        ref = np.array([float(compare.get(n, m)) for n, m in zip(names, mean)])
        out["reference"] = _score(prob, ref, effects) | {"given": {k: float(v) for k, v in compare.items()}}
    return out


#: Posterior draws tried, beside the mean, as the refinement's start.
REFINE_STARTS = 31


def _refined(prob: Problem, summary: dict, samples: np.ndarray, box, effects, say) -> dict[str, Any]:
    """The posterior mean refined by least squares over the training windows; parameters the
    drive does not inform stay at their posterior mean (= the prior's)."""
    from ..diagnostics import refine

    names = parameter_names(effects)
    mean = np.array([summary["parameters"][n]["mean"] for n in names])
    free = [n for n in names if n not in summary["not_identified"]]
    say(f"refining the point estimate by least squares over the training windows ({', '.join(free)})")
    # Candidates: the mean and posterior draws (fixed parameters at the mean); the best start.
    starts = np.concatenate([mean[None], samples[:REFINE_STARTS]])
    fixed = [i for i, n in enumerate(names) if n not in free]
    starts[:, fixed] = mean[fixed]
    ref = refine(prob, starts, box, effects=effects, free=free)
    return {
        "method": "least squares from the posterior mean, channel scales profiled (diagnostics.refine)",
        "values": {n: float(v) for n, v in zip(names, ref.theta)},
        "free": list(ref.free),
        "residual_rms": ref.scale,
        "converged": ref.converged,
    }


def _score(prob: Problem, values: np.ndarray, effects) -> dict[str, Any]:
    from ..simulator import get_effect

    theta, ep = split_parameters(values, effects)
    eff_values = {
        e: {p: float(v) for p, v in zip(get_effect(e).param_names, np.asarray(x))}
        for e, x in zip(effects, ep)
    }
    return validate(prob, np.asarray(theta), effects, eff_values)


def posterior_predictive(key, prob: Problem, samples: np.ndarray, effects, n: int) -> dict[str, Any]:
    """`n` posterior draws simulated with sensor noise on every window; 5/50/95 % bands."""
    import jax.numpy as jnp

    n = min(n, samples.shape[0])
    wm = windowed_model(prob, effects)
    theta, ep = split_parameters(jnp.asarray(samples[:n]), effects)
    ys, ok = simulate_draws(key, wm, theta, sigma_raw=prob.sigma_raw, effect_params=ep)
    ys = np.asarray(ys)[np.asarray(ok)]
    q = np.quantile(ys, [0.05, 0.5, 0.95], axis=0) if ys.shape[0] else np.full((3, *ys.shape[1:]), np.nan)
    return {"q05": q[0], "q50": q[1], "q95": q[2], "n": ys.shape[0]}


def _ppc_summary(prob: Problem, ppc: dict[str, Any]) -> dict[str, Any]:
    inside = (prob.y >= ppc["q05"]) & (prob.y <= ppc["q95"])
    frac = lambda mask: {
        c: (float(inside[..., i][mask].mean()) if ppc["n"] and mask.any() else None)
        for i, c in enumerate(prob.channels)
    }
    return {
        "draws": int(ppc["n"]),
        # None when no posterior draw simulated successfully (no band to compare with).
        "fraction_inside_90pct_band": frac(prob.train),
        "fraction_inside_90pct_band_held_out": frac(prob.held),
    }


def sample(run_dir: str | os.PathLike, n: int, *, seed: int = 0):
    """`n` draws from the estimator `identify` saved in `run_dir`, as a DataFrame (one column per
    parameter).

    Raises:
        InputError: no readable estimator in `run_dir`, or `n` < 1.
    """
    import jax
    import pandas as pd

    from ..inference import Posterior
    from ..simulator import PARAM_NAMES

    path = Path(run_dir) / ESTIMATOR
    if not path.is_file():
        raise InputError(path, "DIR", "no estimator here; run `vdsbi identify` first")
    if n < 1:
        raise InputError("settings", "--n", f"must be >= 1, got {n}")
    try:
        post = Posterior.load(path)
    except Exception as err:  # corrupt or foreign file
        raise InputError(path, "estimator", f"cannot be read ({type(err).__name__}: {err})") from None
    samples = np.asarray(post.sample(jax.random.key(seed), n))
    return pd.DataFrame(samples, columns=list(post.prior.names or PARAM_NAMES))
