"""Driver inputs on a uniform time grid: a recording's series or a built-in profile."""

from __future__ import annotations

import equinox as eqx
import jax.numpy as jnp
from jaxtyping import Array, Float, Int


class Inputs(eqx.Module):
    """(steer, torque_front, torque_rear) sampled on t = t0 + k·dt, k = 0..T-1, and optionally
    the measured longitudinal motion that drives the speed-driven mode.

    Attributes:
        t0: first sample time, s.
        dt: sample interval, s (uniform; readers resample to it).
        steer: front road-wheel angle, rad, shape (T,).
        torque_front: total front-axle wheel torque, N·m (> 0 drives), shape (T,).
        torque_rear: total rear-axle wheel torque, N·m, shape (T,).
        speed: measured longitudinal speed Vx, m/s, shape (T,), or None. Required by
            `SpeedDriven`, ignored by `TorqueDriven`.
        accel: measured longitudinal specific force a_x (IMU ax), m/s², shape (T,), or None.
            Required by `SpeedDriven` (it sets the load transfer), ignored by `TorqueDriven`.

    `speed` and `accel` are None-able pytree leaves: windows stacked with `jax.tree.map`
    and vmapped keep None where every window has None.
    """

    t0: Float[Array, ""]
    dt: float = eqx.field(static=True)
    steer: Float[Array, " T"]
    torque_front: Float[Array, " T"]
    torque_rear: Float[Array, " T"]
    speed: Float[Array, " T"] | None = None
    accel: Float[Array, " T"] | None = None

    def __init__(self, t0, dt, steer, torque_front, torque_rear, speed=None, accel=None):
        self.t0 = jnp.asarray(t0, dtype=float)
        self.dt = float(dt)
        self.steer = jnp.asarray(steer, dtype=float)
        self.torque_front = jnp.asarray(torque_front, dtype=float)
        self.torque_rear = jnp.asarray(torque_rear, dtype=float)
        self.speed = None if speed is None else jnp.asarray(speed, dtype=float)
        self.accel = None if accel is None else jnp.asarray(accel, dtype=float)

    def __check_init__(self):
        if not self.dt > 0:
            raise ValueError(f"inputs: dt must be > 0, got {self.dt}")
        n = self.steer.shape
        if self.torque_front.shape != n or self.torque_rear.shape != n or len(n) != 1:
            raise ValueError("inputs: steer, torque_front, torque_rear must be 1-D of equal length")
        if n[0] < 2:
            raise ValueError("inputs: need at least 2 samples")
        for name in ("speed", "accel"):
            arr = getattr(self, name)
            if arr is not None and arr.shape != n:
                raise ValueError(f"inputs: '{name}' must have the shape of steer {n}, got {arr.shape}")

    @property
    def num_samples(self) -> int:
        return self.steer.shape[0]

    @property
    def ts(self) -> Float[Array, " T"]:
        return self.t0 + self.dt * jnp.arange(self.num_samples)

    @property
    def duration(self) -> float:
        return self.dt * (self.num_samples - 1)

    def _locate(self, t) -> tuple[Int[Array, ""], Float[Array, ""]]:
        # Interval index i and weight w of t in [t_i, t_i+1]; held constant beyond the ends.
        s = jnp.clip((t - self.t0) / self.dt, 0.0, self.num_samples - 1.0)
        i = jnp.clip(jnp.floor(s).astype(jnp.int32), 0, self.num_samples - 2)
        return i, s - i

    def __call__(self, t: Float[Array, ""]) -> Float[Array, "3"]:
        """Linear interpolation at time t (held constant beyond the ends)."""
        i, w = self._locate(t)
        u = jnp.stack([self.steer, self.torque_front, self.torque_rear])
        return u[:, i] * (1 - w) + u[:, i + 1] * w

    def longitudinal(self, t: Float[Array, ""]) -> Float[Array, "3"]:
        """(speed m/s, its slope m/s², accel m/s²) of the measured series at time t.

        Speed and accel are linearly interpolated like the other inputs; the slope is that
        of the interpolated speed (piecewise constant; zero beyond the ends).

        Raises:
            ValueError: if `speed` or `accel` is None (at trace time).
        """
        if self.speed is None or self.accel is None:
            missing = [n for n in ("speed", "accel") if getattr(self, n) is None]
            raise ValueError(f"inputs: the speed-driven mode needs measured {missing} (got None)")
        i, w = self._locate(t)
        inside = (t >= self.t0) & (t <= self.t0 + self.duration)
        slope = jnp.where(inside, (self.speed[i + 1] - self.speed[i]) / self.dt, 0.0)
        speed = self.speed[i] * (1 - w) + self.speed[i + 1] * w
        accel = self.accel[i] * (1 - w) + self.accel[i + 1] * w
        return jnp.stack([speed, slope, accel])
