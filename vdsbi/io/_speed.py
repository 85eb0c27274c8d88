"""The forward speed of a recording that measures none: from ax, and ay ≈ v_x·r where it turns.

A torque-driven recording need not carry vx or wheel speeds: the model drives the wheels by
the torques and needs a speed only at each window start (and to tell moving from standing
and cornering from straight driving). The IMU gives it in the car's own terms. The integral
of the longitudinal specific force follows the speed's changes; its offset and slow drift
(accelerometer bias, road grade) are fixed by the kinematic relation a_y = dv_y/dt + v_x·r ≈
v_x·r, which holds wherever the car turns clearly (the smoothed dv_y/dt is small next to v_x·r).
"""

from __future__ import annotations

import dataclasses

import numpy as np

from ._errors import InputError
from ._recording import Recording

#: Channels the estimate needs.
NEEDS: tuple[str, ...] = ("ax", "ay", "yaw_rate")
#: Centred running mean, s, over ax, ay and the yaw rate (vibration, transients of dv_y/dt).
SMOOTHING = 0.5
#: A sample enters the fit where the smoothed |r| is at least this, rad/s (0.75 m/s² at
#: 15 m/s), and `NOISE_MULTIPLE` noise stds of the smoothed yaw rate.
MIN_YAW_RATE = 0.05
NOISE_MULTIPLE = 10.0
STEADY = 0.25
#: Least turning, s in all, that fixes the speed.
MIN_TURNING = 1.0
#: Knot spacing of the piecewise-linear drift correction, s.
DRIFT_SPACING = 20.0
#: Prior std of the drift rate, m/s² (an accelerometer bias plus a 1 % grade): where the drive
#: does not turn, the correction changes by about this per second at most.
DRIFT_RATE = 0.1
#: Std of ay − v_x·r at the fitted samples, m/s² (road bank, body roll, side-slip changes).
RELATION_STD = 0.3


@dataclasses.dataclass(frozen=True)
class SpeedEstimate:
    """A forward speed estimated from ax, ay and the yaw rate (`estimate_speed`).

    Attributes:
        speed: (T,) forward speed, m/s, >= 0.
        turning: seconds of driving whose ay ≈ v_x·r fixed it.
        residual: RMS of the smoothed ay − v_x·r over those samples, m/s².
        drift: mean rate of the fitted correction to the integrated ax, m/s² (bias and grade).
    """

    speed: np.ndarray
    turning: float
    residual: float
    drift: float

    def describe(self) -> str:
        """One line for a report."""
        return (
            "no speed channel: initial speeds estimated from ax and ay ≈ vx·r (the integral of ax "
            f"with a correction of {self.drift:+.3f} m/s² mean drift, fitted over {self.turning:.1f} s "
            f"of steady turning with |r| >= {MIN_YAW_RATE:g} rad/s; RMS of ay − vx·r "
            f"{self.residual:.2f} m/s²)"
        )


def _running_mean(x: np.ndarray, n: int) -> np.ndarray:
    pad = np.pad(x, (n // 2, n - 1 - n // 2), mode="edge")
    return np.convolve(pad, np.ones(n) / n, mode="valid")


def _hats(t: np.ndarray, knots: np.ndarray) -> np.ndarray:
    """(T, K) piecewise-linear interpolation weights of `t` on `knots`."""
    eye = np.eye(knots.shape[0])
    return np.stack([np.interp(t, knots, eye[k]) for k in range(knots.shape[0])], axis=-1)


def estimate_speed(rec: Recording) -> SpeedEstimate:
    """The forward speed v(t) = ∫ a_x dt + d(t), d piecewise linear, from ay ≈ v·r.

    d has knots every `DRIFT_SPACING` s (two at least: an offset and a drift rate) and is fitted
    by least squares to r·(∫a_x + d) ≈ a_y over the samples where the car turns steadily (|r|
    above `MIN_YAW_RATE` and its noise, |dr/dt| <= `STEADY`·|r|), with a Gaussian prior of std
    `DRIFT_RATE` on its slope, so a stretch without turning keeps the drift of its neighbours.
    ax, ay and r are smoothed over `SMOOTHING` s first.

    Raises:
        InputError: ax, ay or yaw_rate missing, or the drive turns less than `MIN_TURNING` s.
    """
    missing = [c for c in NEEDS if c not in rec.channels]
    if missing:
        raise InputError(
            rec.source,
            "vx",
            f"no vx or wheel-speed channel, and without {', '.join(missing)} the speed cannot be "
            "estimated from ax and ay ≈ vx·r; expected vx, the wheel speeds, or ax, ay and yaw_rate",
        )
    n = max(1, int(round(SMOOTHING * rec.rate)))
    ax, ay, r = (_running_mean(rec.channels[c], n) for c in NEEDS)
    integral = np.concatenate([[0.0], np.cumsum(0.5 * (ax[1:] + ax[:-1])) * rec.dt])
    raw = rec.channels["yaw_rate"]
    noise = 1.4826 * np.median(np.abs(np.diff(raw) - np.median(np.diff(raw)))) / np.sqrt(2.0)
    turning = np.abs(r) >= max(MIN_YAW_RATE, NOISE_MULTIPLE * noise / np.sqrt(n))
    turning &= np.abs(np.gradient(r, rec.dt)) <= STEADY * np.abs(r)
    turning[: n // 2] = turning[rec.num_samples - n // 2 :] = False  # running-mean edges
    seconds = float(turning.sum()) * rec.dt
    if seconds < MIN_TURNING:
        raise InputError(
            rec.source,
            "vx",
            f"no vx or wheel-speed channel, and the drive turns (|yaw_rate| >= {MIN_YAW_RATE:g} rad/s) "
            f"for only {seconds:.1f} s, too little to estimate the speed from ay ≈ vx·r (needs "
            f"{MIN_TURNING:g} s); expected vx or the wheel speeds omega_front, omega_rear",
        )
    k = max(2, int(np.ceil(rec.duration / DRIFT_SPACING)) + 1)
    knots = np.linspace(rec.t[0], rec.t[-1], k)
    basis = _hats(rec.t, knots)
    # Rows are whitened: n neighbouring samples share one smoothed error.
    data_a = r[turning, None] * basis[turning] / (RELATION_STD * np.sqrt(n))
    data_b = (ay[turning] - r[turning] * integral[turning]) / (RELATION_STD * np.sqrt(n))
    slope = (np.eye(k, k, 1) - np.eye(k))[:-1] / (DRIFT_RATE * np.diff(knots)[:, None])
    coef, *_ = np.linalg.lstsq(np.vstack([data_a, slope]), np.r_[data_b, np.zeros(k - 1)], rcond=None)
    speed = integral + basis @ coef
    residual = float(np.sqrt(np.mean((ay - r * speed)[turning] ** 2)))
    drift = float((coef[-1] - coef[0]) / max(rec.duration, rec.dt))
    return SpeedEstimate(np.maximum(speed, 0.0), seconds, residual, drift)


def forward_speed(rec: Recording, wheel_radius: float | None = None) -> np.ndarray | None:
    """(T,) forward speed, m/s: the measured one (`Recording.speed`), else the estimate of
    `estimate_speed` where the recording allows one, else None."""
    speed = rec.speed(wheel_radius)
    if speed is not None or any(c in rec.channels for c in ("vx", "omega_front", "omega_rear")):
        return speed
    try:
        return estimate_speed(rec).speed
    except InputError:
        return None
