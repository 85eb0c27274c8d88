from ._base import AbstractEffect, Param

#: Speed at which `Downforce.coef` is stated, m/s (180 km/h: a race car's fast corners).
REFERENCE_SPEED = 50.0


class Downforce(AbstractEffect):
    """Aerodynamic downforce F_z = ½·ρ·C_L·A·Vx², split between the axles by the aero balance.

    Stated as `coef`, the downforce as a share of the car's weight at `REFERENCE_SPEED`
    (coef = ½·ρ·C_L·A·50²/(m·g); C_L·A = 3 m² on a 700 kg car gives 0.67), and `balance_front`,
    the share the front axle carries: both of order one whatever the car, unlike C_L·A in m².
    It loads the tyres (their limit μ·F_z grows with Vx², their loaded radius shrinks) and is
    not felt by the IMU (it is vertical; the drag that comes with it is `aero_drag`). Dugoff's
    force depends on the load only past half the grip, so a drive informs it where it is both
    fast and near the limit.
    """

    name = "downforce"
    # At coef = 0 the balance moves nothing: 0.5 is only where it sits.
    params = (
        Param("coef", "-", null=0.0, typical=(0.3, 2.0), bounds=(0.0, 3.0), start=0.3),
        Param("balance_front", "-", null=0.5, typical=(0.35, 0.55), bounds=(0.2, 0.8), start=0.5),
    )
    description = "aerodynamic downforce (tyre load and grip grow with speed², unseen by the IMU)"
    adds_load = True

    def vertical_load(self, p, vx, weight):
        force = p[0] * weight * (vx / REFERENCE_SPEED) ** 2
        return p[1] * force, (1.0 - p[1]) * force
