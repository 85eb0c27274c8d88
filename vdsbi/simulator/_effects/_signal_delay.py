import jax.numpy as jnp

from ._base import AbstractEffect, Param

#: Smallest delay the Padé poles are placed for, s: they sit at |λ| = √12/d, so RK4 at 5 ms is
#: stable above it.
DELAY_FLOOR = 0.008


class SignalDelay(AbstractEffect):
    """The measured responses lag the recorded inputs by a pure delay d (sensor filtering, bus
    latency, logging), modelled as the inputs (steer, torques) arriving d late.

    For a time-invariant model a delay of every input equals a delay of every output, so this is
    one measurement delay for all channels (except the measured speed and a_x of the speed-driven
    mode, which are inputs there). The delay is the second-order Padé approximant

        e^{−sd} ≈ (1 − sd/2 + s²d²/12) / (1 + sd/2 + s²d²/12),

    with two states per input, x1 = a0/(s² + a1·s + a0)·u and x2 = x1' (a0 = 12/d², a1 = 6/d):
    x2' = a0·(u − x1) − a1·x2 and u_d = u − d·x2. Its phase matches the delay's within 1° up
    to ω·d ≈ 1.6 (2.5 Hz at d = 0.1 s), ample for driver inputs.

    Below `DELAY_FLOOR` the poles stay at the floor's and only the gain d scales:
    u_d = u − d·x2 ≈ u − d·u' ≈ u(t − d) for driver inputs, continuous down to d = 0 (the base
    model), so a fit can reach a car without latency.
    """

    name = "signal_delay"
    params = (Param("delay", "s", null=0.0, typical=(0.02, 0.15), bounds=(0.01, 0.4), start=0.04),)
    steer_lag = ("delay",)
    description = "inputs and measurements out of step by a pure delay (latency of sensors or bus)"
    num_states = 6

    def init_state(self, p, u0):
        # At rest with the initial inputs: x1 = u0 (unit DC gain), x2 = 0.
        return jnp.concatenate([u0, jnp.zeros(3)])

    def _coefficients(self, p):
        d = jnp.maximum(jnp.abs(p[0]), DELAY_FLOOR)
        return 12.0 / d**2, 6.0 / d

    def state_rhs(self, p, z, u_cmd):
        a0, a1 = self._coefficients(p)
        x1, x2 = z[:3], z[3:]
        dx = jnp.concatenate([x2, a0 * (u_cmd - x1) - a1 * x2])
        # d = 0 (null) is the base model exactly: states frozen, bypassed in `inputs`.
        return jnp.where(p[0] == 0, 0.0, dx)

    def inputs(self, p, z, u):
        # (s² − a1·s + a0)/(s² + a1·s + a0) = 1 − 2·a1·s/(s² + a1·s + a0) and 2·a1/a0 = d.
        return jnp.where(p[0] == 0, u, u - jnp.abs(p[0]) * z[3:])
