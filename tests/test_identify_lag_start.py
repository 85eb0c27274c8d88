"""The steer-to-response lag `check` measures is evidence the fits may use: identify's likelihood
fit gets two more candidate starts with the lag parameters at that lag and at half of it;
diagnose starts each lag parameter at half of it."""

import numpy as np
import pytest

from vdsbi.api._identify import _starts
from vdsbi.discovery._candidates import effect_space
from vdsbi.discovery._diagnose import _lag_started
from vdsbi.io import build_recording
from vdsbi.problem import Box, measured_steer_lag, parameter_names, prior_box
from vdsbi.simulator import default_vehicle
from vdsbi.simulator._effects._steering_lag import SteeringLag


def test_a_measured_lag_adds_starts_at_it_and_at_half_of_it():
    veh = default_vehicle()
    effects = ("signal_delay",)
    box = Box.from_dict(prior_box(veh, effects), parameter_names(effects))
    draws = np.asarray(box.low + 0.5 * box.width)[None] * np.ones((40, 1))
    plain = _starts(draws, box)
    with_lag = _starts(draws, box, lag=0.3)
    assert len(with_lag) == len(plain) + 2
    np.testing.assert_allclose(with_lag[-2:, -1], [0.15, 0.3])
    np.testing.assert_allclose(with_lag[-2:, :-1], draws[:2, :-1])
    assert len(_starts(draws, box, lag=None)) == len(plain)
    # without a lag parameter the measured lag adds nothing
    theta_box = Box.from_dict(prior_box(veh), parameter_names())
    assert len(_starts(draws[:, :-1], theta_box, lag=0.3)) == len(plain)


def test_the_lag_is_measured_where_the_yaw_rate_follows_the_steer():
    t = np.arange(0.0, 60.0, 0.02)
    steer = 0.02 * np.sin(2 * np.pi * t / 4.0) + 0.01 * np.sin(2 * np.pi * t / 1.7)
    v = np.full_like(t, 15.0)
    yaw = v * np.interp(t - 0.3, t, steer) / default_vehicle().wheelbase
    rec = build_recording({"t": t, "steer": steer, "yaw_rate": yaw, "vx": v, "ay": v * yaw}, "lagged")
    assert abs(measured_steer_lag(rec, default_vehicle()) - 0.3) <= 0.02


def test_diagnose_starts_each_steer_lag_parameter_at_half_the_measured_lag():
    space = effect_space(("steering_lag", "signal_delay", "sensor_bias"))
    started = _lag_started(space, 0.34)
    lagged = [space.slices[n].start for n in ("steering_lag", "signal_delay")]
    np.testing.assert_allclose(started.start[lagged], 0.17)
    others = np.setdiff1d(np.arange(space.start.size), lagged)
    np.testing.assert_array_equal(started.start[others], space.start[others])
    # a lag beyond a box starts just inside it; no measured lag changes nothing
    assert space.lo[lagged[1]] < _lag_started(space, 2.0).start[lagged[1]] < space.hi[lagged[1]]
    assert _lag_started(space, None) is space


def test_an_effect_naming_an_unknown_steer_lag_parameter_is_refused():
    with pytest.raises(ValueError, match="steer_lag"):

        class Lagging(SteeringLag):
            name = "lagging"
            steer_lag = ("delay",)
