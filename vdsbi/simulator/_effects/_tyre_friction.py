from ._base import AbstractEffect


class TyreFriction(AbstractEffect):
    """Road–tyre friction μ·s instead of vehicle.json's μ (a data-sheet guess is rarely right).

    Dugoff's force saturates at μ·F_z and departs from linear at half of it, so the factor is
    informed only where the drive uses more than about half the grip (|a_y| ≳ μg/2).
    """

    name = "tyre_friction"
    param_names = ("scale",)
    units = ("-",)
    null = (1.0,)
    typical = ((0.8, 1.25),)
    bounds = ((0.4, 1.8),)
    start = (1.0,)
    description = "road friction differs from vehicle.json's (saturation at the limit of adhesion)"

    def friction_scale(self, p):
        return p[0]
