"""Driver inputs on a uniform time grid: a recording's series or a built-in profile."""

from __future__ import annotations

import equinox as eqx
import jax.numpy as jnp
from jaxtyping import Array, Float


class Inputs(eqx.Module):
    """(steer, torque_front, torque_rear) sampled on t = t0 + k·dt, k = 0..T-1.

    Attributes:
        t0: first sample time, s.
        dt: sample interval, s (uniform; readers resample to it).
        steer: front road-wheel angle, rad, shape (T,).
        torque_front: total front-axle wheel torque, N·m (> 0 drives), shape (T,).
        torque_rear: total rear-axle wheel torque, N·m, shape (T,).
    """

    t0: Float[Array, ""]
    dt: float = eqx.field(static=True)
    steer: Float[Array, " T"]
    torque_front: Float[Array, " T"]
    torque_rear: Float[Array, " T"]

    def __init__(self, t0, dt, steer, torque_front, torque_rear):
        self.t0 = jnp.asarray(t0, dtype=float)
        self.dt = float(dt)
        self.steer = jnp.asarray(steer, dtype=float)
        self.torque_front = jnp.asarray(torque_front, dtype=float)
        self.torque_rear = jnp.asarray(torque_rear, dtype=float)

    def __check_init__(self):
        if not self.dt > 0:
            raise ValueError(f"inputs: dt must be > 0, got {self.dt}")
        n = self.steer.shape
        if self.torque_front.shape != n or self.torque_rear.shape != n or len(n) != 1:
            raise ValueError("inputs: steer, torque_front, torque_rear must be 1-D of equal length")
        if n[0] < 2:
            raise ValueError("inputs: need at least 2 samples")

    @property
    def num_samples(self) -> int:
        return self.steer.shape[0]

    @property
    def ts(self) -> Float[Array, " T"]:
        return self.t0 + self.dt * jnp.arange(self.num_samples)

    @property
    def duration(self) -> float:
        return self.dt * (self.num_samples - 1)

    def __call__(self, t: Float[Array, ""]) -> Float[Array, "3"]:
        """Linear interpolation at time t (held constant beyond the ends)."""
        s = jnp.clip((t - self.t0) / self.dt, 0.0, self.num_samples - 1.0)
        i = jnp.clip(jnp.floor(s).astype(jnp.int32), 0, self.num_samples - 2)
        w = s - i
        u = jnp.stack([self.steer, self.torque_front, self.torque_rear])
        return u[:, i] * (1 - w) + u[:, i + 1] * w
