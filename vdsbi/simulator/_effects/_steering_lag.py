from ._base import AbstractEffect


class SteeringLag(AbstractEffect):
    """First-order lag between recorded and acting road-wheel angle, time constant τ."""

    name = "steering_lag"
    param_names = ("tau",)
    units = ("s",)
    null = (0.0,)
    typical = ((0.03, 0.3),)
    description = "steering actuator/compliance lag (yaw and ay lag the recorded steer)"
    num_states = 1

    def init_state(self, p, u0):
        return u0[:1]

    def state_rhs(self, p, z, u_cmd):
        # τ floored: τ → 0 recovers the base model without an infinitely stiff state.
        return (u_cmd[:1] - z) / (abs(p[0]) + 1e-3)

    def inputs(self, p, z, u):
        return u.at[0].set(z[0])
