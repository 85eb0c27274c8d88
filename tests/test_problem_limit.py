"""Limit handling: a slide caught by counter-steer is found, cut out with its reason, and kept on request."""

import numpy as np

from vdsbi.io import build_recording
from vdsbi.problem import ProblemSettings, make_problem
from vdsbi.problem._limit import slides
from vdsbi.simulator import default_vehicle


def _slalom(slide_at: float | None, lag: float = 0.1, duration: float = 40.0, rate: float = 100.0):
    """A 0.5 Hz slalom at 25 m/s whose yaw rate lags the steer by `lag` s (a normal car), and
    optionally a 0.6 s slide where the yaw rate runs against a counter-steer."""
    t = np.arange(0.0, duration, 1.0 / rate)
    steer = 0.03 * np.sin(2 * np.pi * 0.5 * t)
    r = 0.2 * np.sin(2 * np.pi * 0.5 * (t - lag))
    if slide_at is not None:
        s = (t >= slide_at) & (t < slide_at + 0.6)
        steer[s], r[s] = 0.03, -0.3
    vx = np.full_like(t, 25.0)
    cols = {"t": t, "steer": steer, "ax": np.zeros_like(t), "ay": vx * r, "yaw_rate": r, "vx": vx}
    return build_recording(cols, "slalom.csv", rate=rate)


def test_a_counter_steered_slide_is_found_with_margins_and_a_slalom_is_not():
    veh = default_vehicle()
    assert slides(_slalom(None), wheel_radius=veh.wheel_radius, friction=veh.friction) == []
    found = slides(_slalom(20.0), wheel_radius=veh.wheel_radius, friction=veh.friction)
    assert len(found) == 1
    t0, t1, why = found[0]
    assert 18.9 <= t0 <= 19.1 and 22.4 <= t1 <= 22.7  # 1 s before, 2 s after
    assert "counter-steer" in why


def test_make_problem_cuts_the_slide_out_and_says_why():
    veh = default_vehicle()
    rec = _slalom(20.0)
    prob = make_problem(rec, veh, ProblemSettings(longitudinal="speed", max_window=5.0))
    assert all(w.t1 <= 19.1 or w.t0 >= 22.4 for w in prob.windows)
    reasons = [r[2] for r in prob.description["rejected"]]
    assert any(r.startswith("limit handling") for r in reasons)
    keep = ProblemSettings(longitudinal="speed", max_window=5.0, exclude_slides=False)
    kept = make_problem(rec, veh, keep)
    assert any(w.t0 < 20.3 < w.t1 for w in kept.windows)


def test_torques_that_do_not_explain_the_speed_are_flagged():
    # Torques that would accelerate the car at 1.5 m/s² while it keeps 25 m/s: commanded, not applied.
    veh = default_vehicle()
    rec = _slalom(None)
    cols = {"t": rec.t, "steer": rec.steer, **rec.channels}
    push = 1.5 * veh.mass * veh.wheel_radius
    pushed = {"torque_front": np.full_like(rec.t, push), "torque_rear": 0 * rec.t}
    bad = build_recording(cols | pushed, "x.csv")
    prob = make_problem(bad, veh, ProblemSettings(max_window=10.0))
    assert prob.longitudinal == "torque"
    assert any("do not explain the measured speed" in w for w in prob.warnings)
    # Torques that balance (a steady 25 m/s needs none here): no warning.
    fine = build_recording(cols | {"torque_front": 0 * rec.t, "torque_rear": 0 * rec.t}, "y.csv")
    assert not make_problem(fine, veh, ProblemSettings(max_window=10.0)).warnings
