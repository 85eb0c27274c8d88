"""`predict`: another recording of the car, simulated at an identify run's estimate with its effects
(and, on request, the posterior-predictive 90 % band) — the code the run's own held-out score uses."""

from __future__ import annotations

import dataclasses
import os
from pathlib import Path

import numpy as np
import pandas as pd

from ..io import InputError, read_recording
from ..problem import (
    ProblemSettings,
    band_coverage,
    channel_scores,
    make_problem,
    predict as predict_problem,
    predictive_band,
)
from ..simulator import Vehicle, get_effect
from ._export import load_run
from .outputs import PREDICTIVE


@dataclasses.dataclass(frozen=True)
class PredictResult:
    """A recording predicted.

    Attributes:
        frame: one row per compared sample of every usable window: `t`, `window`, then per channel
            the measured value, the prediction and (with the band) its 5 % and 95 % quantiles.
        scores: {channel: {nrmse, rmse, chi2_dof, samples}} of the prediction over those samples.
        coverage: {channel: share of measured samples inside the 90 % band} (empty without it).
    """

    frame: pd.DataFrame
    scores: dict
    coverage: dict


def predict(
    run_dir: str | os.PathLike, inputs, *, band: bool = False, draws: int = 100, seed: int = 0
) -> PredictResult:
    """Simulate the recording `inputs` at `run_dir`'s estimate, window by window, each from its own
    measured state, as `identify` scores its held-out part.

    Raises:
        InputError: no identify run in `run_dir`, or a recording the run's settings cannot take.
    """
    import jax

    post = load_run(run_dir)
    names = list(post["parameters"])
    effects = tuple(post.get("effects", []))
    vehicle = Vehicle.from_dict(post["vehicle"])
    rec = read_recording(inputs) if isinstance(inputs, (str, os.PathLike)) else inputs
    summary = post["problem"]
    cutoff = (summary.get("filter") or {}).get("cutoff_hz")
    settings = ProblemSettings(longitudinal=post["problem"]["longitudinal"], held_out=0.0, bandwidth=cutoff)
    prob = make_problem(rec, vehicle, settings)
    values = np.array([post["parameters"][n]["estimate"] for n in names])
    effect_values = _effect_values(values, names, effects)
    pred, ok = predict_problem(prob, values[:6], effects, effect_values)
    if not ok:
        raise InputError(rec.source, "inputs", "the model leaves its domain at the estimate")
    mask = prob.valid
    coverage, q = {}, None
    if band:
        samples = pd.read_csv(Path(run_dir) / PREDICTIVE)[names].to_numpy()
        noise = np.array([post["noise_model"][c]["residual_rms"] for c in prob.channels])
        q = predictive_band(jax.random.key(seed), prob, samples[:draws], noise, effects)
        coverage = band_coverage(prob, q, mask)
    w_idx, k_idx = np.nonzero(mask)
    cols = {"t": prob.t_out[w_idx, k_idx], "window": w_idx}
    for i, c in enumerate(prob.channels):
        cols[c] = prob.y[w_idx, k_idx, i]
        cols[f"{c}_predicted"] = pred[w_idx, k_idx, i]
        if q is not None:
            cols[f"{c}_q05"] = q["q05"][w_idx, k_idx, i]
            cols[f"{c}_q95"] = q["q95"][w_idx, k_idx, i]
    return PredictResult(pd.DataFrame(cols), channel_scores(prob, pred, mask), coverage)


def _effect_values(values: np.ndarray, names: list[str], effects) -> dict:
    value = lambda e, p: float(values[names.index(f"{e}.{p}")])
    return {e: {p: value(e, p) for p in get_effect(e).param_names} for e in effects}
