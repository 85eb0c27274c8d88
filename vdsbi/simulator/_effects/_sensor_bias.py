from ._base import AbstractEffect, Param


class SensorBias(AbstractEffect):
    """Constant offsets on the IMU channels."""

    name = "sensor_bias"
    params = (
        Param("ax", "m/s^2", null=0.0, typical=(-0.5, 0.5), bounds=(-2.0, 2.0), start=0.0),
        Param("ay", "m/s^2", null=0.0, typical=(-0.5, 0.5), bounds=(-2.0, 2.0), start=0.0),
        Param("yaw_rate", "rad/s", null=0.0, typical=(-0.02, 0.02), bounds=(-0.08, 0.08), start=0.0),
    )
    description = "IMU offsets (constant shift of ax, ay, yaw_rate without dynamics)"

    def measure(self, p, y, ctx):
        y = dict(y)
        y["ax"] = y["ax"] + p[0]
        y["ay"] = y["ay"] + p[1]
        y["yaw_rate"] = y["yaw_rate"] + p[2]
        return y
