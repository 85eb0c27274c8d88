"""What a recording measures of the car's own motion, as every model start and input uses it."""

from __future__ import annotations

import numpy as np

from ..io import Recording, estimate_speed, forward_speed, running_mean
from ..simulator.models import AbstractVehicleModel, SpeedDriven

#: Smoothing of the measured ax that loads the tyres and of the yaw rate that starts a window,
#: s: IMU vibration (several m/s² on real cars) must not move the loads or the start state.
SMOOTHING = 0.25


def _samples(rec: Recording) -> int:
    return max(1, int(round(SMOOTHING * rec.rate)))


def measured_longitudinal(rec: Recording, wheel_radius: float) -> tuple[np.ndarray, np.ndarray]:
    """(T,) speed and (T,) smoothed longitudinal specific force of the speed-driven mode:
    `Recording.inputs`' rule (vx else wheel speeds × radius; ax else the speed's slope),
    then ax smoothed over `SMOOTHING` s."""
    inputs = rec.inputs(longitudinal=SpeedDriven, wheel_radius=wheel_radius)
    return np.asarray(inputs.speed), running_mean(np.asarray(inputs.accel), _samples(rec))


def start_speed(rec: Recording, wheel_radius: float) -> tuple[np.ndarray, str | None]:
    """(T,) speed, m/s, that starts each torque-driven window, and None, or the line that says
    it is estimated: the measured speed (vx, else the wheel speeds × radius), else
    `vdsbi.io.estimate_speed`'s from ax and ay ≈ vx·r.

    Raises:
        InputError: no measured speed, and none can be estimated (naming what is missing).
    """
    speed = rec.speed(wheel_radius)
    if speed is not None:
        return speed, None
    estimate = estimate_speed(rec)
    return estimate.speed, estimate.describe()


def longitudinal_arrays(
    rec: Recording, wheel_radius: float, model: type[AbstractVehicleModel]
) -> tuple[np.ndarray, np.ndarray]:
    """(T,) speed and (T,) smoothed longitudinal specific force of a problem simulated by `model`:
    `SpeedDriven`'s `measured_longitudinal`; for `TorqueDriven` `start_speed` (window starts only)
    and zeros."""
    if issubclass(model, SpeedDriven):
        return measured_longitudinal(rec, wheel_radius)
    speed = start_speed(rec, wheel_radius)[0]
    return speed, np.zeros_like(speed)


def smoothed_yaw_rate(rec: Recording) -> np.ndarray | None:
    """(T,) yaw rate smoothed over `SMOOTHING` s (a window's start value), or None."""
    if "yaw_rate" not in rec.channels:
        return None
    return running_mean(rec.channels["yaw_rate"], _samples(rec))


#: Median RMS speed error over windows, m/s, above which recorded torques are taken not to be
#: the torques at the wheels (commanded ones, a wrong sign or split).
TORQUE_SPEED_TOLERANCE = 3.0


def torque_speed_error(rec: Recording, wheel_radius: float, mass: float, spans) -> float | None:
    """Median over windows [(t0, t1)] of the RMS error of the speed a point mass driven by the
    recorded torques alone reaches from each window's start speed (`vdsbi.io.forward_speed`;
    None without torques or speed). Applied torques on a car without large resistances stay
    within a few tenths of a m/s per 10–20 s window; commanded torques on a real car miss by
    metres per second."""
    speed = forward_speed(rec, wheel_radius)
    if not rec.has_torques or speed is None or not spans:
        return None
    errors = []
    for t0, t1 in spans:
        i0, i1 = np.searchsorted(rec.t, [t0 - 1e-9, t1 + 1e-9])
        a = (rec.torque_front[i0:i1] + rec.torque_rear[i0:i1]) / (wheel_radius * mass)
        v = speed[i0] + np.concatenate([[0.0], np.cumsum(0.5 * (a[1:] + a[:-1])) * rec.dt])
        errors.append(float(np.sqrt(np.mean((v - speed[i0:i1]) ** 2))))
    return float(np.median(errors))
