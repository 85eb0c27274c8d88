import jax.numpy as jnp

from ._base import AbstractEffect, Param


class RoadBank(AbstractEffect):
    """Constant road bank φ_b (> 0: left side high): −g·sin φ_b along body y, not felt."""

    name = "road_bank"
    params = (Param("bank", "rad", null=0.0, typical=(-0.06, 0.06), bounds=(-0.15, 0.15), start=0.0),)
    description = "road bank (gravity along y, balanced by tire side force: ay offset with drift)"

    def gravity_accel(self, p, ctx):
        return jnp.asarray(0.0), -ctx.gravity * jnp.sin(p[0])
