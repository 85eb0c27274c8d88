"""Uniform-grid check of time stamps, resampling to the model rate, and the running mean."""

from __future__ import annotations

import numpy as np

from ._errors import InputError

#: Relative tolerance of a timestamp's deviation from the fitted uniform grid (1 % of dt) ...
GRID_RTOL = 0.01
#: ... or half a millisecond, so time stamps written with millisecond precision pass (capped at
#: a quarter of dt, so one dropped sample, which shifts the grid by about dt/2, never passes).
GRID_ATOL = 0.5e-3
#: Below this rate `t` is not in seconds (a 100-Hz log stamped in milliseconds reads as 0.1 Hz):
#: refused. Any rate above it is resampled, as the recording format asks.
MIN_RATE = 2.0
#: Below this rate the body's dynamics (1–3 Hz) are barely resolved: read, with a warning.
LOW_RATE = 20.0


def noise_gain(original_rate: float, rate: float) -> float:
    """The factor from a std per recorded sample to the model-rate white noise of the same
    low-frequency density, sqrt(rate / original_rate); 1 for a file at the model rate."""
    ratio = rate / original_rate
    return 1.0 if abs(ratio - 1.0) < 1e-3 else float(np.sqrt(ratio))


def check_uniform(t: np.ndarray, source: str) -> float:
    """Check that strictly increasing `t` (s) is uniform within tolerance; return dt (s).

    Raises:
        InputError: naming `source` and field `t` on an irregular grid or an implausible rate.
    """
    n = t.shape[0]
    k = np.arange(n)
    dt, t0 = np.polyfit(k, t - t[0], 1)  # least-squares grid, so jitter at the ends does not tilt it
    t0 += t[0]
    if not 1.0 / dt >= MIN_RATE * (1.0 - 1e-6):  # the fitted dt of exact stamps is ~1e-15 off
        raise InputError(
            source,
            "t",
            f"sample rate {1.0 / dt:.3g} Hz is below {MIN_RATE:g} Hz; expected t in seconds "
            "(is it in milliseconds or nanoseconds?)",
        )
    resid = np.abs(t - (t0 + dt * k))
    tol = max(GRID_RTOL * dt, min(GRID_ATOL, 0.25 * dt)) + 1e-9 * max(1.0, abs(t[-1]))
    k = int(np.argmax(resid))
    if resid[k] > tol:
        steps = np.diff(t)
        j = int(np.argmax(np.abs(steps - np.median(steps))))
        raise InputError(
            source,
            "t",
            f"irregular time stamps: step {steps[j]:.6g} s at row {j + 2} (t = {t[j + 1]:.6g} s) "
            f"where the median step is {np.median(steps):.6g} s (t is {resid[k]:.3g} s off a uniform "
            f"grid, tolerance {tol:.3g} s); expected a uniform sample rate (gaps or dropped samples?)",
        )
    return float(dt)


def resample(t: np.ndarray, columns: dict[str, np.ndarray], rate: float) -> tuple[np.ndarray, dict]:
    """Resample uniform series onto t0 + k/rate, k = 0..floor(duration·rate).

    The output grid starts at t[0]. Linear interpolation; when downsampling, each series is
    first averaged over a moving window one target step long (a box anti-alias filter), so
    high-rate sensor noise does not alias.

    Args:
        t: (T,) uniform time stamps, s.
        columns: name -> (T,) series.
        rate: target rate, Hz.

    Returns:
        (t_new, columns_new) with t_new of shape (T',).
    """
    dt_in = (t[-1] - t[0]) / (t.shape[0] - 1)
    dt = 1.0 / rate
    if abs(dt_in - dt) <= 1e-6 * dt:
        return t[0] + dt * np.arange(t.shape[0]), dict(columns)
    n_out = int(np.floor((t[-1] - t[0]) / dt + 1e-9)) + 1
    t_new = t[0] + dt * np.arange(n_out)
    width = int(round(dt / dt_in))
    out = {}
    for name, x in columns.items():
        if width > 1:
            kernel = np.ones(width) / width
            pad = np.pad(x, (width // 2, width - 1 - width // 2), mode="edge")
            x = np.convolve(pad, kernel, mode="valid")
        out[name] = np.interp(t_new, t, x)
    return t_new, out


def running_mean(x: np.ndarray, n: int) -> np.ndarray:
    """Centred running mean over `n` samples, ends held."""
    if n <= 1:
        return x
    pad = np.pad(x, (n // 2, n - 1 - n // 2), mode="edge")
    return np.convolve(pad, np.ones(n) / n, mode="valid")
