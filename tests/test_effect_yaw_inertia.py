"""The yaw-inertia effect: k = 1 is the seed's model; k scales the yaw transient, not the steady state."""

import numpy as np

from vdsbi.simulator import CHANNELS, SEED_TRUE_THETA, Inputs, default_vehicle, simulate, theta_from_dict
from vdsbi.simulator.effects import EffectSettings


def _step_steer(dt: float = 0.005, duration: float = 8.0):
    t = np.arange(0.0, duration, dt)
    steer = np.where(t >= 0.5, 0.01, 0.0)
    return Inputs(0.0, dt, steer, np.full_like(t, 120.0), np.zeros_like(t))


def _yaw(k: float | None):
    veh, theta = default_vehicle(), theta_from_dict(SEED_TRUE_THETA)
    effects = (
        EffectSettings()
        if k is None
        else EffectSettings(enabled=("yaw_inertia",), params={"yaw_inertia": {"dynamic_index": k}})
    )
    ys, ok = simulate(theta, _step_steer(), veh, v0=20.0, effects=effects)
    assert ok
    return ys[:, CHANNELS.index("yaw_rate")]


def test_null_is_the_base_model(x64):
    np.testing.assert_allclose(_yaw(1.0), _yaw(None), rtol=0, atol=1e-12)


def test_more_inertia_slows_the_yaw_response_but_not_its_steady_state(x64):
    light, heavy = _yaw(0.7), _yaw(1.4)
    # The yaw rate 0.15 s after the step (rising) is lower for the heavier car ...
    k = int(round(0.65 / 0.005))
    assert heavy[k] < 0.9 * light[k]
    # ... and both settle to the same steady state (it does not depend on I_z).
    np.testing.assert_allclose(heavy[-1], light[-1], rtol=0.02)
