"""A torque-driven recording without vx or wheel speeds: the speed at each window start is
estimated from ax and ay ≈ vx·r."""

import numpy as np
import pytest

from vdsbi.io import InputError, build_recording, estimate_speed
from vdsbi.problem import ProblemSettings, make_problem
from vdsbi.simulator import CHANNELS, SEED_TRUE_THETA, Inputs, default_vehicle, simulate, theta_from_dict

THETA = np.asarray(theta_from_dict(SEED_TRUE_THETA))
NOISE = {"ax": 0.1, "ay": 0.1, "yaw_rate": 0.005}


def _drive(steer_amplitude: float, duration: float = 60.0, dt: float = 0.005, ax_bias: float = 0.0):
    """A simulated drive with torques and only ax, ay, yaw_rate (noisy, ax biased); the true vx."""
    t = np.arange(0.0, duration, dt)
    steer = steer_amplitude * (np.sin(2 * np.pi * t / 8.0) + 0.3 * np.sin(2 * np.pi * t / 2.7))
    torque = 20.0 + 300.0 * np.sin(2 * np.pi * t / 13.0)
    ys, ok = simulate(THETA, Inputs(0.0, dt, steer, 0.6 * torque, 0.4 * torque), default_vehicle(), v0=15.0)
    assert ok
    ys = np.asarray(ys)
    rng = np.random.default_rng(0)
    cols = {"t": t, "steer": steer, "torque_front": 0.6 * torque, "torque_rear": 0.4 * torque}
    for name, std in NOISE.items():
        cols[name] = ys[:, CHANNELS.index(name)] + std * rng.standard_normal(t.shape[0])
    cols["ax"] = cols["ax"] + ax_bias
    return build_recording(cols, "imu_only.csv"), ys[:, CHANNELS.index("vx")]


@pytest.mark.parametrize("ax_bias", [0.0, 0.15])
def test_the_speed_follows_from_ax_and_the_turns(ax_bias):
    rec, vx = _drive(0.015, ax_bias=ax_bias)
    est = estimate_speed(rec)
    assert est.turning > 10.0
    error = np.abs(est.speed / vx - 1)
    assert np.max(error) < 0.08 and np.sqrt(np.mean(error**2)) < 0.03, error.max()


def test_a_torque_drive_without_speed_is_a_torque_driven_problem_with_estimated_starts():
    rec, vx = _drive(0.015, ax_bias=0.1)
    assert set(rec.channels) == {"ax", "ay", "yaw_rate"}
    prob = make_problem(rec, default_vehicle(), ProblemSettings(max_window=10.0))
    assert prob.longitudinal == "torque" and prob.channels == ("ax", "ay", "yaw_rate")
    assert prob.speed is None and prob.accel is None
    assert prob.num_windows >= 4
    starts = np.searchsorted(rec.t, [w.t0 - 1e-9 for w in prob.windows])
    error = np.abs(prob.v0 / vx[starts] - 1)
    assert np.max(error) < 0.08 and np.mean(error) < 0.03, error
    assert "initial speeds estimated from ax and ay ≈ vx·r" in prob.summary()["initial_speed"]
    assert any("initial speeds estimated" in w for w in prob.warnings)


def test_the_speed_driven_mode_still_needs_a_measured_speed():
    rec, _ = _drive(0.015, duration=20.0)
    with pytest.raises(InputError, match=r"imu_only\.csv: vx: no vx or wheel-speed channel; the speed-dr"):
        make_problem(rec, default_vehicle(), ProblemSettings(longitudinal="speed"))


def test_a_drive_that_never_turns_is_refused_naming_what_is_missing():
    rec, _ = _drive(0.0005, duration=20.0)
    with pytest.raises(InputError, match=r"imu_only\.csv: vx: no vx or wheel-speed channel, and the drive"):
        make_problem(rec, default_vehicle())


def test_without_ay_the_speed_cannot_be_estimated():
    rec, _ = _drive(0.015, duration=20.0)
    del rec.channels["ay"]
    with pytest.raises(InputError, match=r"imu_only\.csv: vx: .*without ay the speed cannot be estimated"):
        estimate_speed(rec)
