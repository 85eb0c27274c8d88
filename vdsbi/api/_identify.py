"""`identify`: the vehicle's parameters with their posterior from one drive (or several of one car),
checkpointed per round; `sample` from the neural estimator it saved."""

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
from ..diagnostics import fit_likelihood
from ..io import InputError, SimulationError
from ..problem import (
    Box,
    Problem,
    ProblemSettings,
    band_coverage,
    concat_problems,
    grip_used,
    longitudinal_mode,
    make_problem,
    parameter_names,
    parameter_units,
    predictive_band,
    prior_box,
    split_parameters,
    validate,
)
from ..simulator import SpeedDriven, model_class, release_compiled_programs
from ._commands import diagnose_command
from ._progress import Progress
from ._trust import model_error_warning, trust_warnings
from .outputs import (
    CHECKPOINT,
    ESTIMATOR,
    RUN_FILE,
    checkpoint_dir,
    summarise,
    write_outputs,
    write_text_atomically,
)


@dataclasses.dataclass
class IdentifyResult:
    """What `identify` found.

    Attributes:
        posterior: the trained neural posterior (`vdsbi.inference.Posterior`), for `vdsbi sample`.
        samples: (num_samples, P) draws of the reported (likelihood) posterior, names order.
        summary: the content of posterior.json (parameters with their estimate, noise model,
            combinations, validation, predictive check, warnings).
        out_dir: where the files were written, or None.
        problem: the whole drive's `vdsbi.problem.Problem` (every usable window).
        ppc: the posterior-predictive 5/50/95 % band on `validation`'s windows.
        validation: the problem whose held-out part the band and the validation scores are on
            (`problem` itself when nothing is held out).
        predictive: (ppc_draws, P) parameter draws for predicting other driving at the estimate
            (`vdsbi.diagnostics.LikelihoodPosterior.predictive_draws`), what `predict --band` uses.
    """

    posterior: Any
    samples: np.ndarray
    summary: dict[str, Any]
    out_dir: Path | None = None
    problem: Any = None
    ppc: dict[str, Any] | None = None
    validation: Any = None
    predictive: np.ndarray | None = None

    def table(self) -> str:
        """Per parameter: the estimate (the best fit, what `export` writes), the posterior's std and
        5/50/95 % quantiles; a parameter the drive cannot inform is printed as "not identified"
        with its prior range; then the combinations the drive determines and the warnings."""
        width = max(10, *(len(n) for n in self.summary["parameters"]))
        rows = [f"{'param':<{width}} {'estimate':>11} {'std':>10} {'q05':>11} {'q50':>11} {'q95':>11}"]
        for name, p in self.summary["parameters"].items():
            if p.get("identified") is False:
                lo, hi = p["prior"]
                rows.append(f"{name:<{width}} not identified by this drive (prior {lo:.4g} .. {hi:.4g})")
                continue
            rows.append(
                f"{name:<{width}} {p['estimate']:>11.4g} {p['std']:>10.3g} "
                f"{p['q05']:>11.4g} {p['q50']:>11.4g} {p['q95']:>11.4g}"
            )
        for key, c in self.summary.get("combinations", {}).items():
            if key == "determined_directions":
                continue
            at = f" at {c['at']} m/s" if c.get("at") else ""
            told = "" if c.get("identified", True) else " (not identified: near its prior spread)"
            rows.append(
                f"{key.replace('_', ' ')}{at}: {c['median']:.4g} {c['unit']} "
                f"[95 %: {c['q025']:.4g} .. {c['q975']:.4g}]{told}"
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
    add_effects: Sequence[str] = (),
    priors: Mapping[str, tuple[float, float]] | None = None,
    holdout: float = 0.3,
    compare: Mapping[str, Any] | None = None,
    ppc_draws: int = 100,
    progress: bool = False,
    rate: float = 200.0,
    on_round_end: Callable | None = None,
    log: Callable[[str], None] | None = None,
    names: tuple[Any, Any, Any] | None = None,
) -> IdentifyResult:
    """The vehicle's parameters (and enabled effects') from one drive or several of one car.

    Stages: read the drives; make the validation problem (the last `holdout` of the usable
    driving held out) and the full one (all of it); choose the effects and the prior box; train
    the neural posterior (APT) on the validation problem's training part; fit the likelihood
    posterior there from its draws (`vdsbi.diagnostics.fit_likelihood`: best fit through the
    simulator, model error in the noise model, Laplace) and score it on the held-out part with
    its predictive band; refit on all the driving from that fit: the exported estimate and the
    reported posterior; check the neural posterior against the likelihood one; flag what the
    drive cannot inform and report what it does determine; write the files.

    Args:
        recording: path (.csv, .parquet, bag), a `vdsbi.io.Recording`, or a sequence of them
            (recordings of one car, identified jointly, each window from its own state).
        vehicle: path (.json/.yaml) or a `vdsbi.simulator.Vehicle`.
        rounds, sims: APT rounds and simulations per round.
        embedding: "stats" or "cnn".
        seed: the only source of randomness; same seed, same machine → identical samples.
        out_dir: write posterior.json, samples.csv, plots, report.html, estimator.npz and the
            per-round checkpoint here (None: write nothing).
        resume: continue from `out_dir`'s checkpoint (must have been made with the same settings).
        epochs: maximum training epochs per round.
        num_samples: posterior samples kept.
        segment: (t0, t1) s to restrict the drive to (default: all of it).
        max_duration: longest window, s (default 20 in torque mode, 10 in speed mode).
        longitudinal: "torque", "speed" (follow the measured speed) or "auto".
        bandwidth: low-pass cutoff, Hz, shared by measured and simulated channels.
        effects: effects whose parameters join θ; None: `default_effects`.
        add_effects: effects added to `effects` (or to the defaults): what a diagnosis named.
        priors: {name: (low, high)} replacing the prior box of any parameter (e.g. the ranges
            `vdsbi diagnose` measured for an effect's parameters).
        holdout: fraction of the usable driving held out to validate on (0: none; the estimate
            is always refit on all of it).
        compare: reference values {param: value} (e.g. a lab's) scored on the held-out part.
        ppc_draws: posterior draws simulated for the predictive band.
        progress: tqdm bars.
        on_round_end: extra hook called with the APT state after each round's checkpoint.
        log: where one-line messages go (default: nowhere).
        names: (recording, vehicle, out_dir) as the user knows them, for the commands printed.

    Raises:
        InputError: bad recording, vehicle, settings, a non-empty `out_dir` without `resume`, or
            a drive on which almost every simulation fails.
    """
    import jax

    say = log or (lambda s: None)
    release_compiled_programs()  # a process that identifies drive after drive stays under the limit
    recs, veh = _load(recording, vehicle, rate)
    settings = _settings(rounds, sims, embedding, epochs, num_samples)
    prob = _problem(recs, veh, longitudinal, segment, max_duration, bandwidth, holdout)
    full = prob if holdout == 0 else _problem(recs, veh, longitudinal, segment, max_duration, bandwidth, 0.0)
    effects = _effects(prob, effects, add_effects, say)
    box = _box(veh, effects, priors)
    run_info = _run_info(recs, prob, settings, seed, effects, box)
    _describe(prob, full, say)
    k_id, k_val, k_post, k_band = jax.random.split(jax.random.key(int(seed)), 4)
    working = contextlib.nullcontext() if out_dir is None else checkpoint_dir(out_dir, resume=resume)
    with working as out:
        state = None if out is None else _start(out, run_info, resume, say)
        estimator, npe_samples, state = _train(
            k_id, prob, box, effects, settings, state, out, progress, on_round_end, say
        )
        starts = _starts(npe_samples, box)
        say("fitting the likelihood posterior on the training part (best fit, model-error noise, Laplace)")
        checked = fit_likelihood(prob, starts, box, effects=effects)
        if holdout == 0:
            fit = checked
        else:
            say("refitting on all the usable driving: the estimate and the posterior reported")
            fit = fit_likelihood(
                full, np.concatenate([checked.theta[None], starts]), box, effects=effects, noise=checked.noise
            )
        samples = np.asarray(fit.sample(k_post, settings.num_samples), float)
        summary = _summary(full, samples, fit, state, run_info, box, effects, veh)
        summary["vehicle"] = veh.to_dict()  # the constants `vdsbi export` needs beside θ
        summary["npe_check"] = _npe_check(npe_samples, checked)
        summary["validation"] = _validation(prob, checked, npe_samples, effects, compare)
        band = predictive_band(
            k_band, prob, np.asarray(checked.predictive_draws(k_val, ppc_draws)), checked.noise.scale, effects
        )
        summary["ppc"] = _ppc_summary(prob, band)
        summary["warnings"] = _warnings(
            samples, summary, box, names or (recording, vehicle, out_dir), longitudinal
        )
        predictive = np.asarray(fit.predictive_draws(k_val, ppc_draws), float)
        result = IdentifyResult(estimator, samples, summary, out, full, band, prob, predictive)
        if out is not None:
            write_outputs(out, result, prob, band)
    return result


def default_effects(prob: Problem) -> tuple[str, ...]:
    """The effects every drive of this kind needs, with the reason for each.

    `tyre_friction` where the drive uses more than half the grip (Dugoff leaves its linear range);
    following the measured speed with a yaw rate (a real car's log): `yaw_inertia` (a real I_z is
    not m·l_f·l_r; left at it, the fit bends l_f to match the yaw transient) and `signal_delay`
    (every real log has latency between the steer signal and the motion it causes: bus, sensor
    filters, the steering's own lag).
    """
    chosen = []
    used = grip_used(prob)
    if used is not None and used > 0.5:
        chosen.append(("tyre_friction", f"the drive uses {used:.0%} of the grip μ·g"))
    if issubclass(prob.model_class, SpeedDriven) and "yaw_rate" in prob.channels:
        chosen.append(("yaw_inertia", "a real car's yaw inertia is not m·l_f·l_r"))
        chosen.append(("signal_delay", "a real log's steer leads the motion it causes by its latency"))
    return tuple(chosen)


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


def _settings(rounds, sims, embedding, epochs, num_samples):
    """`IdentifySettings` (which checks them) with `epochs` as the training's epoch limit."""
    from ..inference import IdentifySettings

    base = IdentifySettings(embedding=embedding)  # the embedding's own training default
    cfg = base.config
    if epochs is not None:
        cfg = dataclasses.replace(cfg, training=dataclasses.replace(cfg.training, max_epochs=int(epochs)))
    return IdentifySettings(
        rounds=int(rounds),
        sims_per_round=int(sims),
        embedding=embedding,
        num_samples=int(num_samples),
        config=cfg,
    )


def _problem(recs, veh, longitudinal: str, segment, max_duration, bandwidth, holdout: float) -> Problem:
    """The drives as one `Problem`: 20-s windows with torques, 10-s windows following the speed."""
    if max_duration is not None and max_duration <= 0:
        raise InputError("settings", "--max-duration", "must be > 0")
    if not 0.0 <= holdout < 1.0:
        raise InputError("settings", "--holdout", f"must lie in [0, 1), got {holdout}")
    speed = issubclass(model_class(longitudinal_mode(recs[0], longitudinal)), SpeedDriven)
    window = max_duration if max_duration is not None else (10.0 if speed else 20.0)
    settings = ProblemSettings(
        longitudinal=longitudinal, max_window=window, segment=segment, bandwidth=bandwidth, held_out=holdout
    )
    return concat_problems([make_problem(r, veh, settings) for r in recs])


def _effects(prob: Problem, effects, add_effects, say) -> tuple[str, ...]:
    """The user's effects, else `default_effects` (each said with its reason), then `add_effects`,
    in the registry's order."""
    from ..simulator import EFFECTS

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


def _box(veh, effects, priors) -> Box:
    try:
        bounds = prior_box(veh, effects, priors)
    except ValueError as err:
        raise InputError("settings", "--prior", str(err)) from None
    return Box.from_dict(bounds, parameter_names(effects))


def _run_info(recs, prob: Problem, settings, seed: int, effects, box: Box) -> dict[str, Any]:
    """What run.json records: a checkpoint resumes only a run with the same."""
    return {
        "recording": " + ".join(str(r.source) for r in recs),
        "seed": int(seed),
        "settings": json.loads(json.dumps(dataclasses.asdict(settings), default=str)),
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


def _train(key, prob: Problem, box: Box, effects, settings, state, out, progress, on_round_end, say):
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

    prior = BoxPrior(np.asarray(box.low), np.asarray(box.high), names=box.names)
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


#: Neural-posterior draws tried, beside its mean and the prior centre, as the fit's start.
STARTS = 31


def _starts(npe_samples: np.ndarray, box: Box) -> np.ndarray:
    """Candidate starts of the likelihood fit: the neural posterior's mean and draws (its global
    view of where the data put θ) and the prior centre."""
    centre = np.asarray(box.low + 0.5 * box.width)
    return np.concatenate([npe_samples.mean(0)[None], centre[None], npe_samples[:STARTS]])


def _summary(full: Problem, samples, fit, state, run_info: dict, box: Box, effects, veh) -> dict[str, Any]:
    """posterior.json's core: the reported posterior (the likelihood one on all the driving), the
    estimate (its best fit), the noise model, what the drive cannot inform and what it does."""
    import jax

    from ..diagnostics import MAX_STD_RATIO, determined_directions, vehicle_combinations

    names = box.names
    bounds = {n: (float(a), float(b)) for n, a, b in zip(names, box.low, box.high)}
    params = summarise(samples, bounds, names, parameter_units(effects))
    # Identified by what the drive informs (before model error widens the interval: a parameter
    # the data pin down stays identified, with an interval that says the model misses something).
    informed = np.asarray(fit.sample(jax.random.key(2), len(samples), information_only=True), float)
    informed_std = np.std(informed, axis=0)
    for i, n in enumerate(names):
        prior_std = float(box.width[i]) / np.sqrt(12.0)
        ratio = float(informed_std[i]) / prior_std
        params[n]["estimate"] = float(fit.theta[i])
        params[n]["identified"] = bool(n in fit.free and ratio <= MAX_STD_RATIO)
        if n not in fit.free:
            params[n]["not_identified_because"] = "the channels do not depend on it in this mode"
        elif ratio > MAX_STD_RATIO:
            params[n]["not_identified_because"] = f"the drive leaves {ratio:.0%} of its prior std"
        if n in fit.disagreement:
            d = fit.disagreement[n]
            params[n]["model_error"] = (
                f"the data's halves ({d['split']}) disagree on it by {d['sigmas']:.1f} standard deviations: "
                "the model lacks something that moves it; its interval is widened by the disagreement"
            )
    speed = full.speed if full.speed is not None else np.broadcast_to(full.v0[:, None], full.t.shape)
    rms_speed = float(np.sqrt(np.mean(np.asarray(speed)[:, :: full.factor][full.train] ** 2)))
    prior = np.random.default_rng(0).uniform(box.low, box.high, (4000, box.dim))
    return {
        "vdsbi_version": __version__,
        "recording": run_info["recording"],
        "parameters": params,
        "estimate": {
            "values": {n: float(v) for n, v in zip(names, fit.theta)},
            "method": "best fit of all the usable driving through the simulator (maximum a posteriori "
            "under the noise model below); the reported posterior is the Laplace approximation there",
            "converged": fit.converged,
            "halves_disagree": None
            if fit.inconsistency is None
            else fit.inconsistency
            | {
                "what": "two halves of the data cannot share one θ (D² of their difference beyond "
                "χ²'s 95 % point): the model lacks something, and the covariance is scaled by D²/P"
            },
        },
        "noise_model": fit.noise.to_dict(),
        "not_identified": [n for n in names if params[n]["identified"] is False],
        "combinations": vehicle_combinations(samples, names, veh, rms_speed, prior, informed)
        | {"determined_directions": determined_directions(samples, prior, names, fit.free)},
        "effects": list(effects),
        "problem": full.summary(),
        "channels": list(full.channels),
        "seed": run_info["seed"],
        "settings": run_info["settings"],
        "rounds": [{k: v for k, v in h.items() if isinstance(v, (int, float, str))} for h in state.history],
    }


def _npe_check(npe_samples: np.ndarray, checked) -> dict[str, Any]:
    """The neural posterior against the likelihood posterior of the same (training) data: the
    squared Mahalanobis distance of its mean, in the likelihood posterior's logit coordinates
    (≤ χ²_P(0.5): inside its 50 % region), and each parameter's std ratio."""
    from scipy.stats import chi2

    d2 = float(checked.mahalanobis2(npe_samples.mean(0))[0])
    limit = float(chi2.ppf(0.5, len(checked.z)))
    import jax

    lik = np.asarray(checked.sample(jax.random.key(1), 2000), float)
    spread = np.std(npe_samples, axis=0) / (np.std(lik, axis=0) + 1e-300)
    ratio = {n: float(r) for n, r in zip(checked.names, spread)}
    agree = d2 <= limit and all(0.5 <= r <= 2.0 for n, r in ratio.items() if n in checked.free)
    return {
        "mahalanobis2_of_npe_mean": d2,
        "chi2_50pct": limit,
        "std_ratio_npe_to_likelihood": ratio,
        "agree": bool(agree),
        "reported": "likelihood",
        "why": "the neural posterior is trained on simulations with sensor noise only; the likelihood "
        "posterior carries the model error the fit measured, and its best fit is the estimate",
    }


def _validation(prob: Problem, checked, npe_samples: np.ndarray, effects, compare) -> dict[str, Any]:
    """Held-out scores of the training fit (the estimate's validation) and of the neural
    posterior's mean; the user's reference values beside them (parameters a reference does not
    give are taken from the fit)."""
    if not prob.held.any():
        return {}
    names = parameter_names(effects)
    out = {
        "estimate": _score(prob, checked.theta, effects),
        "npe_mean": _score(prob, npe_samples.mean(0), effects),
        "what": "fitted on the training part, scored on the held-out part; the exported estimate "
        "is then refit on all the driving",
    }
    if compare:
        unknown = [k for k in compare if k not in names]
        if unknown:
            raise InputError(
                "settings", "--compare", f"unknown parameter {unknown[0]!r}; known: {', '.join(names)}"
            )
        ref = np.array([float(compare.get(n, m)) for n, m in zip(names, checked.theta)])
        out["reference"] = _score(prob, ref, effects) | {"given": {k: float(v) for k, v in compare.items()}}
    return out


def _warnings(samples: np.ndarray, summary: dict, box: Box, names, longitudinal: str) -> list[dict[str, Any]]:
    """posterior.json's `warnings`: mass piled at the prior's edges, or a predictive band that
    misses the recording, each pointing to `vdsbi diagnose`."""
    rec, veh, out = (n if isinstance(n, (str, os.PathLike)) else None for n in names)
    if rec is None:
        rec = summary["recording"]
    ppc = summary["ppc"]
    bounds = {n: (float(a), float(b)) for n, a, b in zip(box.names, box.low, box.high)}
    problem = [{"kind": "recording", "message": w} for w in summary["problem"].get("warnings", ())]
    command = diagnose_command(rec, veh, out, longitudinal)
    coverage = {
        "train": ppc["fraction_inside_90pct_band"],
        "held_out": ppc["fraction_inside_90pct_band_held_out"],
    }
    return (
        problem
        + trust_warnings(
            samples,
            list(summary["parameters"]),
            bounds,
            summary["not_identified"],
            coverage,
            command,
        )
        + model_error_warning(summary["noise_model"], command)
    )


def _score(prob: Problem, values: np.ndarray, effects) -> dict[str, Any]:
    from ..simulator import get_effect

    theta, ep = split_parameters(values, effects)
    eff_values = {
        e: {p: float(v) for p, v in zip(get_effect(e).param_names, np.asarray(x))}
        for e, x in zip(effects, ep)
    }
    return validate(prob, np.asarray(theta), effects, eff_values)


def _ppc_summary(prob: Problem, band: dict[str, Any]) -> dict[str, Any]:
    return {
        "draws": int(band["n"]),
        "noise": "the likelihood fit's noise model (model error included)",
        # None when no posterior draw simulated successfully (no band to compare with).
        "fraction_inside_90pct_band": band_coverage(prob, band, prob.train),
        "fraction_inside_90pct_band_held_out": band_coverage(prob, band, prob.held),
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
