"""`identify`: the vehicle's parameters with their posterior from one drive (or several of one car),
checkpointed per round."""

from __future__ import annotations

import contextlib
import dataclasses
import json
import os
from collections.abc import Callable
from pathlib import Path
from typing import TYPE_CHECKING, Any, NamedTuple

import numpy as np

if TYPE_CHECKING:
    pass

from ..estimation import FitRequest, ModelError, fit_likelihood, screened_sample
from ..io import InputError, SimulationError
from ..problem import (
    Box,
    Problem,
    ProblemSettings,
    concat_problems,
    default_effects,
    grip_used,
    longitudinal_mode,
    make_problem,
    measured_steer_lag,
    parameter_names,
    prior_box,
    steer_lag_index,
)
from ..problem.validation import predictive_band
from ..simulator.models import SpeedDriven, model_class
from ._extrapolation import held_out_extrapolation
from ._identify_report import npe_check, ppc_summary, run_summary, run_warnings, validation_report
from ._identify_result import IdentifyResult
from ._options import Budget, DriveOptions, IdentifyOptions, ModelOptions, Progress
from ._progress import Bars
from .outputs import (
    CHECKPOINT,
    RUN_FILE,
    checkpoint_dir,
    write_outputs,
    write_text_atomically,
)


def identify(
    recording,
    vehicle,
    options: IdentifyOptions = IdentifyOptions(),
    *,
    out_dir: str | os.PathLike | None = None,
    resume: bool = False,
    progress: Progress | None = None,
    names: tuple[Any, Any, Any] | None = None,
) -> IdentifyResult:
    """The vehicle's parameters (and enabled effects') from one drive or several of one car.

    Stages: read the drives; make the validation problem (the last `holdout` of the usable
    driving held out) and the full one (all of it); choose the effects and the prior box; train
    the neural posterior (APT) on the validation problem's training part; fit the likelihood
    posterior there from its draws (`vdsbi.estimation.fit_likelihood`: best fit through the
    simulator, model error in the noise model, Laplace) and score it on the held-out part with
    its predictive band; refit on all the driving from that fit: the exported estimate and the
    reported posterior; check the neural posterior against the likelihood one; flag what the
    drive cannot inform and report what it does determine; write the files.

    Args:
        recording: path (.csv, .parquet, bag), a `vdsbi.io.Recording`, or a sequence of them
            (recordings of one car, identified jointly, each window from its own state).
        vehicle: path (.json/.yaml) or a `vdsbi.simulator.Vehicle`.
        options: the drive's problem, the model, the estimators' budget, the seed.
        out_dir: write posterior.json, samples.csv, plots, report.html, estimator.npz and the
            per-round checkpoint here (None: write nothing).
        resume: continue from `out_dir`'s checkpoint (must have been made with the same options).
        progress: where messages, bars and round hooks go (None: nowhere).
        names: (recording, vehicle, out_dir) as the user knows them, for the commands printed.

    Raises:
        InputError: bad recording, vehicle, options, a non-empty `out_dir` without `resume`, or
            a drive on which almost every simulation fails.
    """
    import jax

    progress = progress or Progress(say=lambda s: None)
    say, drive, model, budget = progress.say, options.drive, options.model, options.budget
    recs, veh = _load(recording, vehicle, drive.rate)
    settings = _settings(budget)
    prob = _problem(recs, veh, drive, drive.holdout)
    full = prob if drive.holdout == 0 else _problem(recs, veh, drive, 0.0)
    effects = _effects(prob, model, say)
    box = _box(veh, effects, model.priors, grip_used(full))
    run_info = _run_info(recs, prob, settings, options.seed, effects, box)
    _describe(prob, full, say)
    k_id, k_val, k_post, k_band = jax.random.split(jax.random.key(int(options.seed)), 4)
    working = contextlib.nullcontext() if out_dir is None else checkpoint_dir(out_dir, resume=resume)
    with working as out:
        state = None if out is None else _start(out, run_info, resume, say)
        estimator, npe_samples, state = _train(k_id, prob, box, effects, settings, state, out, progress)
        starts = _starts(npe_samples, box, measured_steer_lag(recs[0], veh))
        checked, fit = _fit_likelihood(prob, full, starts, box, effects, say)
        prob, full = checked.with_fitted_starts(prob), fit.with_fitted_starts(full)
        setup = _Setup(veh, run_info, box, effects, names or (recording, vehicle, out_dir))
        fitted = _Fitted(prob, full, checked, fit, estimator, npe_samples, state)
        result = _result((k_val, k_post, k_band), setup, fitted, options, out)
        if out is not None:
            write_outputs(out, result, prob, result.ppc)
    return result


def _fit_likelihood(prob: Problem, full: Problem, starts, box: Box, effects, say):
    """The likelihood posterior on the validation problem's training part (`checked`), then
    refit from it on all the usable driving (`fit`: the estimate and the posterior reported);
    one fit when nothing is held out."""
    say("fitting the likelihood posterior on the training part (best fit, model-error noise, Laplace)")
    checked = fit_likelihood(prob, starts, box, effects=effects)
    if not np.isfinite(checked.chi2_dof):
        raise InputError(
            prob.source,
            "windows",
            "no start of the likelihood fit simulates this drive; check the time base, units of "
            "the torques and that the car keeps rolling",
        )
    if full is prob:
        return checked, checked
    say("refitting on all the usable driving: the estimate and the posterior reported")
    start = np.concatenate([checked.theta[None], starts])
    return checked, fit_likelihood(
        full, start, box, FitRequest(noise=ModelError(start=checked.noise)), effects=effects
    )


class _Setup(NamedTuple):
    """What a run was set up with: the car, run.json's record, the prior box, the effects, and
    the paths as the user knows them (for the commands printed)."""

    vehicle: Any
    run_info: dict
    box: Box
    effects: tuple[str, ...]
    names: tuple


class _Fitted(NamedTuple):
    """What a run fitted: the validation and the whole problem (start speeds corrected), the
    likelihood posterior on the training part and on all of it, the neural posterior, its draws
    and its training state."""

    prob: Problem
    full: Problem
    checked: Any
    fit: Any
    estimator: Any
    npe_samples: np.ndarray
    state: Any


def _result(keys, setup: _Setup, fitted: _Fitted, options: IdentifyOptions, out) -> IdentifyResult:
    """The reported posterior's samples and summary, the neural posterior's check, the
    validation on the held-out part with its predictive band, the warnings and the exported
    predictive draws."""
    import jax

    vehicle, run_info, box, effects, names = setup
    prob, full, checked, fit, estimator, npe_samples, state = fitted
    num_samples, ppc_draws = options.budget.num_samples, options.budget.ppc_draws
    compare, longitudinal = options.compare, options.drive.longitudinal
    k_val, k_post, k_band = keys
    samples = np.asarray(fit.sample(k_post, num_samples), float)
    summary = run_summary(full, samples, fit, state, run_info, box, effects, vehicle)
    summary["vehicle"] = vehicle.to_dict()  # the constants `vdsbi export` needs beside θ
    summary["npe_check"] = npe_check(npe_samples, checked)
    summary["validation"] = validation_report(prob, checked, npe_samples, effects, compare)
    draws, _ = screened_sample(k_val, checked, prob, ppc_draws, effects, information_only=True)
    band = predictive_band(k_band, prob, draws, checked.noise.scale, effects)
    band = held_out_extrapolation(summary, k_band, prob, full, band, draws, checked.noise.scale, effects)
    summary["ppc"] = ppc_summary(prob, band)
    summary["warnings"] = run_warnings(samples, summary, box, names, longitudinal)
    # Its own key: the exported draws are not the validation band's draws of another fit.
    k_pred = jax.random.fold_in(k_val, 1)
    predictive, kept = screened_sample(k_pred, fit, full, ppc_draws, effects, information_only=True)
    summary["likelihood_screen"] = {"kept_share": round(kept, 4)}
    return IdentifyResult(estimator, samples, summary, out, full, band, prob, predictive)


def _load(recording, vehicle, rate: float):
    """([Recording, …], Vehicle) from paths or objects, cross-checked when both are files."""
    from ..io import load_drive, read_recording, read_vehicle

    many = recording if isinstance(recording, (list, tuple)) else [recording]
    if not many:
        raise InputError("settings", "REC", "no recording given")
    veh = read_vehicle(vehicle) if isinstance(vehicle, (str, os.PathLike)) else vehicle
    recs = []
    for r in many:
        if isinstance(r, (str, os.PathLike)) and isinstance(vehicle, (str, os.PathLike)):
            recs.append(load_drive(r, vehicle, rate=rate)[0])
        else:
            recs.append(read_recording(r, rate=rate) if isinstance(r, (str, os.PathLike)) else r)
    return recs, veh


def _settings(budget: Budget):
    """The neural estimator's `IdentifySettings` (which checks them), `budget.epochs` its epoch
    limit."""
    from ..inference import IdentifySettings, StatisticsMLP

    embedding = StatisticsMLP() if budget.embedding is None else budget.embedding
    cfg = IdentifySettings(embedding=embedding).config  # the embedding's own training default
    if budget.epochs is not None:
        cfg = dataclasses.replace(
            cfg, training=dataclasses.replace(cfg.training, max_epochs=int(budget.epochs))
        )
    return IdentifySettings(
        rounds=int(budget.rounds),
        sims_per_round=int(budget.sims),
        embedding=embedding,
        num_samples=int(budget.num_samples),
        config=cfg,
    )


def _problem(recs, veh, drive: DriveOptions, holdout: float) -> Problem:
    """The drives as one `Problem`: 20-s windows with torques, 10-s windows following the speed."""
    if drive.max_duration is not None and drive.max_duration <= 0:
        raise InputError("settings", "--max-duration", "must be > 0")
    if not 0.0 <= holdout < 1.0:
        raise InputError("settings", "--holdout", f"must lie in [0, 1), got {holdout}")
    speed = issubclass(model_class(longitudinal_mode(recs[0], drive.longitudinal)), SpeedDriven)
    window = drive.max_duration if drive.max_duration is not None else (10.0 if speed else 20.0)
    settings = ProblemSettings(
        longitudinal=drive.longitudinal,
        max_window=window,
        segment=drive.segment,
        bandwidth=drive.bandwidth,
        held_out=holdout,
    )
    return concat_problems([make_problem(r, veh, settings) for r in recs])


def _effects(prob: Problem, model: ModelOptions, say) -> tuple[str, ...]:
    """The user's effects, else `default_effects` (each said with its reason), then `add_effects`,
    in the registry's order."""
    from ..simulator.effects import EFFECTS

    effects, add_effects = model.effects, model.add_effects
    unknown = [e for e in (*(effects or ()), *add_effects) if e not in EFFECTS]
    if unknown:
        known = ", ".join(EFFECTS)
        raise InputError("settings", "--effects", f"unknown effect {unknown[0]!r}; known: {known}")
    if effects is None:
        chosen = default_effects(prob)
        for name, why in chosen:
            say(f"{why}: {name} joins θ")
        effects = [name for name, _ in chosen]
    for name in add_effects:
        if name not in effects:
            say(f"{name} joins θ (asked for)")
    wanted = {*effects, *add_effects}
    return tuple(e for e in EFFECTS if e in wanted)


def _box(veh, effects, priors, grip: float | None) -> Box:
    try:
        bounds = prior_box(veh, effects, priors, grip)
    except ValueError as err:
        raise InputError("settings", "--prior", str(err)) from None
    return Box.from_dict(bounds, parameter_names(effects))


def _run_info(recs, prob: Problem, settings, seed: int, effects, box: Box) -> dict[str, Any]:
    """What run.json records: a checkpoint resumes only a run with the same."""
    from ..inference import as_record

    return {
        "recording": " + ".join(str(r.source) for r in recs),
        "seed": int(seed),
        "settings": json.loads(json.dumps(as_record(settings), default=str)),
        "longitudinal": prob.longitudinal,
        "windows": [[w.t0, w.t1, w.role] for w in prob.windows],
        "channels": list(prob.channels),
        "effects": list(effects),
        "prior": {n: [float(a), float(b)] for n, a, b in zip(box.names, box.low, box.high)},
        "rate_hz": recs[0].rate,
    }


def _describe(prob: Problem, full: Problem, say: Callable[[str], None]) -> None:
    info = prob.summary()
    say(f"{prob.longitudinal}-driven; {info['how']}; channels {', '.join(prob.channels)}")
    say(
        f"validated: fitted {info['train_seconds']:.1f} s, held out {info['held_out_seconds']:.1f} s; "
        f"estimate: fitted on all {full.summary()['train_seconds']:.1f} s"
    )
    share = full.description.get("lateral_information_share")  # a list over several recordings
    shares = [s for s in (share if isinstance(share, list) else [share]) if s is not None]
    if shares:
        text = " / ".join(f"{s:.0%}" for s in shares)
        say(f"the windows carry {text} of the drive's lateral information (Σ a_lat²)")
    for w in prob.warnings:
        say(f"warning: {w}")


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


def _train(key, prob: Problem, box: Box, effects, settings, state, out, progress: Progress):
    """`vdsbi.inference.identify_problem` with progress bars, per-round checkpoints and messages."""
    from ..inference import BoxPrior, Execution, identify_problem, save_state

    bars, say = Bars(settings.rounds, progress.bars), progress.say

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
        if progress.on_round_end is not None:
            progress.on_round_end(st)

    prior = BoxPrior(np.asarray(box.low), np.asarray(box.high), names=box.names)
    try:
        execution = Execution(
            on_round_end=round_end, on_epoch_end=bars.epoch, on_simulate=bars.simulate, state=state
        )
        return identify_problem(key, prob, prior, settings, effects=effects, execution=execution)
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


#: Neural-posterior draws tried, beside its mean and the prior centre, as the fit's start.
STARTS = 31


def _starts(npe_samples: np.ndarray, box: Box, lag: float | None = None) -> np.ndarray:
    """Candidate starts of the likelihood fit: the neural posterior's mean and draws (its global
    view of where the data put θ) and the prior centre; with a measured steer-to-response `lag`,
    also the mean with its lag parameters at that lag and at half of it (the measured one holds
    the tyres' and the body's own lag too): evidence the fit may use, kept only if it fits best."""
    centre = np.asarray(box.low + 0.5 * box.width)
    mean = npe_samples.mean(0)
    out = [mean[None], centre[None], npe_samples[:STARTS]]
    lags = steer_lag_index(box.names)
    if lag is not None and lag > 0 and lags.size:
        lo, hi = np.asarray(box.low), np.asarray(box.high)
        for share in (0.5, 1.0):
            start = mean.copy()
            start[lags] = np.clip(
                share * lag, lo[lags] + 0.01 * (hi - lo)[lags], hi[lags] - 0.01 * (hi - lo)[lags]
            )
            out.append(start[None])
    return np.concatenate(out)
