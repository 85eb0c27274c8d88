"""Checks of the values `simulate`, `observability` and `design` share: the vehicle, θ, the
initial speed and the channels a noise model can measure. Each failure is an `InputError`
naming the value."""

from __future__ import annotations

import math
import os
from collections.abc import Mapping, Sequence
from typing import Literal

import numpy as np

from ..io import InputError, read_vehicle
from ..simulator import CHANNELS, PARAM_NAMES, SEED_TRUE_THETA, Vehicle, check_theta, default_vehicle
from ..simulator.measurement import SensorNoise

#: Initial speed on a built-in profile, m/s (the middle of the seed's U[10, 11]).
PROFILE_V0 = 10.5


def load_vehicle(vehicle: str | os.PathLike | Vehicle | None) -> tuple[Vehicle, str]:
    """(Vehicle, the name messages use) from a file, an object, or None for the built-in one."""
    if vehicle is None:
        return default_vehicle(), "vehicle"
    if isinstance(vehicle, (str, os.PathLike)):
        return read_vehicle(vehicle), str(vehicle)
    return vehicle, "vehicle"


def checked_theta(
    theta: Mapping[str, float] | Sequence[float] | np.ndarray | None,
    vehicle: Vehicle,
    defaults: Mapping[str, float] = SEED_TRUE_THETA,
) -> np.ndarray:
    """θ in PARAM_NAMES order, from an array or {name: value} over `defaults`.

    Raises:
        InputError: an unknown name, or a value `check_theta` rejects (naming the parameter).
    """
    if theta is None or isinstance(theta, Mapping):
        given = dict(theta or {})
        unknown = [n for n in given if n not in PARAM_NAMES]
        if unknown:
            raise InputError(
                "--theta", str(unknown[0]), f"unknown parameter; expected one of {list(PARAM_NAMES)}"
            )
        values = {**defaults, **given}
        theta = [values[n] for n in PARAM_NAMES]
    theta = np.asarray(theta, dtype=float)
    try:
        check_theta(theta, vehicle)
    except ValueError as err:
        name = _culprit(theta, vehicle, defaults)
        raise InputError("--theta", name, str(err).removeprefix("theta: ")) from None
    return theta


def _culprit(theta: np.ndarray, vehicle: Vehicle, defaults: Mapping[str, float]) -> str:
    """The first parameter that `check_theta` rejects on its own (with the others at `defaults`)."""
    base = np.array([defaults[n] for n in PARAM_NAMES], dtype=float)
    if theta.shape != base.shape:
        return "theta"
    for i, name in enumerate(PARAM_NAMES):
        probe = base.copy()
        probe[i] = theta[i]
        try:
            check_theta(probe, vehicle)
        except ValueError:
            return name
    return "theta"


def checked_v0(v0: float) -> float:
    """A finite initial speed > 0 m/s."""
    if not (math.isfinite(v0) and v0 > 0):
        raise InputError("--v0", "v0", f"initial speed must be > 0 m/s, got {v0}")
    return float(v0)


def first_speed(rec, vehicle: Vehicle) -> float:
    """The recording's speed at its first sample (vx, else the wheel speeds), m/s."""
    speed = rec.speed(vehicle.wheel_radius)
    if speed is None:
        raise InputError(rec.source, "v0", "the recording has neither vx nor wheel speeds; give --v0")
    v0 = float(speed[0])
    if not (math.isfinite(v0) and v0 > 0):
        raise InputError(rec.source, "v0", f"initial speed {v0:g} m/s is not > 0; give --v0")
    return v0


#: The sensor-noise names `simulate`, `observability` and `design` take, and the noise each
#: makes from a vehicle file's noise_std (None: none).
#: Sensor noise by name: none, the seed's relative noise, or the vehicle file's noise_std.
NoiseName = Literal["none", "seed", "vehicle"]
NOISE = {
    "none": lambda noise_std: None,
    "seed": lambda noise_std: SensorNoise.seed(),
    "vehicle": SensorNoise.additive_std,
}


def sensor_noise(noise: NoiseName, vehicle: Vehicle, source: str) -> SensorNoise | None:
    """The sensor noise `NOISE` names, for `vehicle`.

    Raises:
        InputError: an unknown name, or a noise that needs the vehicle's noise_std and finds none.
    """
    if noise not in NOISE:
        raise InputError("--noise", noise, f"must be one of {', '.join(NOISE)}")
    made = NOISE[noise](vehicle.noise_std or {})
    if made is not None and not (np.any(made.relative > 0) or np.any(made.additive > 0)):
        raise InputError(source, "noise_std", f"--noise {noise} needs noise_std in the vehicle file")
    return made


def noise_channels(
    channels: Sequence[str], noise: SensorNoise | None, source: str
) -> tuple[list[str], list[str]]:
    """(channels kept, channels dropped): channels that `noise` leaves noise-free go (they would
    carry infinite information), e.g. those the vehicle file gives no noise_std.

    Raises:
        InputError: no noise model, or no channel is left.
    """
    if noise is None:
        raise InputError("--noise", "none", "information needs a noise model: seed or vehicle")
    noisy = np.asarray(noise.relative > 0) | np.asarray(noise.additive > 0)  # CHANNELS order
    dropped = [c for c in channels if not noisy[CHANNELS.index(c)]]
    kept = [c for c in channels if c not in dropped]
    if not kept:
        raise InputError(
            source,
            "noise_std",
            f"the noise model needs a positive noise_std for at least one measured channel of {dropped}",
        )
    return kept, dropped
