"""`simulate`: one drive of the model, driven by a recording's inputs or an `Inputs` profile."""

from __future__ import annotations

import dataclasses
import os
from collections.abc import Mapping, Sequence

import numpy as np

from ..io import InputError, Recording
from ..problem import longitudinal_mode, measured_longitudinal, smoothed_yaw_rate
from ..simulator import CHANNELS, Inputs, Vehicle
from ..simulator.effects import EffectSettings
from ..simulator.models import (
    AbstractVehicleModel,
    LongitudinalChoice,
    SpeedDriven,
    TorqueDriven,
    model_class,
)
from ._validate import (
    PROFILE_V0,
    NoiseName,
    checked_theta,
    checked_v0,
    first_speed,
    load_vehicle,
    sensor_noise,
)


@dataclasses.dataclass
class SimulateResult:
    """One simulation.

    Attributes:
        t: (T,) time stamps, s (float64, from the inputs' t0 and dt).
        dt: time step, s.
        readings: (T, 6) channels in CHANNELS order, with the requested sensor noise.
        ok: whether the solve stayed in the model's domain (no noise is added when not).
        theta: (6,) the parameters simulated, PARAM_NAMES order.
        v0: initial speed, m/s.
        steer, torque_front, torque_rear: (T,) the inputs as given (float64; a recording's own
            values, not their float32 copies inside the simulator).
    """

    t: np.ndarray
    dt: float
    readings: np.ndarray
    ok: bool
    theta: np.ndarray
    v0: float
    steer: np.ndarray
    torque_front: np.ndarray | None
    torque_rear: np.ndarray | None

    def to_frame(self):
        import pandas as pd

        df = pd.DataFrame(self.readings, columns=list(CHANNELS))
        df.insert(0, "t", self.t)
        return df

    def to_recording(self, source: str = "simulation") -> Recording:
        """The drive as a `vdsbi.io.Recording` (inputs and all six channels)."""
        ys = np.asarray(self.readings, dtype=float)
        rate = 1.0 / self.dt
        return Recording(
            t=self.t,
            steer=self.steer,
            torque_front=self.torque_front,
            torque_rear=self.torque_rear,
            channels={c: ys[:, i] for i, c in enumerate(CHANNELS)},
            source=source,
            rate=rate,
            original_rate=rate,
        )


def simulate(
    theta: Mapping[str, float] | Sequence[float] | np.ndarray,
    inputs: Inputs | Recording | None,
    vehicle: str | os.PathLike | Vehicle | None = None,
    *,
    v0: float | None = 10.0,
    effects: EffectSettings = EffectSettings(),
    noise: NoiseName = "none",
    seed: int = 0,
    longitudinal: LongitudinalChoice = "auto",
) -> SimulateResult:
    """One simulation of `vehicle` (a Vehicle, a file, or None for the built-in one).

    Args:
        theta: (6,) array or {name: value}; missing names take the seed's Table II values.
        inputs: an `Inputs` profile, a `Recording` whose steer and torques drive the model, or
            None for the seed profile (`vdsbi.simulator.seed_profile`).
        v0: initial speed, m/s; None takes a recording's first speed, or the seed profile's.
        effects: the effects to enable and their parameter values (`EffectSettings`).
        noise: sensor noise, "none", "seed" (relative) or "vehicle" (the vehicle's noise_std).
        seed: seed of the noise.
        longitudinal: with a recording, "torque", "speed" (follow its measured speed) or
            "auto" (torque if it has torque columns). A recording is predicted from its own
            initial state: measured speed and yaw rate, steady-state side speed under θ.

    Raises:
        InputError: θ, v0 or the noise model does not fit the vehicle.
        ValueError: from the simulator, for inputs or effects it rejects.
    """
    import jax

    from ..simulator import seed_profile, simulate as solve_one

    if inputs is None:
        inputs, v0 = seed_profile(), PROFILE_V0 if v0 is None else v0
    veh, source = load_vehicle(vehicle)
    th = checked_theta(theta, veh)
    rec = inputs if isinstance(inputs, Recording) else None
    mode = TorqueDriven if rec is None else model_class(longitudinal_mode(rec, longitudinal))
    inp = inputs if rec is None else _recording_inputs(rec, veh, mode)
    if v0 is None and rec is None:
        raise InputError("--v0", "v0", "give an initial speed for bare inputs")
    v0 = first_speed(rec, veh) if v0 is None else checked_v0(v0)
    add_noise = sensor_noise(noise, veh, source)
    lateral0 = None if rec is None else _lateral0(rec, th, veh, v0)
    ys, ok = solve_one(
        th,
        inp,
        veh,
        v0=v0,
        effects=effects,
        longitudinal=mode,
        lateral0=lateral0,
    )
    if ok and add_noise is not None:
        ys = np.asarray(add_noise(jax.random.key(seed), ys))
    return _result(rec if rec is not None else inp, inp, ys, ok, th, v0)


def _result(given, inp: Inputs, ys, ok, theta, v0: float) -> SimulateResult:
    """The simulation with the inputs as `given` (a recording's own values, or the profile)."""
    as_float = lambda a: None if a is None else np.asarray(a, dtype=float)
    return SimulateResult(
        t=float(inp.t0) + inp.dt * np.arange(inp.num_samples),
        dt=float(inp.dt),
        readings=np.asarray(ys),
        ok=bool(ok),
        theta=theta,
        v0=v0,
        steer=as_float(given.steer),
        torque_front=as_float(given.torque_front),
        torque_rear=as_float(given.torque_rear),
    )


def _recording_inputs(rec: Recording, vehicle: Vehicle, mode: type[AbstractVehicleModel]) -> Inputs:
    """A recording's inputs for the model class `mode`, the measured longitudinal motion as
    identify uses it."""
    inp = rec.inputs(longitudinal=mode, wheel_radius=vehicle.wheel_radius)
    if not issubclass(mode, SpeedDriven):
        return inp
    speed, accel = measured_longitudinal(rec, vehicle.wheel_radius)
    return Inputs(inp.t0, inp.dt, inp.steer, inp.torque_front, inp.torque_rear, speed=speed, accel=accel)


def _lateral0(rec: Recording, theta: np.ndarray, vehicle: Vehicle, v0: float):
    """The recording's own initial lateral state, as a problem's window starts: its smoothed
    yaw rate and the steady-state side speed for it under θ (none without a yaw-rate channel)."""
    from ..simulator.models import steady_lateral_state

    yaw = smoothed_yaw_rate(rec)
    if yaw is None:
        return None
    vy0, r0 = steady_lateral_state(np.asarray(theta), vehicle, v0, float(yaw[0]))
    return np.array([float(vy0), float(r0)])
