"""What a recording measures of the car's own motion, as every model start and input uses it."""

from __future__ import annotations

import numpy as np

from ..io import Recording

#: Smoothing of the measured ax that loads the tyres and of the yaw rate that starts a window,
#: s: IMU vibration (several m/s² on real cars) must not move the loads or the start state.
SMOOTHING = 0.25


def running_mean(x: np.ndarray, n: int) -> np.ndarray:
    """Centred running mean over `n` samples, ends held."""
    if n <= 1:
        return x
    pad = np.pad(x, (n // 2, n - 1 - n // 2), mode="edge")
    return np.convolve(pad, np.ones(n) / n, mode="valid")


def _samples(rec: Recording) -> int:
    return max(1, int(round(SMOOTHING * rec.rate)))


def measured_longitudinal(rec: Recording, wheel_radius: float) -> tuple[np.ndarray, np.ndarray]:
    """(T,) speed and (T,) smoothed longitudinal specific force of the speed-driven mode:
    `Recording.inputs`' rule (vx else wheel speeds × radius; ax else the speed's slope),
    then ax smoothed over `SMOOTHING` s."""
    inputs = rec.inputs(longitudinal="speed", wheel_radius=wheel_radius)
    return np.asarray(inputs.speed), running_mean(np.asarray(inputs.accel), _samples(rec))


def smoothed_yaw_rate(rec: Recording) -> np.ndarray | None:
    """(T,) yaw rate smoothed over `SMOOTHING` s (a window's start value), or None."""
    if "yaw_rate" not in rec.channels:
        return None
    return running_mean(rec.channels["yaw_rate"], _samples(rec))
