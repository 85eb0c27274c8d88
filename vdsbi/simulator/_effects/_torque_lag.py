from ._base import AbstractEffect


class TorqueLag(AbstractEffect):
    """First-order lag between recorded (commanded) and acting axle torques, time constant τ."""

    name = "torque_lag"
    param_names = ("tau",)
    units = ("s",)
    null = (0.0,)
    typical = ((0.05, 0.5),)
    description = "powertrain/brake actuator lag (ax and wheel speeds lag the recorded torque)"
    num_states = 2

    def init_state(self, p, u0):
        return u0[1:]

    def state_rhs(self, p, z, u_cmd):
        return (u_cmd[1:] - z) / (abs(p[0]) + 1e-3)

    def inputs(self, p, z, u):
        return u.at[1:].set(z)
