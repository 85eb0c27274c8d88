"""Driving beyond what a fit saw: the windows of a prediction that go past the fitted driving's
envelope, said per window, and their predictive band with the tyres' grip drawn from its prior.

The fit informs the friction factors only through the grip its own driving used; past its peak
the posterior's width on them is the curvature of a likelihood that never saw that grip, so
there they are drawn from the prior identify gives them on the fitted driving (`prior_box` at its
grip), its ceiling raised to what the window asks. A model without friction factors holds
vehicle.json's μ: they join it, drawn from that prior, only where the window leaves the tyres'
linear range, since below it the grip does not act.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np

from ..problem import Problem, parameter_names, prior_box
from ..problem.validation import ENVELOPE_UNITS, beyond_envelope, envelope, predictive_band
from ..simulator import GRAVITY
from ..simulator.effects import EFFECTS

#: The effect whose parameters are the tyres' grip.
GRIP = "tyre_friction"
#: Share of vehicle.json's μ·g past which Dugoff's tyre leaves its linear range and the grip acts.
LINEAR_GRIP = 0.5


def extrapolation(
    key,
    problem: Problem,
    mask: np.ndarray,
    fitted: Mapping[str, float],
    band: dict | None = None,
    draws: np.ndarray | None = None,
    noise_std=None,
    effects: Sequence[str] = (),
) -> tuple[dict | None, list[dict]]:
    """The windows of `problem` whose `mask` samples go beyond the `fitted` envelope, and `band`
    widened on them.

    Args:
        key: PRNG key of the widened band.
        problem: the driving predicted.
        mask: (W, K) the samples predicted (a held-out part, or all of another drive).
        fitted: the fitted driving's envelope (`vdsbi.problem.validation.envelope`).
        band: the posterior-predictive band (`vdsbi.problem.validation.predictive_band`) on `problem`, or
            None for the flags alone; `draws`, `noise_std` and `effects` are what it was made from.

    Returns:
        (the band, its `mask` samples of windows beyond the envelope where the grip acts replaced
        by the band with the grip drawn from its prior; the flagged windows of
        `vdsbi.problem.validation.beyond_envelope`, each whose band was so widened with "grip_from_prior":
        {parameter: [low, high]}).
    """
    import jax

    flagged = beyond_envelope(fitted, problem, mask)
    mu_g = problem.vehicle.friction * GRAVITY
    acting = [f for f in flagged if GRIP in effects or f["peaks"].get("ay", 0.0) > LINEAR_GRIP * mu_g]
    if band is None or not acting:
        return band, flagged
    widened = tuple(e for e in EFFECTS if e in {*effects, GRIP})
    peak = max(f["peaks"].get("ay", 0.0) for f in acting)
    bounds = _grip_bounds(problem, widened, fitted.get("ay"), peak)
    k_draws, k_band = jax.random.split(key)
    grip_draws = _with_grip(k_draws, np.asarray(draws, float), effects, widened, bounds)
    wide = predictive_band(k_band, problem, grip_draws, noise_std, widened)
    where = np.zeros_like(mask)
    for f in acting:
        where[f["window"]] = mask[f["window"]]
        f["grip_from_prior"] = {n: list(b) for n, b in bounds.items()}
    out = {q: np.where(where[..., None], wide[q], band[q]) for q in ("q05", "q50", "q95")}
    return out | {"n": band["n"]}, flagged


def held_out_extrapolation(
    summary: dict[str, Any], key, prob: Problem, full: Problem, band: dict, draws, noise_std, effects
) -> dict:
    """Writes posterior.json's `envelope` (the driving the estimate was fitted on) and
    `validation.extrapolation` (the held-out windows beyond the training part's envelope) into
    `summary`; returns `band` (made with `key`) widened on those windows (`extrapolation`)."""
    import jax

    summary["envelope"] = envelope_record(envelope(full, full.train))
    band, flagged = extrapolation(
        jax.random.fold_in(key, 1),  # its own key: the widened band's draws are not the band's
        prob,
        prob.held,
        envelope(prob, prob.train),
        band,
        draws,
        noise_std,
        effects,
    )
    if summary.get("validation"):
        summary["validation"]["extrapolation"] = flagged
    return band


def envelope_record(peaks: Mapping[str, float]) -> dict[str, Any]:
    """posterior.json's `envelope`: the peaks with their units and what they are."""
    return {
        "peaks": dict(peaks),
        "units": {q: ENVELOPE_UNITS[q] for q in peaks},
        "what": "peaks of the fitted driving (|a_y|, speed, |steer rate|, |a_x|, each averaged over "
        "0.2 s): a drive predicted beyond them is flagged per window",
    }


def _grip_bounds(
    problem: Problem, effects: Sequence[str], fitted_ay: float | None, peak_ay: float
) -> dict[str, tuple[float, float]]:
    """The grip parameters' prior: identify's on the fitted driving, its ceiling raised to what
    `peak_ay` asks."""
    mu_g = problem.vehicle.friction * GRAVITY
    fit_grip = None if fitted_ay is None else fitted_ay / mu_g
    low = prior_box(problem.vehicle, effects, grip=fit_grip)
    high = prior_box(problem.vehicle, effects, grip=max(peak_ay / mu_g, fit_grip or 0.0))
    names = [n for n in low if n.startswith(f"{GRIP}.")]
    return {n: (low[n][0], max(low[n][1], high[n][1])) for n in names}


def _with_grip(key, draws: np.ndarray, effects, widened, bounds: Mapping[str, tuple[float, float]]):
    """`draws` (in `effects`' parameter order) in `widened`'s, the grip drawn uniformly in `bounds`."""
    import jax

    names, out_names = parameter_names(effects), parameter_names(widened)
    out = np.stack([draws[:, names.index(n)] if n in names else np.nan * draws[:, 0] for n in out_names], -1)
    grip = [out_names.index(n) for n in bounds]
    low, high = (np.array([b[i] for b in bounds.values()]) for i in (0, 1))
    u = np.asarray(jax.random.uniform(key, (draws.shape[0], len(grip))), float)
    out[:, grip] = low + (high - low) * u
    return out
