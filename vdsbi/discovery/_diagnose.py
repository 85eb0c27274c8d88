"""The mismatch-discovery pipeline: identify → detect → locate → name → model → re-identify →
show the fit improve on held-out data.

Noise model throughout: additive white Gaussian sensor noise per channel, std from
vehicle.json's `noise_std` where given, else `vdsbi.io.estimate_noise_std` on the usable
stretches. Identification is the differentiable MAP fit with a Laplace covariance
(`Fitter.fit`); pass `identify_fn` to use another estimator with the same interface.
"""

from __future__ import annotations

import dataclasses
import os
import time
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import NamedTuple

import jax
import numpy as np

from ..diagnostics import Localisation, MisspecificationTest, locate_mismatch, misspecification_test
from ..io import Recording, read_recording, read_vehicle
from ..problem import Problem, ProblemSettings, longitudinal_mode, make_problem
from ..simulator import PARAM_NAMES, Vehicle
from ._candidates import effect_names, effect_space, label
from ._data import compared_inputs, fit_data, held_out_metrics
from ._fit import FitResult, Fitter
from ._rank import HELD_OUT_CLAIM, STRONG, Ranked, bic_score, choose, merge, rank, separability, worst_channel
from ._report import build_report, write_report
from ._search import Step, forward_search
from ._terms import TermDiscovery, discover_terms

IdentifyFn = Callable[[Fitter, tuple, "np.ndarray | None", int], FitResult]


def typical_theta(vehicle: Vehicle) -> np.ndarray:
    """A typical passenger car in this vehicle's terms (second start of the base fit):
    CoG at 45 % of the wheelbase, 0.55 m high, slip stiffness 15 and cornering stiffness 8
    times the static axle load."""
    load = vehicle.mass * 9.81 / 2
    prior = vehicle.default_prior()
    th = np.array([0.45 * vehicle.wheelbase, 0.55, 15 * load, 15 * load, 8 * load, 8 * load])
    lo = np.array([prior[n][0] for n in PARAM_NAMES])
    hi = np.array([prior[n][1] for n in PARAM_NAMES])
    return np.clip(th, lo + 0.02 * (hi - lo), hi - 0.02 * (hi - lo))


def default_identify(fitter: Fitter, effects: tuple, z0, max_iter: int) -> FitResult:
    """MAP fit of θ (and the effects' parameters) with a Laplace covariance."""
    return fitter.fit(effects, z0, max_iter=max_iter)


@dataclasses.dataclass
class DiagnosisResult:
    """Everything `diagnose` found; `report` is what report.json holds."""

    report: dict
    windows: Problem
    base: FitResult
    final: FitResult
    ranked: list[Ranked]
    test_before: MisspecificationTest
    test_after: MisspecificationTest
    localisation: Localisation
    predictions: dict
    residual_stretches: dict
    variances: dict = dataclasses.field(default_factory=dict)  # of the predictions, same keys
    terms: TermDiscovery | None = None
    test_terms: MisspecificationTest | None = None

    @property
    def chosen(self) -> list[str]:
        return list(self.report["chosen"])

    @property
    def mismatch_detected(self) -> bool:
        return bool(self.report["mismatch_detected"])


def _stretches(fit: FitResult, windows: Problem):
    """Contiguous equal-length training stretches of the whitened residual, and the matching
    Jacobian rows: (W, L, C), (W·L·C, K), times (W, L), inputs (W, L, 3); windows without
    training samples (held out whole) are skipped."""
    W = windows.num_windows
    C = len(windows.channels)
    mask = windows.train
    T_fit = int(np.max(np.nonzero(mask.any(0))[0])) + 1
    r = fit.residual.reshape(W, T_fit, C)
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
        base = (w * T_fit + np.arange(s, s + L))[:, None] * C + np.arange(C)[None]
        rows.append(base.reshape(-1))
    rows = np.concatenate(rows)
    return np.stack(res), fit.jacobian[rows], np.stack(ts), np.stack(us)


@dataclasses.dataclass(frozen=True)
class DiagnoseSettings:
    """How `diagnose` searches; every field is also a keyword argument of `diagnose`.

    Attributes:
        seed: seed of the simulated null of the misspecification test.
        alpha: level of the misspecification test.
        max_effects: most effects the forward search selects (1: singles only).
        top_pairs: 0 also restricts the search to single effects (the CLI's --top-pairs 0);
            other values are ignored (the forward search replaced pairs among the top singles).
        candidates: effects to consider (default: every registered effect).
        longitudinal: "torque", "speed" or "auto" (see `vdsbi.problem.ProblemSettings`).
        max_window, max_windows: windows cut from the usable stretches (s, count; None: 20 s
            with torques, 10 s following the speed, and all of them).
        train_fraction: share of the usable driving fitted; the rest is held out (whole windows
            at the end of a drive of 3 or more windows, else the end of each window).
        num_draws: simulated null draws of the test.
        single_iters, final_iters: LM iteration caps for the search and the final fit.
        search_dt, final_dt: RK4 steps, s, of the candidate search and of the base/final fits
            (the test and the held-out comparison use the final step).
        identify_fn: `(fitter, effects, z0, max_iter) -> FitResult`; default MAP + Laplace.
        max_terms: most candidate terms (`simulator.TERMS`) used to describe a mismatch the
            chosen effects leave (p after the fix < alpha); 0: no term search.
        quiet: no progress lines.
        plots: write the figures (with `out_dir`).
    """

    seed: int = 0
    alpha: float = 0.05
    max_effects: int = 3
    top_pairs: int = 3
    candidates: Sequence[str] | None = None
    longitudinal: str = "auto"
    max_window: float | None = None
    max_windows: int | None = None
    train_fraction: float = 0.7
    num_draws: int = 400
    single_iters: int = 8
    final_iters: int = 20
    search_dt: float = 0.005
    final_dt: float = 0.0025
    identify_fn: IdentifyFn | None = None
    max_terms: int = 3
    quiet: bool = True
    plots: bool = True

    @property
    def identify(self) -> IdentifyFn:
        return self.identify_fn or default_identify

    def candidate_names(self) -> tuple[str, ...]:
        """The effects searched, in registry order (read now); ValueError on an unknown name."""
        known = effect_names()
        if self.candidates is None:
            return known
        unknown = set(self.candidates) - set(known)
        if unknown:
            raise ValueError(f"candidates: unknown effect(s) {sorted(unknown)} (known: {known})")
        return tuple(n for n in known if n in set(self.candidates))


class _Check(NamedTuple):
    """The misspecification test of one fit, on its contiguous training stretches."""

    test: MisspecificationTest
    residual: np.ndarray  # (W, L, C)
    t: np.ndarray  # (W, L)
    u: np.ndarray  # (W, L, 3)


class _Search(NamedTuple):
    fits: dict[tuple, FitResult]  # at the search step, () -> its own base fit
    ranked: list[Ranked]
    pairs: list[tuple[str, ...]]  # the sets of several effects fitted
    steps: list[Step]


class _Decision(NamedTuple):
    ranked: list[Ranked]  # the search's ranking, with any polished rows merged in
    chosen: tuple[str, ...]
    final: FitResult


class _Progress:
    """Progress lines (none when quiet); `seconds` since the start."""

    def __init__(self, quiet: bool):
        self.quiet, self.t_start = quiet, time.perf_counter()

    @property
    def seconds(self) -> float:
        return time.perf_counter() - self.t_start

    def __call__(self, msg: str) -> None:
        if not self.quiet:
            print(msg, flush=True)


def _cut_windows(recording: Recording, vehicle: Vehicle, s: DiagnoseSettings, say) -> Problem:
    speed = longitudinal_mode(recording, s.longitudinal) == "speed"
    settings = ProblemSettings(
        longitudinal=s.longitudinal,
        max_window=s.max_window or (10.0 if speed else 20.0),
        max_windows=s.max_windows,
        held_out=1.0 - s.train_fraction,
    )
    problem = make_problem(recording, vehicle, settings)
    span = problem.t.shape[1] * problem.dt
    say(
        f"{problem.longitudinal}-driven; windows: {problem.num_windows} × {span:.1f} s, "
        f"channels {', '.join(problem.channels)}"
    )
    return problem


def _fitters(vehicle: Vehicle, windows: Problem, s: DiagnoseSettings) -> tuple[Fitter, Fitter]:
    """The search's fitter (coarse step) and the base/final fits' (fine step), on the
    training part, over the same effects (the registry now)."""
    train, effects = fit_data(windows, "train"), effect_space()
    coarse = Fitter(vehicle, train, dt=s.search_dt, effects=effects)
    return coarse, Fitter(vehicle, train, dt=s.final_dt, effects=effects)


def _fit_base(coarse: Fitter, fitter: Fitter, vehicle: Vehicle, s: DiagnoseSettings, say):
    """The base model from two starts (middle of the prior box, and a typical passenger car),
    searched with the coarse step, then polished with the fine one."""
    starts = [None, coarse.initial_z(typical_theta(vehicle))]
    base_c = min((s.identify(coarse, (), z, s.final_iters) for z in starts), key=lambda f: f.chi2)
    base = s.identify(fitter, (), base_c.z, max(4, s.final_iters // 2))
    say(f"base fit: χ²/dof {base.chi2_dof:.3f} ({base.iterations} it, {say.seconds:.0f} s)")
    return base_c, base


def _check(fit: FitResult, windows: Problem, seed: int, s: DiagnoseSettings) -> _Check:
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


def _held_out_predictions(fitter: Fitter, windows: Problem, base: FitResult, decision: _Decision):
    """Whole-window predictions of the base and the chosen model, (W, K, 6) each, and their
    variances from the fits' parameter uncertainty."""
    full = fit_data(windows, "valid", truncate=False)
    before = fitter.predict(base.z, (), full)
    var_before = fitter.prediction_variance(base, full)
    if not decision.chosen:
        return {"before": before, "after": before}, {"before": var_before, "after": var_before}
    after = fitter.predict(decision.final.z, decision.chosen, full)
    var_after = fitter.prediction_variance(decision.final, full)
    return {"before": before, "after": after}, {"before": var_before, "after": var_after}


def _search(coarse: Fitter, base_c: FitResult, names: tuple[str, ...], s: DiagnoseSettings, say) -> _Search:
    """Forward selection at the coarse step: singles from the base fit, then one effect at a
    time added on the refitted set while the evidence gain is strong (`forward_search`)."""
    most = 1 if s.top_pairs == 0 else s.max_effects
    fit_fn = lambda cand, z0: s.identify(coarse, cand, z0, s.single_iters)
    found = forward_search(fit_fn, base_c, names, most)
    ranked = rank(found.fits, base_c)
    singles = [r for r in ranked if len(r.effects) == 1]
    say("singles: " + ", ".join(f"{r.name} {r.score:.1f}" for r in singles[:5]))
    for st in found.steps[1:]:
        also = f" (as strong: {', '.join(st.ambiguous_with)})" if st.ambiguous_with else ""
        say(f"add to {label(st.current)}: {st.added or 'nothing'}{also}")
    multi = [e for e in found.fits if len(e) > 1]
    return _Search(found.fits, ranked, multi, found.steps)


def _decide(search: _Search, fitter: Fitter, base: FitResult, detected: bool, s: DiagnoseSettings, say):
    """The chosen explanation and its fit at the fine step."""
    ranked = search.ranked
    polished: dict[tuple, FitResult] = {(): base}
    if detected and len(ranked[0].effects) >= 2 and ranked[0].score >= STRONG:
        # Several effects win the search: the search caps iterations and a set starts where
        # its subset stopped, so polish the set and its fitted subsets one smaller at the fine
        # step with the same budget before deciding between them.
        top = ranked[0].effects
        subsets = [tuple(e for e in top if e != x) for x in top]
        for cand in [top, *(c for c in subsets if c in search.fits)]:
            polished[cand] = s.identify(fitter, cand, search.fits[cand].z, s.final_iters)
        decision = rank(polished, base)
        chosen = choose(decision, detected)
        say("set check: " + ", ".join(f"{r.name} {r.score:.1f}" for r in decision))
        # report the polished evidence for these, so the ranking and choice agree
        ranked = merge(ranked, decision)
    else:
        chosen = choose(ranked, detected)
    if chosen in polished:
        final = polished[chosen]
    elif chosen:
        final = s.identify(fitter, chosen, search.fits[chosen].z, s.final_iters)
    else:
        final = base
    say(f"chosen: {label(chosen)} ({say.seconds:.0f} s)")
    return _Decision(ranked, chosen, final)


def _describe_remainder(vehicle, fitter: Fitter, windows: Problem, base, decision, after, held_ok, s, say):
    """Candidate terms for what the chosen effects leave (`discover_terms`), when a mismatch
    was detected and the fix leaves the residual inconsistent with noise or the held-out
    χ²/dof above `HELD_OUT_CLAIM`; and the residual test of their refit."""
    if s.max_terms <= 0 or (after.test.p_value >= s.alpha and held_ok):
        return None, None
    terms = lambda fit, chosen: discover_terms(
        vehicle, fitter.data, fit, fitter, chosen, max_terms=s.max_terms, max_iter=s.final_iters
    )
    found = terms(decision.final, decision.chosen)
    if decision.chosen:
        # The chosen effects may stand in for what a term describes better: the terms on the
        # base model alone, kept if their evidence beats the library fit (with its terms).
        alone = terms(base, ())
        rival = found.fit if found.fit is not None else decision.final
        if alone.fit is not None and bic_score(alone.fit, rival) > 0:
            gain = float(bic_score(alone.fit, decision.final))
            found = dataclasses.replace(alone, gain=gain, dropped=list(decision.chosen))
    for t in found.terms:
        say(f"discovered term: {t['formula']}")
    if found.fit is None:
        say(f"no candidate term has strong evidence ({say.seconds:.0f} s)")
        return found, None
    return found, _check(found.fit, windows, s.seed + 2, s).test


def diagnose(
    recording: Recording | str | os.PathLike,
    vehicle: Vehicle | str | os.PathLike,
    out_dir: str | os.PathLike | None = None,
    *,
    settings: DiagnoseSettings | None = None,
    **options,
) -> DiagnosisResult:
    """Find where a recording and the model disagree, name the missing physics and fix it.

    Stages: cut windows → fit the base model → test it for misspecification and locate the
    mismatch → fit every candidate effect, then add effects one at a time while the evidence
    supports it (forward search, up to `max_effects`) → choose by evidence →
    test the fixed model and compare both on the held-out part → report.

    Args:
        recording: a `Recording` or a path readable by `vdsbi.io.read_recording`.
        vehicle: a `Vehicle` or a vehicle file path.
        out_dir: if given, write report.json, report.md and plots there (must not exist or be
            empty).
        settings: how to search (default `DiagnoseSettings()`).
        **options: any `DiagnoseSettings` field (seed, alpha, top_pairs, candidates, ...),
            overriding `settings`.

    Returns:
        `DiagnosisResult`.
    """
    s = dataclasses.replace(settings or DiagnoseSettings(), **options)
    say = _Progress(s.quiet)
    vehicle = vehicle if isinstance(vehicle, Vehicle) else read_vehicle(vehicle)
    recording = recording if isinstance(recording, Recording) else read_recording(recording)
    names = s.candidate_names()
    with jax.enable_x64(True):
        windows = _cut_windows(recording, vehicle, s, say)
        coarse, fitter = _fitters(vehicle, windows, s)
        base_c, base = _fit_base(coarse, fitter, vehicle, s, say)
        before = _check(base, windows, s.seed, s)
        loc, detected = _locate(before, windows, s, say)
        search = _search(coarse, base_c, names, s, say)
        decision = _decide(search, fitter, base, detected, s, say)
        after = _check(decision.final, windows, s.seed + 1, s)
        predictions, variances = _held_out_predictions(fitter, windows, base, decision)
        held = held_out_metrics(predictions["after"], windows, variances["after"])
        held_ok = not detected or worst_channel(held)[1] <= HELD_OUT_CLAIM
        terms, test_terms = _describe_remainder(
            vehicle, fitter, windows, base, decision, after, held_ok, s, say
        )
        if terms is not None and terms.fit is not None:
            full = fit_data(windows, "valid", truncate=False)
            predictions["after_terms"] = terms.fitter.predict(terms.fit.z, terms.effects, full)
            variances["after_terms"] = terms.fitter.prediction_variance(terms.fit, full)
        sep = separability(search.ranked, base_c)  # all at the search step, against its own none
    found = DiagnosisResult(
        report={},
        windows=windows,
        base=base,
        final=decision.final,
        ranked=decision.ranked,
        test_before=before.test,
        test_after=after.test,
        localisation=loc,
        predictions=predictions,
        variances=variances,
        residual_stretches={"before": before.residual, "after": after.residual, "t": before.t},
        terms=terms,
        test_terms=test_terms,
    )
    found.report = build_report(found, recording, s, names, decision.chosen, search, sep, fitter, coarse)
    found.report["seconds"] = say.seconds
    if out_dir is not None:
        write_report(found, Path(out_dir), plots=s.plots)
    return found


__all__ = ["DiagnoseSettings", "DiagnosisResult", "diagnose", "default_identify"]
