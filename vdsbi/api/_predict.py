"""`predict`: another recording of the car, simulated at an identify run's estimate with its effects
(and, on request, the posterior-predictive 90 % band) — the code the run's own held-out score uses —
with the windows that go beyond the driving the estimate was fitted on."""

from __future__ import annotations

import dataclasses
import os
from pathlib import Path

import numpy as np
import pandas as pd

from ..io import InputError, read_recording
from ..problem import ProblemSettings, make_problem, parameter_name
from ..problem.validation import band_coverage, channel_scores, predict as predict_problem, predictive_band
from ..simulator import PARAM_NAMES, Vehicle
from ..simulator.effects import get_effect
from ._export import load_run
from ._extrapolation import extrapolation
from .outputs import PREDICTIVE


@dataclasses.dataclass(frozen=True)
class PredictResult:
    """A recording predicted.

    Attributes:
        frame: one row per compared sample of every usable window: `t`, `window`,
            `beyond_envelope` (its window goes beyond the fitted driving), then per channel the
            measured value, the prediction and (with the band) its 5 % and 95 % quantiles.
        scores: {channel: {nrmse, rmse, chi2_dof, samples}} of the prediction over those samples.
        coverage: {channel: share of measured samples inside the 90 % band} (empty without it).
        extrapolation: the windows beyond the envelope of the driving the estimate was fitted on
            (`vdsbi.problem.validation.beyond_envelope`; with the band, those whose grip was drawn from its
            prior say so), or None where the run stores no envelope.
    """

    frame: pd.DataFrame
    scores: dict
    coverage: dict
    extrapolation: list[dict] | None = None


def predict(
    run_dir: str | os.PathLike, inputs, *, band: bool = False, draws: int = 100, seed: int = 0
) -> PredictResult:
    """Simulate the recording `inputs` at `run_dir`'s estimate, window by window, each from its own
    measured state, as `identify` scores its held-out part. Windows beyond the envelope of the
    driving the run was fitted on are flagged, and their band draws the grip from its prior
    (`extrapolation`).

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
    # The run's own window length: a window simulated from its measured start state is scored as
    # identify scored its held-out part.
    spans = [w["t1"] - w["t0"] for w in summary.get("windows", ())]
    window = float(np.ceil(max(spans) * 10.0) / 10.0) if spans else None
    settings = ProblemSettings(
        longitudinal=summary["longitudinal"],
        held_out=0.0,
        bandwidth=cutoff,
        **({"max_window": window} if window else {}),
    )
    prob = make_problem(rec, vehicle, settings)
    values = np.array([post["parameters"][n]["estimate"] for n in names])
    effect_values = _effect_values(values, names, effects)
    pred, ok = predict_problem(prob, values[: len(PARAM_NAMES)], effects, effect_values)
    if not ok:
        raise InputError(rec.source, "inputs", "the model leaves its domain at the estimate")
    mask = prob.valid
    q = samples = noise = None
    key = jax.random.key(seed)
    if band:
        samples = pd.read_csv(Path(run_dir) / PREDICTIVE)[names].to_numpy()[:draws]
        noise = np.array([post["noise_model"][c]["residual_rms"] for c in prob.channels])
        q = predictive_band(key, prob, samples, noise, effects)
    fitted = (post.get("envelope") or {}).get("peaks")
    flagged = None
    if fitted is not None:
        # Its own key: the widened band's draws are not the band's.
        q, flagged = extrapolation(jax.random.fold_in(key, 1), prob, mask, fitted, q, samples, noise, effects)
    coverage = {} if q is None else band_coverage(prob, q, mask)
    w_idx, k_idx = np.nonzero(mask)
    beyond = np.isin(w_idx, [f["window"] for f in flagged or ()])
    cols = {"t": prob.t_out[w_idx, k_idx], "window": w_idx, "beyond_envelope": beyond}
    for i, c in enumerate(prob.channels):
        cols[c] = prob.y[w_idx, k_idx, i]
        cols[f"{c}_predicted"] = pred[w_idx, k_idx, i]
        if q is not None:
            cols[f"{c}_q05"] = q["q05"][w_idx, k_idx, i]
            cols[f"{c}_q95"] = q["q95"][w_idx, k_idx, i]
    return PredictResult(pd.DataFrame(cols), channel_scores(prob, pred, mask), coverage, flagged)


def _effect_values(values: np.ndarray, names: list[str], effects) -> dict:
    value = lambda e, p: float(values[names.index(parameter_name(e, p))])
    return {e: {p: value(e, p) for p in get_effect(e).param_names} for e in effects}
