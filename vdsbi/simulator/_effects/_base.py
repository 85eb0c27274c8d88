"""The interface every physics effect implements; all hooks default to 'no effect'."""

from __future__ import annotations

from typing import ClassVar, NamedTuple

import equinox as eqx
import jax.numpy as jnp
from jaxtyping import Array, Float


class Context(NamedTuple):
    """Vehicle state seen by effect hooks (all scalars, SI units)."""

    vx: Float[Array, ""]
    vy: Float[Array, ""]
    r: Float[Array, ""]
    r_dot: Float[Array, ""]
    fz_front: Float[Array, ""]
    fz_rear: Float[Array, ""]
    r_eff_front: Float[Array, ""]
    r_eff_rear: Float[Array, ""]
    omega_front: Float[Array, ""]
    omega_rear: Float[Array, ""]
    mass: Float[Array, ""]
    gravity: float


class AbstractEffect(eqx.Module):
    """A physics effect left out of the base model.

    Class attributes describe its parameters: `param_names`, their `units`, the `null` values
    at which the effect vanishes, and `typical` (low, high) ranges used as priors when the
    effect is searched for. Hooks receive `p`, the effect's parameter vector.
    """

    name: ClassVar[str]
    param_names: ClassVar[tuple[str, ...]]
    units: ClassVar[tuple[str, ...]]
    null: ClassVar[tuple[float, ...]]
    typical: ClassVar[tuple[tuple[float, float], ...]]
    description: ClassVar[str]
    num_states: ClassVar[int] = 0

    def init_state(self, p, u0: Float[Array, "3"]) -> Float[Array, " S"]:
        return jnp.zeros(self.num_states)

    def state_rhs(self, p, z, u_cmd) -> Float[Array, " S"]:
        return jnp.zeros(self.num_states)

    def inputs(self, p, z, u: Float[Array, "3"]) -> Float[Array, "3"]:
        """Effective (steer, torque_front, torque_rear) acting on the vehicle."""
        return u

    def radius_scale(self, p) -> Float[Array, ""]:
        """Factor on the free tire radius."""
        return jnp.asarray(1.0)

    def wheel_torque(self, p, ctx: Context) -> tuple[Float[Array, ""], Float[Array, ""]]:
        """Extra torque on the front and rear axle, N·m."""
        return jnp.asarray(0.0), jnp.asarray(0.0)

    def body_force(self, p, ctx: Context) -> tuple[Float[Array, ""], Float[Array, ""]]:
        """Non-gravitational force on the body (felt by the IMU), N, body axes."""
        return jnp.asarray(0.0), jnp.asarray(0.0)

    def gravity_accel(self, p, ctx: Context) -> tuple[Float[Array, ""], Float[Array, ""]]:
        """Gravity component in the road plane, m/s²: accelerates the car, unseen by the IMU."""
        return jnp.asarray(0.0), jnp.asarray(0.0)

    def measure(self, p, y: dict, ctx: Context) -> dict:
        """Transform the ideal sensor readings {channel: value}."""
        return y
