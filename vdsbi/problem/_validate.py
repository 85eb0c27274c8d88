"""How well a parameter set predicts driving the fit never saw."""

from __future__ import annotations

from collections.abc import Mapping, Sequence

import numpy as np

from ..simulator import PARAM_NAMES
from ..simulator.effects import effect_params_from
from ..simulator.solvers import Solver
from ._problem import Problem
from ._simulate import simulate_draws, windowed_model


def channel_scores(problem: Problem, predicted: np.ndarray, mask: np.ndarray) -> dict[str, dict[str, float]]:
    """Per channel NRMSE (RMS error / std of the measurement) and χ²/dof over `mask`.

    Args:
        problem: supplies the measurement `y` (W, K, C) and noise σ (C,).
        predicted: (W, K, C) noise-free predictions on the same samples.
        mask: (W, K) samples scored.
    """
    out = {}
    for c, name in enumerate(problem.channels):
        y, p = problem.y[..., c][mask], predicted[..., c][mask]
        err = p - y
        out[name] = {
            "nrmse": float(np.sqrt(np.mean(err**2)) / (np.std(y) + 1e-12)),
            "rmse": float(np.sqrt(np.mean(err**2))),
            "chi2_dof": float(np.mean((err / problem.sigma[c]) ** 2)),
            "samples": int(mask.sum()),
        }
    return out


def predict(
    problem: Problem,
    theta,
    effects: Sequence[str] = (),
    effect_values: Mapping[str, object] | None = None,
    solver: Solver = Solver(),
) -> tuple[np.ndarray, bool]:
    """(W, K, C) noise-free compared samples of every window of `problem` at θ."""
    wm = windowed_model(problem, effects, solver)
    _, params = effect_params_from(effects, effect_values)
    ys, ok = simulate_draws(
        None, wm, np.asarray(theta, float)[None], effect_params=tuple(p[None] for p in params)
    )
    return np.asarray(ys[0]), bool(ok[0])


def validate(
    problem: Problem,
    theta,
    effects: Sequence[str] = (),
    effect_values: Mapping[str, object] | None = None,
    solver: Solver = Solver(),
) -> dict:
    """Scores of θ on the held-out part of `problem` (the `validation` block of posterior.json).

    Returns:
        {"theta": {name: value}, "ok": solved, "channels": {channel: {nrmse, rmse, chi2_dof,
        samples}}, "held_out_seconds": …}; channels are empty if nothing is held out.
    """
    held = problem.select("held")
    pred, ok = predict(held, theta, effects, effect_values, solver)
    out = {
        "theta": {n: float(v) for n, v in zip(PARAM_NAMES, np.asarray(theta, float))},
        "ok": ok,
        "held_out_seconds": problem.summary()["held_out_seconds"],
        "channels": channel_scores(held, pred, held.held) if ok else {},
    }
    if effects:
        out["effects"] = {e: dict(v) for e, v in (effect_values or {}).items()}
    return out


def predictive_band(
    key,
    problem: Problem,
    draws,
    noise_std,
    effects: Sequence[str] = (),
    solver: Solver = Solver(),
) -> dict:
    """The 5/50/95 % posterior-predictive band of every window's compared samples.

    Each draw (…, 6 + P: θ then the effects' parameters) is simulated noise-free, and Gaussian
    noise of the noise model's per-sample std (C,) is added: the band a new recording of the
    same driving should fall in, model error included.

    Returns:
        {"q05", "q50", "q95": (W, K, C) arrays, "n": draws that simulated}.
    """
    import jax

    from ._parameters import split_parameters

    wm = windowed_model(problem, effects, solver)
    theta, ep = split_parameters(np.asarray(draws, float), effects)
    ys, ok = simulate_draws(None, wm, theta, effect_params=ep)
    ys = np.asarray(ys)[np.asarray(ok)]
    ys = ys + np.asarray(noise_std) * np.asarray(jax.random.normal(key, ys.shape))
    if not ys.shape[0]:
        nan = np.full(problem.y.shape, np.nan)
        return {"q05": nan, "q50": nan, "q95": nan, "n": 0}
    q = np.quantile(ys, [0.05, 0.5, 0.95], axis=0)
    return {"q05": q[0], "q50": q[1], "q95": q[2], "n": int(ys.shape[0])}


def band_coverage(problem: Problem, band: dict, mask: np.ndarray) -> dict[str, float | None]:
    """Share of `mask`'s measured samples inside the 90 % band, per channel (None: no band)."""
    inside = (problem.y >= band["q05"]) & (problem.y <= band["q95"])
    return {
        c: (float(inside[..., i][mask].mean()) if band["n"] and mask.any() else None)
        for i, c in enumerate(problem.channels)
    }
