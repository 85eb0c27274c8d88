"""The driving envelope of a problem's part — its peak |lateral acceleration|, speed, |steer rate|
and |longitudinal acceleration| — and the windows of other driving that go beyond it: where a
prediction extrapolates from what a fit saw."""

from __future__ import annotations

from collections.abc import Mapping

import numpy as np
from scipy.ndimage import uniform_filter1d

from ._problem import Problem, compared_speed

#: The envelope's quantities and their units.
ENVELOPE_UNITS = {"ay": "m/s²", "speed": "m/s", "steer_rate": "rad/s", "ax": "m/s²"}
#: Signals are averaged over this span before their peaks are taken, s: the peak of a manoeuvre
#: rather than of sensor noise, alike at any sample rate.
SMOOTHING = 0.2
#: A peak above the fitted one by at most this share plus `SLACK` is the same driving.
TOLERANCE = 0.05
#: Absolute slack per quantity, in its unit: small against a manoeuvre, above what noise leaves
#: after smoothing, so that a fit that barely brakes does not flag every window that brakes a little.
SLACK = {"ay": 0.3, "speed": 0.5, "steer_rate": 0.01, "ax": 0.3}


def window_peaks(problem: Problem, mask: np.ndarray) -> list[dict[str, float]]:
    """Per window, the peak of each quantity over its `mask` samples ({} where it has none).

    Args:
        problem: the driving; the lateral acceleration is the measured ay, else speed × yaw rate;
            the speed is `compared_speed`'s; the longitudinal acceleration is the speed mode's
            measured one, else ax. A quantity the problem cannot give is left out.
        mask: (W, K) compared samples to take the peaks over.

    Returns:
        W dicts {quantity: peak of its |smoothed signal|, in `ENVELOPE_UNITS`' units}.
    """
    signals = _signals(problem)
    return [
        {q: float(np.max(np.abs(s[w][mask[w]]))) for q, s in signals.items()} if mask[w].any() else {}
        for w in range(problem.num_windows)
    ]


def envelope(problem: Problem, mask: np.ndarray) -> dict[str, float]:
    """The peak of each quantity (`window_peaks`) over all of `mask`'s samples, 4 significant digits."""
    peaks: dict[str, float] = {}
    for p in window_peaks(problem, mask):
        for q, v in p.items():
            peaks[q] = max(peaks.get(q, 0.0), v)
    return {q: _rounded(v) for q, v in peaks.items()}


def beyond_envelope(fitted: Mapping[str, float], problem: Problem, mask: np.ndarray) -> list[dict]:
    """The windows whose `mask` samples go beyond the `fitted` envelope.

    A quantity is beyond where its window peak exceeds the fitted one by more than `TOLERANCE`
    of it plus its `SLACK`; quantities only one side has are not compared.

    Returns:
        [{"window": index, "t0", "t1": s (the masked samples' span), "peaks": {quantity: this
        window's peak}, "beyond": {quantity: [fitted peak, this peak]}}] for each window beyond
        in at least one quantity, in window order.
    """
    out = []
    for w, peaks in enumerate(window_peaks(problem, mask)):
        beyond = {
            q: [float(fitted[q]), _rounded(v)]
            for q, v in peaks.items()
            if q in fitted and v > fitted[q] * (1.0 + TOLERANCE) + SLACK[q]
        }
        if beyond:
            t = problem.t_out[w][mask[w]]
            out.append(
                {
                    "window": w,
                    "t0": round(float(t.min()), 3),
                    "t1": round(float(t.max()), 3),
                    "peaks": {q: _rounded(v) for q, v in peaks.items()},
                    "beyond": beyond,
                }
            )
    return out


def _signals(problem: Problem) -> dict[str, np.ndarray]:
    """{quantity: (W, K) smoothed signal at the compared samples} for each quantity available."""
    k = problem.y.shape[1]
    compared = lambda a: np.asarray(a, float)[:, :: problem.factor][:, :k]
    smooth = lambda a, dt: uniform_filter1d(
        np.asarray(a, float), max(1, round(SMOOTHING / dt)), axis=1, mode="nearest"
    )
    channel = lambda c: problem.y[..., problem.channels.index(c)] if c in problem.channels else None
    speed = compared_speed(problem)
    lateral = channel("ay")
    if lateral is None and speed is not None and "yaw_rate" in problem.channels:
        lateral = speed * channel("yaw_rate")
    longitudinal = compared(problem.accel) if problem.accel is not None else channel("ax")
    steer_rate = compared(np.gradient(smooth(problem.u[..., 0], problem.dt), problem.dt, axis=1))
    found = {"ay": lateral, "speed": speed, "ax": longitudinal}
    out = {q: smooth(s, problem.compared_dt) for q, s in found.items() if s is not None}
    return out | {"steer_rate": steer_rate}


def _rounded(v: float) -> float:
    return float(f"{v:.4g}")
