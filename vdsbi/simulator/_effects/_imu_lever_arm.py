from ._base import AbstractEffect, Param


class ImuLeverArm(AbstractEffect):
    """IMU mounted at (dx, dy) from the CoG: a_imu = a_cog + ṙ×d − r²·d (planar rigid body)."""

    name = "imu_lever_arm"
    params = (
        Param("dx", "m", null=0.0, typical=(-1.0, 1.0), bounds=(-2.5, 2.5), start=0.0),
        Param("dy", "m", null=0.0, typical=(-0.4, 0.4), bounds=(-1.0, 1.0), start=0.0),
    )
    description = "IMU away from the CoG (ay gains dx·ṙ, ax gains −dy·ṙ, centripetal −r²·d)"

    def measure(self, p, y, ctx):
        dx, dy = p[0], p[1]
        y = dict(y)
        y["ax"] = y["ax"] - ctx.r_dot * dy - ctx.r**2 * dx
        y["ay"] = y["ay"] + ctx.r_dot * dx - ctx.r**2 * dy
        return y
