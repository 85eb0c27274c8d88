from ._base import AbstractEffect, Param


class YawInertia(AbstractEffect):
    """Yaw inertia I_z = k·m·l_f·l_r instead of the seed's m·l_f·l_r (k = 1).

    k is the "dynamic index" of vehicle-dynamics texts: I_z/(m·l_f·l_r). Passenger cars lie at
    about 0.8–1.1 (mass near the axles raises it, a heavy cabin load between them lowers it).
    With k fixed at 1, a fit compensates the yaw response through l_f; k is seen in the
    transient yaw response (the steady state does not depend on I_z).
    """

    name = "yaw_inertia"
    params = (Param("dynamic_index", "-", null=1.0, typical=(0.75, 1.15), bounds=(0.4, 2.0), start=1.0),)
    description = "yaw inertia differs from m·l_f·l_r (the car's dynamic index k ≠ 1)"

    def yaw_inertia_scale(self, p):
        return p[0]
