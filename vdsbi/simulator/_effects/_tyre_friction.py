from typing import ClassVar

from ._base import AbstractEffect


class TyreFriction(AbstractEffect):
    """Tyre–road friction μ·s_f (front) and μ·s_r (rear) instead of vehicle.json's μ.

    A data-sheet μ is rarely right, and the axles differ (tyres, camber, load sensitivity): the
    front/rear balance of grip decides whether the car under- or oversteers at the limit.
    Dugoff's force saturates at μ·F_z and departs from linear at half of it, so the factors
    are informed only where the drive uses more than about half the grip (|a_y| ≳ μg/2).

    A drive that uses `grip` × vehicle.json's μ·g (a race car's downforce included, which the
    model lacks) needs factors of at least `grip`: the prior's upper bounds reach
    `grip_margin` × `grip`.
    """

    name = "tyre_friction"
    param_names = ("scale_front", "scale_rear")
    units = ("-", "-")
    null = (1.0, 1.0)
    typical = ((0.7, 1.5), (0.7, 1.5))
    bounds = ((0.4, 1.8), (0.4, 1.8))
    start = (1.0, 1.0)
    description = "road friction differs from vehicle.json's (saturation at the limit of adhesion)"
    grip_margin: ClassVar[float] = 1.25

    @classmethod
    def prior_bounds(cls, grip):
        if grip is None:
            return cls.bounds
        return tuple((lo, max(hi, cls.grip_margin * grip)) for lo, hi in cls.bounds)

    def friction_scale(self, p):
        return p[0], p[1]
