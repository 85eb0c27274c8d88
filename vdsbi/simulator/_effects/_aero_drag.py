import jax.numpy as jnp

from ._base import AbstractEffect, Param

AIR_DENSITY = 1.225  # kg/m³, sea level at 15 °C


class AeroDrag(AbstractEffect):
    """Aerodynamic drag F = −½·ρ·CdA·Vx·|Vx| at the CoG; felt by the accelerometer."""

    name = "aero_drag"
    params = (Param("CdA", "m^2", null=0.0, typical=(0.4, 1.0), bounds=(0.0, 2.5), start=0.3),)
    description = "aerodynamic drag (force ∝ speed², felt by the accelerometer)"

    def body_force(self, p, ctx):
        return -0.5 * AIR_DENSITY * p[0] * ctx.vx * jnp.abs(ctx.vx), jnp.asarray(0.0)
