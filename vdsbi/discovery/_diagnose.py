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

import jax
import numpy as np

from ..diagnostics._misspecification import (
    Localisation,
    MisspecificationTest,
    locate_mismatch,
    misspecification_test,
)
from ..io import Recording, read_recording, read_vehicle
from ..simulator import EFFECTS, PARAM_NAMES, Vehicle
from ..simulator._vehicle import CHANNELS
from ._candidates import label, pair_candidates, single_candidates
from ._data import Windows, make_windows
from ._fit import EFFECT_BOUNDS, EFFECT_NAMES, FitResult, Fitter
from ._rank import PAIR_LOG_PRIOR, STRONG, Ranked, choose, merge, rank, separability

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
    windows: Windows
    base: FitResult
    final: FitResult
    ranked: list[Ranked]
    test_before: MisspecificationTest
    test_after: MisspecificationTest
    localisation: Localisation
    predictions: dict
    residual_stretches: dict

    @property
    def chosen(self) -> list[str]:
        return list(self.report["chosen"])

    @property
    def mismatch_detected(self) -> bool:
        return bool(self.report["mismatch_detected"])


def _stretches(fit: FitResult, windows: Windows):
    """Contiguous equal-length training stretches of the whitened residual, and the matching
    Jacobian rows: (W, L, C), (W·L·C, K), times (W, L), inputs (W, L, 3)."""
    W = windows.num_windows
    C = len(windows.channels)
    mask = windows.train
    T_fit = int(np.max(np.nonzero(mask.any(0))[0])) + 1
    r = fit.residual.reshape(W, T_fit, C)
    starts = [int(np.argmax(mask[w])) for w in range(W)]
    lens = [int(mask[w].sum()) for w in range(W)]
    L = min(lens)
    rows = []
    res, ts, us = [], [], []
    for w in range(W):
        s = starts[w]
        res.append(r[w, s : s + L])
        ts.append(windows.t[w, s : s + L])
        us.append(windows.u[w, s : s + L])
        base = (w * T_fit + np.arange(s, s + L))[:, None] * C + np.arange(C)[None]
        rows.append(base.reshape(-1))
    rows = np.concatenate(rows)
    return np.stack(res), fit.jacobian[rows], np.stack(ts), np.stack(us)


def _held_metrics(pred: np.ndarray, windows: Windows) -> dict:
    """Per channel on the held-out samples: NRMSE (RMS error / std of the measurement) and
    χ²/dof (mean squared whitened error; no parameters were fitted on these samples)."""
    out = {}
    m = windows.held
    for c, name in enumerate(windows.channels):
        e = (pred[:, :, CHANNELS.index(name)] - windows.y[:, :, c])[m]
        y = windows.y[:, :, c][m]
        out[name] = {
            "nrmse": float(np.sqrt(np.mean(e**2)) / (np.std(y) + 1e-12)),
            "chi2_dof": float(np.mean((e / windows.sigma[c]) ** 2)),
        }
    return out


def _effect_rows(ranked: Sequence[Ranked]) -> list[dict]:
    return [
        {
            "name": r.name,
            "effects": list(r.effects),
            "score": r.score,
            "log_bayes_factor": r.log_bayes_factor,
            "probability": r.probability,
            "chi2": r.chi2,
            "num_params": r.num_effect_params,
            "params": r.fit.effect_params,
            "params_std": r.fit.effect_std,
        }
        for r in ranked
    ]


def _at_bounds(fit: FitResult, fitter: Fitter, frac: float = 0.01) -> list[str]:
    """Names of fitted values within `frac` of their box's edge (the data pushed them there:
    a sign that they absorb something the model lacks)."""
    out = []
    lo, hi = np.asarray(fitter.space.theta_lo), np.asarray(fitter.space.theta_hi)
    for n, v, a, b in zip(PARAM_NAMES, fit.theta, lo, hi):
        if min(v - a, b - v) < frac * (b - a):
            out.append(n)
    for e, d in fit.effect_params.items():
        for (k, v), (a, b) in zip(d.items(), EFFECT_BOUNDS[e]):
            if min(v - a, b - v) < frac * (b - a):
                out.append(f"{e}.{k}")
    return out


def verdict(detected: bool, chosen: Sequence[str], p_after: float, alpha: float, held_improved) -> dict:
    """One-line conclusion, and whether the chosen effects account for the whole mismatch.

    `explained` needs both a residual consistent with noise after the fix (p_after ≥ α) and a
    better held-out fit; otherwise physics outside the library remains (or the fix is absorbing
    it), and the report says so instead of claiming the effect as the answer.
    """
    if not detected:
        return {"explained": None, "text": "no mismatch detected: the base model fits within the noise"}
    if not chosen:
        return {
            "explained": False,
            "text": "mismatch detected, but no candidate effect has strong evidence: the missing "
            "physics is outside the library (see where it is located)",
        }
    names = " + ".join(chosen)
    if held_improved is False:
        return {
            "explained": False,
            "text": f"mismatch detected; {names} fits the fitted part but not the held-out part: "
            "it is absorbing physics outside the library, not naming it",
        }
    if p_after < alpha / 10:
        return {
            "explained": False,
            "text": f"mismatch detected; {names} explains part of it (p after the fix = {p_after:.3g} < "
            f"{alpha / 10:g}): physics outside the library remains",
        }
    if p_after < alpha:
        # at level α, one complete fix in 1/α still rejects by chance: say so, do not overclaim
        return {
            "explained": False,
            "text": f"mismatch detected; {names} explains most of it, but the residual test still "
            f"rejects weakly (p after the fix = {p_after:.3g} < {alpha:g}; about 1 in {1 / alpha:.0f} "
            "complete fixes does so by chance): something small may remain",
        }
    return {"explained": True, "text": f"mismatch detected and explained by {names}"}


def _theta_dict(x) -> dict:
    return {n: float(v) for n, v in zip(PARAM_NAMES, x)}


def diagnose(
    recording: Recording | str | os.PathLike,
    vehicle: Vehicle | str | os.PathLike,
    out_dir: str | os.PathLike | None = None,
    *,
    seed: int = 0,
    alpha: float = 0.05,
    top_pairs: int = 3,
    candidates: Sequence[str] | None = None,
    max_window: float = 20.0,
    max_windows: int = 3,
    train_fraction: float = 0.7,
    num_draws: int = 400,
    single_iters: int = 8,
    final_iters: int = 20,
    search_dt: float = 0.005,
    final_dt: float = 0.0025,
    identify_fn: IdentifyFn | None = None,
    quiet: bool = True,
    plots: bool = True,
) -> DiagnosisResult:
    """Find where a recording and the model disagree, name the missing physics and fix it.

    Args:
        recording: a `Recording` or a path readable by `vdsbi.io.read_recording`.
        vehicle: a `Vehicle` or a vehicle file path.
        out_dir: if given, write report.json, report.md and plots there (must not exist or be
            empty).
        seed: seed of the simulated null of the misspecification test.
        alpha: level of the misspecification test.
        top_pairs: pairs are fitted among this many best single effects.
        candidates: effects to consider (default: all ten).
        max_window, max_windows: windows cut from the usable stretches (s, count).
        train_fraction: share of each window fitted; the rest is held out.
        num_draws: simulated null draws of the test.
        single_iters, final_iters: LM iteration caps for the search and the final fit.
        search_dt, final_dt: RK4 steps, s, of the candidate search and of the base/final fits
            (the test and the held-out comparison use the final step).
        identify_fn: `(fitter, effects, z0, max_iter) -> FitResult`; default MAP + Laplace.
        quiet: no progress lines.
        plots: write the figures (with `out_dir`).

    Returns:
        `DiagnosisResult`.
    """
    t_start = time.perf_counter()
    say = (lambda *a: None) if quiet else (lambda *a: print(*a, flush=True))
    if not isinstance(vehicle, Vehicle):
        vehicle = read_vehicle(vehicle)
    if not isinstance(recording, Recording):
        recording = read_recording(recording)
    identify = identify_fn or default_identify
    with jax.enable_x64(True):
        windows = make_windows(
            recording, vehicle, max_window=max_window, max_windows=max_windows, train_fraction=train_fraction
        )
        say(
            f"windows: {windows.num_windows} × {windows.t.shape[1] * windows.dt:.1f} s, "
            f"channels {', '.join(windows.channels)}"
        )
        train = windows.fit_data("train")
        coarse = Fitter(vehicle, train, dt=search_dt)
        fitter = Fitter(vehicle, train, dt=final_dt)
        # Base model from two starts (middle of the prior box, and a typical passenger car),
        # searched with the coarse step, then polished with the fine one.
        starts = [None, coarse.initial_z(typical_theta(vehicle))]
        base_c = min((identify(coarse, (), z, final_iters) for z in starts), key=lambda f: f.chi2)
        base = identify(fitter, (), base_c.z, max(4, final_iters // 2))
        say(
            f"base fit: χ²/dof {base.chi2_dof:.3f} ({base.iterations} it, "
            f"{time.perf_counter() - t_start:.0f} s)"
        )
        res, jac, ts, us = _stretches(base, windows)
        rate = 1.0 / windows.dt
        test0 = misspecification_test(
            seed, res, jac, rate=rate, channels=windows.channels, num_draws=num_draws
        )
        loc = locate_mismatch(test0, res, ts, us, rate=rate)
        detected = test0.p_value < alpha
        say(f"misspecification p = {test0.p_value:.4f} -> {'detected' if detected else 'not detected'}")
        # Search with the coarse step; every candidate warm-starts from the base fit.
        fits: dict[tuple, FitResult] = {(): base_c}
        allowed = set(EFFECT_NAMES if candidates is None else candidates)
        unknown = allowed - set(EFFECT_NAMES)
        if unknown:
            raise ValueError(f"candidates: unknown effect(s) {sorted(unknown)} (known: {EFFECT_NAMES})")
        for cand in [c for c in single_candidates() if c[0] in allowed]:
            fits[cand] = identify(coarse, cand, base_c.z, single_iters)
        singles = [r for r in rank(fits, base_c) if len(r.effects) == 1]
        say("singles: " + ", ".join(f"{r.name} {r.score:.1f}" for r in singles[:5]))
        pairs = pair_candidates([r.effects[0] for r in singles], top=top_pairs)
        by_name = {r.effects[0]: r for r in singles}
        for pair in pairs:
            lead = max(pair, key=lambda e: by_name[e].score)
            fits[pair] = identify(coarse, pair, fits[(lead,)].z, single_iters)
        ranked = search = rank(fits, base_c)
        polished: dict[tuple, FitResult] = {(): base}
        if detected and len(ranked[0].effects) == 2 and ranked[0].score >= STRONG:
            # A pair wins the search: the search caps iterations and a pair starts where its
            # lead single stopped, so polish the pair and both members at the fine step with
            # the same budget before deciding between them.
            pair = ranked[0].effects
            for cand in [pair, (pair[0],), (pair[1],)]:
                polished[cand] = identify(fitter, cand, fits[cand].z, final_iters)
            decision = rank(polished, base)
            chosen = choose(decision, detected)
            say("pair check: " + ", ".join(f"{r.name} {r.score:.1f}" for r in decision))
            # report the polished evidence for these three, so the ranking and choice agree
            ranked = merge(ranked, decision)
        else:
            chosen = choose(ranked, detected)
        if chosen in polished:
            final = polished[chosen]
        elif chosen:
            final = identify(fitter, chosen, fits[chosen].z, final_iters)
        else:
            final = base
        say(f"chosen: {label(chosen)} ({time.perf_counter() - t_start:.0f} s)")
        res1, jac1, _, _ = _stretches(final, windows)
        test1 = misspecification_test(
            seed + 1, res1, jac1, rate=rate, channels=windows.channels, num_draws=num_draws
        )
        full = windows.fit_data("valid", truncate=False)
        pred0 = fitter.predict(base.z, (), full)
        pred1 = fitter.predict(final.z, chosen, full) if chosen else pred0
        sep = separability(search, base_c)  # all at the search step, against its own none
    fit_before, fit_after = _held_metrics(pred0, windows), _held_metrics(pred1, windows)
    at_bounds = _at_bounds(final, fitter)
    chi_b = float(np.mean([v["chi2_dof"] for v in fit_before.values()]))
    chi_a = float(np.mean([v["chi2_dof"] for v in fit_after.values()]))
    top = ranked[0]
    second = ranked[1] if len(ranked) > 1 else None
    held_improved = bool(chi_a < chi_b) if chosen else None
    concl = verdict(detected, chosen, float(test1.p_value), alpha, held_improved)
    report = {
        "source": str(recording.source),
        "mismatch_detected": bool(detected),
        "p_value": float(test0.p_value),
        "alpha": alpha,
        "p_value_after": float(test1.p_value),
        "located": {
            "channels": loc.channels,
            "windows": loc.windows,
            "bands_hz": loc.bands_hz,
            "channel_scores": loc.channel_scores,
            "whiteness_p": loc.whiteness,
            "input_xcorr": loc.xcorr,
            "band_power_ratio": {
                c: {
                    f"{b[0]:g}-{b[1]:g}": float(test0.band_power_ratio[i, j])
                    for j, b in enumerate(test0.bands_hz)
                }
                for i, c in enumerate(windows.channels)
            },
        },
        "effects": _effect_rows(ranked),
        "chosen": list(chosen),
        "ranking_confidence": {
            "top": top.name,
            "probability": top.probability,
            "log_evidence_gap_to_next": float(top.score - second.score) if second else None,
            "next": second.name if second else None,
        },
        "separability": sep,
        "pairs_fitted": [label(p) for p in pairs],
        "pairs_skipped": "pairs not among the top "
        f"{top_pairs} single effects ({45 - len(pairs)} of 45) were not fitted"
        + ("" if candidates is None else f"; only {sorted(allowed)} were considered"),
        "fit": {"before": fit_before, "after": fit_after},
        # Validation: does the chosen fix also improve the held-out part (mean χ²/dof over
        # channels)? If not, the effect is absorbing some other mismatch on the fitted part.
        "held_out_improved": held_improved,
        "explained": concl["explained"],
        "verdict": concl["text"],
        "fit_train_chi2_dof": {"before": base.chi2_dof, "after": final.chi2_dof},
        "theta": {"before": _theta_dict(base.theta), "after": _theta_dict(final.theta)},
        "theta_std": {"before": _theta_dict(base.theta_std), "after": _theta_dict(final.theta_std)},
        "v0": {"before": base.v0.tolist(), "after": final.v0.tolist()},
        "at_bounds": at_bounds,
        "effect_params": final.effect_params,
        "effect_params_std": final.effect_std,
        "noise": {
            "model": "additive white Gaussian per channel",
            "sigma": {c: float(s) for c, s in zip(windows.channels, windows.sigma)},
            "source": windows.sigma_source,
        },
        "windows": {
            "spans_s": [
                [float(windows.t[w, 0]), float(windows.t[w][windows.valid[w]][-1])]
                for w in range(windows.num_windows)
            ],
            "held_out_from_s": windows.t_train_end.tolist(),
            "train_fraction": train_fraction,
        },
        "channels": list(windows.channels),
        "recording_warnings": list(recording.warnings),
        "method": {
            "identification": "MAP (Levenberg–Marquardt, forward-mode Jacobian, float64) "
            "+ Laplace covariance",
            "test": "max standardised low-band/high-band residual power ratio; null by simulated noise "
            f"through the linearised refit ({num_draws} draws)",
            "evidence": "score = BIC log Bayes factor vs 'none' + log prior odds (pairs "
            f"{PAIR_LOG_PRIOR:g}); strong if > {STRONG:g}",
            "solver_dt_s": {"search": coarse.dt, "final": fitter.dt},
        },
        "seconds": time.perf_counter() - t_start,
    }
    result = DiagnosisResult(
        report=report,
        windows=windows,
        base=base,
        final=final,
        ranked=ranked,
        test_before=test0,
        test_after=test1,
        localisation=loc,
        predictions={"before": pred0, "after": pred1},
        residual_stretches={"before": res, "after": res1, "t": ts},
    )
    if out_dir is not None:
        from ._report import write_report

        write_report(result, Path(out_dir), plots=plots)
    return result


__all__ = ["DiagnosisResult", "diagnose", "default_identify", "EFFECT_NAMES", "EFFECTS"]
