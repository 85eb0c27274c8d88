"""The mismatch-discovery pipeline: identify → detect → locate → name → model → re-identify →
show the fit improve on held-out data.

Every fit is identify's (`vdsbi.estimation.fit_likelihood`, through `Fitter.fit`): the same noise
model (the model's error measured per channel, its samples counted by their autocorrelation), the
same start speeds and Laplace covariance; a search step's candidates are weighed with the noise
model of the fit they extend. Detection holds the base fit's residual against the sensor noise
alone (std from vehicle.json's `noise_std` where given, else `vdsbi.io.estimate_noise_std`): the
hypothesis that the model is right. An effect is claimed only where it improves the held-out fit.
"""

from __future__ import annotations

import dataclasses
import os
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import NamedTuple

import jax
import numpy as np

from ..diagnostics import Localisation, MisspecificationTest, locate_mismatch, misspecification_test
from ..estimation import ModelError
from ..io import Recording, read_recording, read_vehicle
from ..problem import (
    Box,
    Problem,
    ProblemSettings,
    concat_problems,
    default_effects,
    longitudinal_mode,
    make_problem,
    measured_steer_lag,
)
from ..runtime import in_background
from ..simulator import PARAM_NAMES, Vehicle
from ..simulator.effects import EFFECTS
from ..simulator.models import SpeedDriven, model_class
from ._candidates import EffectSpace, effect_names, effect_space, label
from ._data import compared_inputs, held_out_scores
from ._fit import Fitter
from ._held_out import held_out_improves
from ._rank import (
    STRONG,
    bic_score,
    changes,
    choose,
    claim_limit,
    merge,
    rank,
    separability,
    verdict,
    worst_channel,
)
from ._report import Findings, build_report, write_report
from ._results import DiagnosisResult, DiscoveryFit, Ranked, Verdict
from ._search import Step, forward_search
from ._settings import DiagnoseSettings, Progress
from ._terms import HeldOutScores, discover_terms, terms_section


def typical_theta(vehicle: Vehicle) -> np.ndarray:
    """A typical passenger car in this vehicle's terms (second start of the base fit):
    CoG at 45 % of the wheelbase, 0.55 m high, slip stiffness 15 and cornering stiffness 8
    times the static axle load."""
    load = vehicle.mass * 9.81 / 2
    box = Box.from_dict(vehicle.default_prior(), PARAM_NAMES)
    lo, hi = np.asarray(box.low), np.asarray(box.high)
    th = np.array([0.45 * vehicle.wheelbase, 0.55, 15 * load, 15 * load, 8 * load, 8 * load])
    return np.clip(th, lo + 0.02 * (hi - lo), hi - 0.02 * (hi - lo))


def _stretches(fit: DiscoveryFit, windows: Problem):
    """Contiguous equal-length training stretches of the whitened residual, and the matching
    Jacobian rows: (W, L, C), (W·L·C, K), times (W, L), inputs (W, L, 3); `windows` are the
    fitted ones (`Fitter.problem`)."""
    W, K_t = windows.train.shape
    C = len(windows.channels)
    mask = windows.train
    r = fit.residual.reshape(W, K_t, C)
    fitted = [w for w in range(W) if mask[w].any()]
    starts = {w: int(np.argmax(mask[w])) for w in fitted}
    L = min(int(mask[w].sum()) for w in fitted)
    u_all = compared_inputs(windows)
    rows = []
    res, ts, us = [], [], []
    for w in fitted:
        s = starts[w]
        res.append(r[w, s : s + L])
        ts.append(windows.t_out[w, s : s + L])
        us.append(u_all[w, s : s + L])
        base = (w * K_t + np.arange(s, s + L))[:, None] * C + np.arange(C)[None]
        rows.append(base.reshape(-1))
    rows = np.concatenate(rows)
    return np.stack(res), fit.jacobian[rows], np.stack(ts), np.stack(us)


class _Check(NamedTuple):
    """The misspecification test of one fit, on its contiguous training stretches."""

    test: MisspecificationTest
    residual: np.ndarray  # (W, L, C)
    t: np.ndarray  # (W, L)
    u: np.ndarray  # (W, L, 3)


class _Search(NamedTuple):
    fits: dict[tuple, DiscoveryFit]  # at the search step, () -> its own base fit
    ranked: list[Ranked]
    pairs: list[tuple[str, ...]]  # the sets of several effects fitted
    steps: list[Step]


class _Decision(NamedTuple):
    ranked: list[Ranked]  # the search's ranking, with any polished rows merged in
    chosen: tuple[str, ...]
    final: DiscoveryFit


def _cut_windows(recordings: Sequence[Recording], vehicle: Vehicle, s: DiagnoseSettings, say) -> Problem:
    """The windows of every recording, side by side (`concat_problems`)."""
    speed = issubclass(model_class(longitudinal_mode(recordings[0], s.longitudinal)), SpeedDriven)
    settings = ProblemSettings(
        longitudinal=s.longitudinal,
        max_window=s.max_window or (10.0 if speed else 20.0),
        max_windows=s.max_windows,
        held_out=1.0 - s.train_fraction,
    )
    problem = concat_problems([make_problem(r, vehicle, settings) for r in recordings])
    span = problem.t.shape[1] * problem.dt
    say(
        f"{problem.longitudinal}-driven; windows: {problem.num_windows} × {span:.1f} s, "
        f"channels {', '.join(problem.channels)}"
    )
    return problem


def _base_effects(windows: Problem, s: DiagnoseSettings) -> tuple[str, ...]:
    """What the search starts from: the effects identify adds by default on this drive
    (`default_effects`), or the settings' `base_effects`; in the registry's order."""
    names = [n for n, _ in default_effects(windows)] if s.base_effects is None else list(s.base_effects)
    unknown = [n for n in names if n not in EFFECTS]
    if unknown:
        raise ValueError(f"base_effects: unknown effect(s) {unknown}")
    return tuple(n for n in EFFECTS if n in names)


def _fitters(
    windows: Problem, s: DiagnoseSettings, base: tuple[str, ...], lag: float | None
) -> tuple[Fitter, Fitter]:
    """The search's fitter (coarse step) and the base/final fits' (fine step), on the
    training part, over the same effects (the registry's searched ones now, and the base set),
    their steer-lag parameters started at half the `lag` the recording shows."""
    effects = _lag_started(effect_space(tuple(n for n in EFFECTS if n in {*effect_names(), *base})), lag)
    coarse = Fitter(windows, dt=s.search_dt, effects=effects)
    return coarse, Fitter(windows, dt=s.final_dt, effects=effects)


def _lag_started(effects: EffectSpace, lag: float | None) -> EffectSpace:
    """`effects` with each steer-lag parameter (`AbstractEffect.steer_lag`) starting at half the
    measured `lag`, inside its bounds: the measured lag holds the tyres' and the body's own lag
    too, and a lag of 0.2 s is not reached from the default start by a few local steps."""
    if lag is None or lag <= 0:
        return effects
    start = effects.start.copy()
    for name, cls in effects.classes.items():
        for param in cls.steer_lag:
            i = effects.slices[name].start + cls.param_names.index(param)
            margin = 0.01 * (effects.hi[i] - effects.lo[i])
            start[i] = np.clip(0.5 * lag, effects.lo[i] + margin, effects.hi[i] - margin)
    return dataclasses.replace(effects, start=start)


def _fit_base(coarse: Fitter, fitter: Fitter, vehicle: Vehicle, effects, s: DiagnoseSettings, say):
    """The base model (θ and identify's default `effects`) from two starts (middle of the prior
    box, and a typical passenger car), searched with the coarse step, then polished with the fine
    one."""
    # The fine step's programs compile on the other core while the coarse fits run; the polish
    # waits for them rather than compile them a second time.
    compiling = in_background(fitter.fit, effects, max_iter=1, noise=ModelError(passes=0))
    starts = [None, coarse.initial_z(typical_theta(vehicle))]
    # The starts are told apart after one re-measurement of the noise; the polish carries on
    # from the better one's noise model.
    once = ModelError(passes=1)
    base_c = min(
        (coarse.fit(effects, z, max_iter=s.final_iters, noise=once) for z in starts), key=lambda f: f.chi2
    )
    compiling.result()  # compiled (or raised) before the polish calls it: never compiled twice
    base = fitter.fit(
        effects, base_c.z, max_iter=max(4, s.final_iters // 2), noise=ModelError(start=base_c.noise)
    )
    say(
        f"base fit ({label(effects) if effects else 'θ alone'}): χ²/dof {base.chi2_dof:.3f} "
        f"({base.iterations} it, {say.seconds:.0f} s)"
    )
    return base_c, base


def _check(fit: DiscoveryFit, windows: Problem, seed: int, s: DiagnoseSettings) -> _Check:
    """`windows`: the fitted ones (`Fitter.problem`)."""
    res, jac, ts, us = _stretches(fit, windows)
    test = misspecification_test(
        seed, res, jac, rate=1.0 / windows.compared_dt, channels=windows.channels, num_draws=s.num_draws
    )
    return _Check(test, res, ts, us)


def _locate(before: _Check, windows: Problem, s: DiagnoseSettings, say) -> tuple[Localisation, bool]:
    """Where the base fit's residual departs from noise, and whether the test rejects it."""
    loc = locate_mismatch(before.test, before.residual, before.t, before.u, rate=1.0 / windows.compared_dt)
    detected = bool(before.test.p_value < s.alpha)
    say(f"misspecification p = {before.test.p_value:.4f} -> {'detected' if detected else 'not detected'}")
    return loc, detected


def _held_out(fitter: Fitter, windows: Problem, fits: dict[str, DiscoveryFit], block: int):
    """Whole-window predictions (W, K, C) of each fit on every window of `windows`, their
    variances from the fit's parameter uncertainty, and their held-out scores (with those of
    runs of `block` samples)."""
    pred, var, held = {}, {}, {}
    for key, fit in fits.items():
        pred[key] = fitter.predict(fit.z, fit.effects, windows)
        var[key] = fitter.prediction_variance(fit, windows)
        held[key] = held_out_scores(windows, pred[key], var[key], block)
    return pred, var, held


def _block(base: DiscoveryFit) -> int:
    """Held-out samples per block of the paired comparison: twice the base fit's longest residual
    autocorrelation time, so that the blocks' differences are close to independent."""
    return max(1, int(np.ceil(2.0 * float(np.max(base.noise.tau)))))


def _search(
    coarse: Fitter, base_c: DiscoveryFit, names: tuple[str, ...], s: DiagnoseSettings, say
) -> _Search:
    """Forward selection at the coarse step: singles from the base fit, then one effect at a
    time added on the refitted set while the evidence gain is strong (`forward_search`)."""
    # Candidates weighed with the noise model of the fit they extend, so their evidence compares.
    held = ModelError(passes=0, start=base_c.noise)
    fit_fn = lambda cand, z0: coarse.fit(cand, z0, max_iter=s.single_iters, noise=held)
    found = forward_search(fit_fn, base_c, names, s.max_effects, s.workers)
    ranked = rank(found.fits, base_c)
    singles = [r for r in ranked if changes(r.effects, base_c.effects) == 1]
    say("singles: " + ", ".join(f"{r.name} {r.score:.1f}" for r in singles[:5]))
    for st in found.steps[1:]:
        also = f" (as strong: {', '.join(st.ambiguous_with)})" if st.ambiguous_with else ""
        say(f"add to {label(st.current)}: {st.added or 'nothing'}{also}")
    multi = [e for e in found.fits if changes(e, base_c.effects) > 1]
    return _Search(found.fits, ranked, multi, found.steps)


def _decide(search: _Search, fitter: Fitter, base: DiscoveryFit, detected: bool, s: DiagnoseSettings, say):
    """The chosen explanation and its fit at the fine step."""
    ranked, start = search.ranked, tuple(base.effects)
    polished: dict[tuple, DiscoveryFit] = {start: base}
    if detected and changes(ranked[0].effects, start) >= 2 and ranked[0].score >= STRONG:
        # Several changes win the search: the search caps iterations and a set starts where
        # its subset stopped, so polish the set and its fitted subsets one smaller at the fine
        # step with the same budget before deciding between them.
        top = ranked[0].effects
        subsets = [tuple(e for e in top if e != x) for x in top if x not in start]
        for cand in [top, *(c for c in subsets if c in search.fits)]:
            polished[cand] = fitter.fit(cand, search.fits[cand].z, max_iter=s.final_iters)
        decision = rank(polished, base)
        chosen = choose(decision, detected, start)
        say("set check: " + ", ".join(f"{r.name} {r.score:.1f}" for r in decision))
        # report the polished evidence for these, so the ranking and choice agree
        ranked = merge(ranked, decision, start)
    else:
        chosen = choose(ranked, detected, start)
    if chosen in polished:
        final = polished[chosen]
    else:
        final = fitter.fit(chosen, search.fits[chosen].z, max_iter=s.final_iters)
    say(f"chosen: {label(chosen)} ({say.seconds:.0f} s)")
    return _Decision(ranked, chosen, final)


def _describe_remainder(fitter: Fitter, base, decision, after, held_ok, s, say):
    """Candidate terms for what the chosen effects leave (`discover_terms`), when a mismatch
    was detected and the fix leaves the residual inconsistent with noise or the held-out
    χ²/dof above `claim_limit`; and the residual test of their refit."""
    if s.max_terms <= 0 or (after.test.p_value >= s.alpha and held_ok):
        return None, None
    terms = lambda fit, chosen: discover_terms(
        fit, fitter, chosen, max_terms=s.max_terms, max_iter=s.final_iters
    )
    found = terms(decision.final, decision.chosen)
    if decision.chosen != tuple(base.effects):
        # The chosen effects may stand in for what a term describes better: the terms on the
        # base model alone, kept if their evidence beats the library fit (with its terms).
        alone = terms(base, base.effects)
        rival = found.fit if found.fit is not None else decision.final
        if alone.fit is not None and bic_score(alone.fit, rival) > 0:
            gain = float(bic_score(alone.fit, decision.final))
            named = [e for e in decision.chosen if e not in base.effects]
            found = dataclasses.replace(alone, gain=gain, dropped=named)
    for t in found.terms:
        say(f"discovered term: {t['formula']}")
    if found.fit is None:
        say(f"no candidate term has strong evidence ({say.seconds:.0f} s)")
        return found, None
    return found, _check(found.fit, fitter.problem, s.seed + 2, s).test


def _conclude(checks: tuple, decision, base, held, remainder: tuple, windows: Problem, s):
    """The verdict, the report's section on the discovered terms (`terms_section`), and the
    held-out scores the report shows (those with the terms only where the section uses them).
    ``checks``: the residual checks of the base fit and of the chosen effects'; ``remainder``: the
    term discovery and its test (`_describe_remainder`). The verdict names the changes to the
    base set: the effects added, then any removed."""
    (before, after), (terms, test_terms) = checks, remainder
    p_before, p_after = float(before.test.p_value), float(after.test.p_value)
    named = tuple(e for e in decision.chosen if e not in base.effects)
    dropped = tuple(e for e in base.effects if e not in decision.chosen)
    changed = named + tuple(f"no {e}" for e in dropped)
    detected = p_before < s.alpha
    tau = dict(zip(base.noise.channels, base.noise.tau))
    improved = held_out_improves(held["before"], held["after"], tau) if changed else None
    concl = verdict(detected, changed, p_after, s.alpha, improved, worst_channel(held["after"]))
    section = terms_section(
        p_before=p_before,
        p_after=p_after,
        chosen=changed,
        terms=terms,
        p_terms=None if test_terms is None else float(test_terms.p_value),
        held=HeldOutScores(held["after"], held.get("after_terms"), int(windows.held.sum()), tau),
        alpha=s.alpha,
    )
    text = concl["text"] + (f"; {section['sentence']}" if section.get("sentence") else "")
    found = Verdict(detected, named, concl["explained"], improved, section["explanation"], text, dropped)
    if section.pop("fit", None) is None:
        held = {k: v for k, v in held.items() if k != "after_terms"}
    return found, section, held


def diagnose_mismatch(
    recording: Recording | str | os.PathLike | Sequence[Recording | str | os.PathLike],
    vehicle: Vehicle | str | os.PathLike,
    out_dir: str | os.PathLike | None = None,
    *,
    settings: DiagnoseSettings | None = None,
    log: Callable[[str], None] | None = None,
    **options,
) -> DiagnosisResult:
    """Find where a recording and the model disagree, name the missing physics and fix it.

    Stages: cut windows → fit the base model → test it for misspecification and locate the
    mismatch → fit every candidate effect, then add effects one at a time while the evidence
    supports it (forward search, up to `max_effects`) → choose by evidence →
    test the fixed model and compare both on the held-out part → report.

    Args:
        recording: a `Recording` or a path readable by `vdsbi.io.read_recording`; or several
            recordings of one car (or of cars of one platform), diagnosed together: their
            windows side by side, each drive's last part held out.
        vehicle: a `Vehicle` or a vehicle file path.
        out_dir: if given, write report.json, report.md and plots there (must not exist or be
            empty).
        settings: how to search (default `DiagnoseSettings()`).
        log: where progress lines go unless `quiet` (default: printed).
        **options: any `DiagnoseSettings` field (seed, alpha, max_effects, candidates, ...),
            overriding `settings`.

    Returns:
        `DiagnosisResult`.
    """
    s = dataclasses.replace(settings or DiagnoseSettings(), **options)
    say = Progress(s.quiet, log)
    vehicle = vehicle if isinstance(vehicle, Vehicle) else read_vehicle(vehicle)
    recordings = _recordings(recording)
    names = s.candidate_names()
    with jax.enable_x64(True):
        windows = _cut_windows(recordings, vehicle, s, say)
        found = _find(windows, vehicle, s, names, _steer_lag(recordings, vehicle), say)
    report = build_report(recordings, windows, s, found, seconds=say.seconds)
    result = DiagnosisResult(
        report=report,
        verdict=found.conclusion,
        windows=windows,
        base=found.base,
        final=found.final,
        ranked=found.ranked,
        test_before=found.test_before,
        test_after=found.test_after,
        localisation=found.localisation,
        held_out=found.held_out,
        predictions=found.predictions,
        variances=found.variances,
        residual_stretches=found.residual_stretches,
        terms=found.terms,
        test_terms=found.test_terms,
    )
    if out_dir is not None:
        write_report(result, Path(out_dir), plots=s.plots)
    return result


def _recordings(given) -> list[Recording]:
    """One or several recordings, read where given as paths."""
    many = isinstance(given, Sequence) and not isinstance(given, str)
    out = [r if isinstance(r, Recording) else read_recording(r) for r in (given if many else [given])]
    if not out:
        raise ValueError("diagnose: no recording given")
    return out


def _steer_lag(recordings: Sequence[Recording], vehicle: Vehicle) -> float | None:
    """The steer-to-response lag the recordings show: the median of those measured (None: none)."""
    lags = [lag for r in recordings if (lag := measured_steer_lag(r, vehicle)) is not None]
    return float(np.median(lags)) if lags else None


def _find(
    windows: Problem, vehicle: Vehicle, s: DiagnoseSettings, names: tuple[str, ...], lag: float | None, say
) -> Findings:
    """Every stage after cutting the windows, up to the verdict; `lag`: the steer-to-response
    lag the recording shows, s (None: not measured)."""
    start = _base_effects(windows, s)
    coarse, fitter = _fitters(windows, s, start, lag)
    fitted = fitter.problem
    base_c, base = _fit_base(coarse, fitter, vehicle, start, s, say)
    # The held-out comparison's programs compile during the search.
    predicting = in_background(fitter.predict, base.z, start, windows)
    before = _check(base, fitted, s.seed, s)
    loc, detected = _locate(before, fitted, s, say)
    search = _search(coarse, base_c, names, s, say)
    decision = _decide(search, fitter, base, detected, s, say)
    after = _check(decision.final, fitted, s.seed + 1, s)
    predicting.result()  # compiled (or raised) before the comparison calls it
    block = _block(base)
    fits = {"before": base, "after": decision.final}
    predictions, variances, held = _held_out(fitter, windows, fits, block)
    worst = worst_channel(held["after"])
    held_ok = not detected or worst[1] <= claim_limit(worst[2])
    terms, test_terms = _describe_remainder(fitter, base, decision, after, held_ok, s, say)
    if terms is not None and terms.fit is not None:
        extra = _held_out(terms.fitter, windows, {"after_terms": terms.fit}, block)
        for into, part in zip((predictions, variances, held), extra):
            into.update(part)
    conclusion, section, shown = _conclude(
        (before, after), decision, base, held, (terms, test_terms), windows, s
    )
    return Findings(
        base=base,
        final=decision.final,
        ranked=decision.ranked,
        test_before=before.test,
        test_after=after.test,
        localisation=loc,
        held_out=held,
        held_out_shown=shown,
        predictions=predictions,
        variances=variances,
        residual_stretches={"before": before.residual, "after": after.residual, "t": before.t},
        terms=terms,
        test_terms=test_terms,
        conclusion=conclusion,
        terms_section=section,
        search=search,
        separability=separability(search.ranked, base_c),  # at the search step, vs its own none
        fitter=fitter,
        coarse=coarse,
    )
