import jax.numpy as jnp

from ._base import AbstractEffect, Param


class RollingResistance(AbstractEffect):
    """Rolling-resistance torque −c_rr·F_z·R_eff on each axle's wheels.

    It acts through the wheels, so it shows as tire force (felt by the accelerometer) and as
    a small braking slip on the free-rolling axle.
    """

    name = "rolling_resistance"
    params = (Param("c_rr", "-", null=0.0, typical=(0.005, 0.03), bounds=(0.0, 0.08), start=0.004),)
    description = "rolling resistance (constant drag ∝ load, felt by the accelerometer)"

    def wheel_torque(self, p, ctx):
        # tanh: a smooth sign so the torque vanishes, not flips, at standstill.
        tf = -p[0] * ctx.fz_front * ctx.r_eff_front * jnp.tanh(ctx.omega_front / 0.5)
        tr = -p[0] * ctx.fz_rear * ctx.r_eff_rear * jnp.tanh(ctx.omega_rear / 0.5)
        return tf, tr
