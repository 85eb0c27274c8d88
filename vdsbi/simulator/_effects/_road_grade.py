import jax.numpy as jnp

from ._base import AbstractEffect, Param


class RoadGrade(AbstractEffect):
    """Constant road grade θ_g (> 0 uphill): −g·sin θ_g along body x, not felt by the IMU."""

    name = "road_grade"
    params = (Param("grade", "rad", null=0.0, typical=(-0.06, 0.06), bounds=(-0.15, 0.15), start=0.0),)
    description = "road grade (gravity along x: speed changes the accelerometer does not see)"

    def gravity_accel(self, p, ctx):
        return -ctx.gravity * jnp.sin(p[0]), jnp.asarray(0.0)
