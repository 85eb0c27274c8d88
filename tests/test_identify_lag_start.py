"""The steer-to-response lag `check` measures is evidence identify's likelihood fit may use: two
more candidate starts with the lag parameters at that lag and at half of it."""

import numpy as np

from vdsbi.api._identify import _starts, _steer_lag
from vdsbi.io import build_recording
from vdsbi.problem import Box, parameter_names, prior_box
from vdsbi.simulator import default_vehicle


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
    assert abs(_steer_lag(rec, default_vehicle()) - 0.3) <= 0.02
