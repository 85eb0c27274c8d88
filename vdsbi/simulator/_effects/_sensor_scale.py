from ._base import AbstractEffect, Param


class SensorScale(AbstractEffect):
    """Scale-factor errors of the inertial sensors: each reads (1 + e)·(true value).

    MEMS accelerometers and gyros carry calibration errors of a few per cent; a body that rolls
    under lateral acceleration tips the accelerometer by φ ∝ a_y, which reads as an a_y scale
    factor (1 + g·dφ/da_y) as well.
    """

    name = "sensor_scale"
    params = (
        Param("ax", "-", null=0.0, typical=(-0.05, 0.05), bounds=(-0.3, 0.3), start=0.0),
        Param("ay", "-", null=0.0, typical=(-0.05, 0.05), bounds=(-0.3, 0.3), start=0.0),
        Param("yaw_rate", "-", null=0.0, typical=(-0.05, 0.05), bounds=(-0.3, 0.3), start=0.0),
    )
    description = "IMU scale factors (ax, ay, yaw_rate read (1 + e) times the true value)"

    def measure(self, p, y, ctx):
        y = dict(y)
        y["ax"] = (1.0 + p[0]) * y["ax"]
        y["ay"] = (1.0 + p[1]) * y["ay"]
        y["yaw_rate"] = (1.0 + p[2]) * y["yaw_rate"]
        return y
