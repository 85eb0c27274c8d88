from typing import ClassVar

from ._base import AbstractEffect, Param


class TyreFriction(AbstractEffect):
    """Tyre–road friction μ·s_f (front) and μ·s_r (rear) instead of vehicle.json's μ.

    A data-sheet μ is rarely right, and the axles differ (tyres, camber, load sensitivity): the
    front/rear balance of grip decides whether the car under- or oversteers at the limit.
    Dugoff's force saturates at μ·F_z and departs from linear at half of it, so the factors
    are informed only where the drive uses more than about half the grip (|a_y| ≳ μg/2).

    A drive that uses `grip` × vehicle.json's μ·g needs factors of at least `grip` (its
    downforce included where no enabled effect models it): the prior's upper bounds reach
    `grip_margin` × `grip`, and its lower bounds `grip_floor` × `grip`, so the fit cannot put
    the tyres' limit below grip the car demonstrably pulled.
    """

    name = "tyre_friction"
    params = (
        Param("scale_front", "-", null=1.0, typical=(0.7, 1.5), bounds=(0.4, 1.8), start=1.0),
        Param("scale_rear", "-", null=1.0, typical=(0.7, 1.5), bounds=(0.4, 1.8), start=1.0),
    )
    description = "road friction differs from vehicle.json's (saturation at the limit of adhesion)"
    grip_margin: ClassVar[float] = 1.25
    grip_floor: ClassVar[float] = 0.9

    @classmethod
    def prior_bounds(cls, grip, extra_load=False):
        if grip is None:
            return cls.bounds
        # Steady cornering loads each axle in proportion to its share of the weight, so an axle
        # whose μ·s·F_z carries the car's a_y = grip·μ·g needs s ≥ grip. The floor's 0.9 leaves
        # room for yaw transients and load transfer (one axle briefly above its share) and for
        # noise in the grip's 99th percentile. An effect that adds load (downforce) can carry
        # that grip with smaller factors: then only the upper bounds move.
        floor = 0.0 if extra_load else cls.grip_floor * grip
        return tuple((max(lo, floor), max(hi, cls.grip_margin * grip)) for lo, hi in cls.bounds)

    def friction_scale(self, p):
        return p[0], p[1]
