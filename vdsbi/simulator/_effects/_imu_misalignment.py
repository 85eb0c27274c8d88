import jax.numpy as jnp

from ._base import AbstractEffect, Param


class ImuMisalignment(AbstractEffect):
    """IMU rotated by roll φ and yaw ψ relative to the body.

    Yaw mixes ax and ay; roll tips the y axis towards the vertical, so ay reads a share
    g·sin φ of the support force (the specific force is +g upward on a level road).
    """

    name = "imu_misalignment"
    params = (
        Param("roll", "rad", null=0.0, typical=(-0.05, 0.05), bounds=(-0.15, 0.15), start=0.0),
        Param("yaw", "rad", null=0.0, typical=(-0.05, 0.05), bounds=(-0.15, 0.15), start=0.0),
    )
    description = "IMU mounted rotated (roll: constant ay offset; yaw: ax leaks into ay)"

    def measure(self, p, y, ctx):
        roll, yaw = p[0], p[1]
        c, s = jnp.cos(yaw), jnp.sin(yaw)
        ax, ay = y["ax"], y["ay"]
        y = dict(y)
        y["ax"] = c * ax + s * ay
        y["ay"] = jnp.cos(roll) * (-s * ax + c * ay) + ctx.gravity * jnp.sin(roll)
        return y
