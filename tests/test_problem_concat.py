"""Several recordings of one car as one problem, and the combinations a drive determines."""

import numpy as np
import pytest

from vdsbi.diagnostics import vehicle_combinations
from vdsbi.io import InputError, build_recording
from vdsbi.problem import ProblemSettings, concat_problems, make_problem
from vdsbi.problem.validation import predict
from vdsbi.simulator import (
    CHANNELS,
    GRAVITY,
    SEED_TRUE_THETA,
    Inputs,
    default_vehicle,
    simulate,
    theta_from_dict,
)

THETA = np.asarray(theta_from_dict(SEED_TRUE_THETA))


def _drive(duration, period, name, dt=0.005):
    t = np.arange(0.0, duration, dt)
    steer = 0.02 * np.sin(2 * np.pi * t / period)
    torque = np.full_like(t, 150.0)
    ys, ok = simulate(THETA, Inputs(0.0, dt, steer, 0.6 * torque, 0.4 * torque), default_vehicle(), v0=15.0)
    assert ok
    return build_recording({"t": t, "steer": steer, **{c: ys[:, i] for i, c in enumerate(CHANNELS)}}, name)


def test_two_recordings_become_one_problem_each_window_from_its_own_state():
    veh = default_vehicle()
    settings = ProblemSettings(longitudinal="speed", max_window=6.0, held_out=0.0)
    a, b = (
        make_problem(_drive(12.0, 3.0, "a.csv"), veh, settings),
        make_problem(_drive(7.0, 2.0, "b.csv"), veh, settings),
    )
    both = concat_problems([a, b])
    assert both.num_windows == a.num_windows + b.num_windows
    assert both.source == "a.csv + b.csv" and not both.held.any()
    assert both.train.sum() == a.train.sum() + b.train.sum()
    np.testing.assert_array_equal(both.v0, np.concatenate([a.v0, b.v0]))
    # Padding is never compared, and each recording's windows predict as they do alone.
    pred_both, ok = predict(both, THETA)
    pred_b, ok_b = predict(b, THETA)
    assert ok and ok_b
    # (the last compared samples of the longest window sit at the filter's edge in `b` alone)
    k = b.y.shape[1]
    inner = b.train & (np.arange(k) < k - 8)
    # (float32 in a batch of another size: XLA may vectorise the steps differently, 1e-4 apart)
    np.testing.assert_allclose(pred_both[a.num_windows :, :k][inner], pred_b[inner], rtol=1e-4, atol=1e-4)


def test_recordings_with_other_channels_are_refused_by_name():
    veh = default_vehicle()
    a = make_problem(
        _drive(8.0, 3.0, "a.csv"), veh, ProblemSettings(longitudinal="speed", channels=("ay", "yaw_rate"))
    )
    b = make_problem(
        _drive(8.0, 3.0, "b.csv"), veh, ProblemSettings(longitudinal="speed", channels=("yaw_rate",))
    )
    with pytest.raises(InputError, match="b.csv"):
        concat_problems([a, b])


def test_understeer_gradient_and_yaw_gain_follow_the_single_track_formulas():
    veh = default_vehicle()
    m, L = veh.mass, veh.wheelbase
    lf, cf, cr = 1.2, 80e3, 100e3
    samples = np.array([[lf, 0.5, 1e5, 1e5, cf, cr]] * 3)
    names = ("l_f", "h_cog", "C_kappa_f", "C_kappa_r", "C_alpha_f", "C_alpha_r")
    out = vehicle_combinations(samples, names, veh, speed=20.0)
    k = m / L * ((L - lf) / cf - lf / cr)
    assert out["understeer_gradient"]["median"] == pytest.approx(np.degrees(k) * GRAVITY)
    assert out["yaw_rate_gain"]["median"] == pytest.approx(20.0 / (L + k * 400.0))
    # Neutral steer: K = 0 and the gain is kinematic, v/L.
    neutral = np.array([[lf, 0.5, 1e5, 1e5, cf, cf * lf / (L - lf)]])
    assert vehicle_combinations(neutral, names, veh, 20.0)["understeer_gradient"]["median"] == pytest.approx(
        0.0, abs=1e-9
    )


def test_a_combination_is_identified_when_the_draws_narrow_it_well_below_the_prior():
    veh = default_vehicle()
    names = ("l_f", "h_cog", "C_kappa_f", "C_kappa_r", "C_alpha_f", "C_alpha_r")
    rng = np.random.default_rng(0)
    prior = rng.uniform([1.0, 0.3, 5e4, 5e4, 3e4, 3e4], [1.6, 0.7, 2e5, 2e5, 2e5, 2e5], (4000, 6))
    # Stiffnesses spread over their prior but tied in ratio: the understeer gradient is fixed
    # (to the extent l_f is), each stiffness is not.
    tied = prior.copy()
    tied[:, 0] = 1.3 + 0.01 * rng.standard_normal(4000)
    tied[:, 5] = tied[:, 4] * 1.1
    out = vehicle_combinations(tied, names, veh, 20.0, prior)
    assert out["understeer_gradient"]["identified"] and out["understeer_gradient"]["std_ratio_to_prior"] < 0.5
    same = vehicle_combinations(prior, names, veh, 20.0, prior)
    assert not same["understeer_gradient"]["identified"] and not same["yaw_rate_gain"]["identified"]
    assert "identified" not in vehicle_combinations(prior, names, veh, 20.0)["understeer_gradient"]
