"""Built-in excitation profiles (driver inputs)."""

from __future__ import annotations

import dataclasses

import jax
import jax.numpy as jnp
import numpy as np

from ._inputs import Inputs


@dataclasses.dataclass(frozen=True, kw_only=True)
class SeedManeuver:
    """The shape of the seed's maneuver (`seed_profile`): square-wave gas/brake and sinusoidal
    steer. The seed gives no amplitudes: 0.05 rad of road-wheel angle gives ≈ 3 m/s² lateral
    acceleration at 10.5 m/s on the default car (inside the tires' linear range), 600 N·m of
    drive ≈ +1.3 m/s² and 1200 N·m of braking (65 % front, a typical brake balance) ≈ −2.6 m/s².

    Attributes:
        steer_amplitude: road-wheel angle amplitude, rad.
        steer_period: period of the steer sine, s.
        torque_period: period of the gas/brake square wave, s (gas in its first half).
        drive_torque: front-axle drive torque while on the gas, N·m.
        brake_torque: total braking torque, N·m.
        brake_front_share: share of the braking torque on the front axle.
    """

    steer_amplitude: float = 0.05
    steer_period: float = 4.0
    torque_period: float = 5.0
    drive_torque: float = 600.0
    brake_torque: float = 1200.0
    brake_front_share: float = 0.65


def seed_profile(
    duration: float = 5.0,
    rate: float = 200.0,
    *,
    maneuver: SeedManeuver = SeedManeuver(),
    t0: float = 0.0,
) -> Inputs:
    """The seed's maneuver: square-wave gas/brake (period 5 s), sinusoidal steer (period 4 s).

    Front-wheel drive; braking on both axles. `maneuver` sets its periods and amplitudes
    (`SeedManeuver`); `duration` s sampled at `rate` Hz from `t0`.
    """
    m = maneuver
    n = int(round(duration * rate)) + 1
    t = np.arange(n) / rate
    steer = m.steer_amplitude * np.sin(2 * np.pi * t / m.steer_period)
    gas = (t % m.torque_period) < m.torque_period / 2
    tf = np.where(gas, m.drive_torque, -m.brake_front_share * m.brake_torque)
    tr = np.where(gas, 0.0, -(1 - m.brake_front_share) * m.brake_torque)
    return Inputs(t0, 1.0 / rate, steer, tf, tr)


def random_profile(
    key,
    duration: float = 20.0,
    rate: float = 200.0,
    *,
    max_steer: float = 0.06,
    max_drive: float = 900.0,
    max_brake: float = 1800.0,
    brake_front_share: float = 0.65,
) -> Inputs:
    """A random but drivable maneuver: steer as a sum of 4 sines (0.1–1.2 Hz), torque as
    smoothed random gas/brake/coast segments of 1–4 s. Front-wheel drive."""
    k1, k2, k3, k4, k5 = jax.random.split(key, 5)
    n = int(round(duration * rate)) + 1
    t = np.arange(n) / rate
    freqs = np.asarray(jax.random.uniform(k1, (4,), minval=0.1, maxval=1.2))
    phases = np.asarray(jax.random.uniform(k2, (4,), maxval=2 * np.pi))
    amps = np.asarray(jax.random.uniform(k3, (4,), minval=0.2, maxval=1.0))
    steer = (amps[:, None] * np.sin(2 * np.pi * freqs[:, None] * t + phases[:, None])).sum(0)
    steer = max_steer * steer / max(np.abs(steer).max(), 1e-9)
    n_seg = int(duration) + 2
    lengths = np.asarray(jax.random.uniform(k4, (n_seg,), minval=1.0, maxval=4.0))
    levels = np.asarray(jax.random.uniform(k5, (n_seg,), minval=-1.0, maxval=1.0))
    edges = np.concatenate([[0.0], np.cumsum(lengths)])
    level = levels[np.clip(np.searchsorted(edges, t, side="right") - 1, 0, n_seg - 1)]
    # Smooth the steps over ~0.2 s, as a driver's pedal would.
    width = max(1, int(0.2 * rate))
    level = np.convolve(np.pad(level, width, mode="edge"), np.ones(width) / width, "same")
    level = level[width:-width]
    tf = np.where(level > 0, level * max_drive, level * max_brake * brake_front_share)
    tr = np.where(level > 0, 0.0, level * max_brake * (1 - brake_front_share))
    return Inputs(0.0, 1.0 / rate, steer, tf, tr)


def constant_profile(
    duration: float,
    rate: float = 200.0,
    *,
    steer: float = 0.0,
    torque_front: float = 0.0,
    torque_rear: float = 0.0,
) -> Inputs:
    n = int(round(duration * rate)) + 1
    ones = jnp.ones(n)
    return Inputs(0.0, 1.0 / rate, steer * ones, torque_front * ones, torque_rear * ones)
