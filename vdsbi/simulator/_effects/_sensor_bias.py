from ._base import AbstractEffect


class SensorBias(AbstractEffect):
    """Constant offsets on the IMU channels."""

    name = "sensor_bias"
    param_names = ("ax", "ay", "yaw_rate")
    units = ("m/s^2", "m/s^2", "rad/s")
    null = (0.0, 0.0, 0.0)
    typical = ((-0.5, 0.5), (-0.5, 0.5), (-0.02, 0.02))
    bounds = ((-2.0, 2.0), (-2.0, 2.0), (-0.08, 0.08))
    start = (0.0, 0.0, 0.0)
    description = "IMU offsets (constant shift of ax, ay, yaw_rate without dynamics)"

    def measure(self, p, y, ctx):
        y = dict(y)
        y["ax"] = y["ax"] + p[0]
        y["ay"] = y["ay"] + p[1]
        y["yaw_rate"] = y["yaw_rate"] + p[2]
        return y
