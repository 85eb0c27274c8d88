from ._base import AbstractEffect, Param


class WheelRadiusError(AbstractEffect):
    """True free tire radius R_f·(1 + e) instead of vehicle.json's R_f (wear, pressure, size)."""

    name = "wheel_radius_error"
    params = (Param("rel_error", "-", null=0.0, typical=(-0.05, 0.05), bounds=(-0.15, 0.15), start=0.0),)
    description = "tire radius differs from the data sheet (wheel speeds scale by 1/(1+e))"

    def radius_scale(self, p):
        return 1.0 + p[0]
