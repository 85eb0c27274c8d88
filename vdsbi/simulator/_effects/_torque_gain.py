from ._base import AbstractEffect, Param, promoted


class TorqueGain(AbstractEffect):
    """Applied axle torques are g times the recorded (commanded) ones: T_applied = g·T_cmd.

    Engine maps, driveline efficiency and brake-pad friction make the torque a car's bus reports
    differ from what reaches the wheels by a roughly constant factor; one g for both axles (a
    per-axle gain is nearly unidentifiable on a drive where one axle only brakes).
    """

    name = "torque_gain"
    params = (Param("gain", "-", null=1.0, typical=(0.8, 1.2), bounds=(0.4, 1.8), start=1.0),)
    description = "commanded torque is not applied torque (gain of actuator and driveline)"

    def inputs(self, p, z, u):
        return promoted(u, p).at[1:].multiply(p[0]).astype(u.dtype)
