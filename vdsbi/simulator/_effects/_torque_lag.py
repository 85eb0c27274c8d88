import jax.numpy as jnp

from ._base import AbstractEffect, Param, promoted
from ._steering_lag import TAU_FLOOR


class TorqueLag(AbstractEffect):
    """First-order lag between recorded (commanded) and acting axle torques, time constant τ."""

    name = "torque_lag"
    params = (Param("tau", "s", null=0.0, typical=(0.05, 0.5), bounds=(0.005, 1.2), start=0.05),)
    description = "powertrain/brake actuator lag (ax and wheel speeds lag the recorded torque)"
    num_states = 2

    def init_state(self, p, u0):
        return u0[1:]

    def state_rhs(self, p, z, u_cmd):
        # As SteeringLag: τ = 0 is the base model exactly, else τ is floored at TAU_FLOOR.
        tau = jnp.maximum(jnp.abs(p[0]), TAU_FLOOR)
        return jnp.where(p[0] == 0, 0.0, (u_cmd[1:] - z) / tau)

    def inputs(self, p, z, u):
        return promoted(u, p, z).at[1:].set(jnp.where(p[0] == 0, u[1:], z)).astype(u.dtype)
