import jax.numpy as jnp

from ._base import AbstractEffect, Param, promoted

#: Smallest time constant used, s: keeps the lag state stable for RK4 at the default 2.5 ms step.
TAU_FLOOR = 1e-3


class SteeringLag(AbstractEffect):
    """First-order lag between recorded and acting road-wheel angle, time constant τ."""

    name = "steering_lag"
    params = (Param("tau", "s", null=0.0, typical=(0.03, 0.3), bounds=(0.005, 0.8), start=0.04),)
    steer_lag = ("tau",)
    description = "steering actuator/compliance lag (yaw and ay lag the recorded steer)"
    num_states = 1

    def init_state(self, p, u0):
        return u0[:1]

    def state_rhs(self, p, z, u_cmd):
        # τ = 0 (null) is the base model exactly: the state is frozen and bypassed in `inputs`;
        # otherwise τ is floored at TAU_FLOOR, so τ → 0 needs no infinitely stiff state.
        tau = jnp.maximum(jnp.abs(p[0]), TAU_FLOOR)
        return jnp.where(p[0] == 0, 0.0, (u_cmd[:1] - z) / tau)

    def inputs(self, p, z, u):
        return promoted(u, p, z).at[0].set(jnp.where(p[0] == 0, u[0], z[0])).astype(u.dtype)
