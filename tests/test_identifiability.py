"""What a drive can and cannot tell: the Fisher-information flag, and `simulate --inputs` in the
speed-driven mode predicting a recording from its own initial state."""

import numpy as np
import pandas as pd
import pytest

from vdsbi.cli import main
from vdsbi.diagnostics import identifiability
from vdsbi.io import build_recording, read_recording
from vdsbi.problem import ProblemSettings, make_problem
from vdsbi.simulator import CHANNELS, SEED_TRUE_THETA, Inputs, default_vehicle, simulate, theta_from_dict

THETA = theta_from_dict(SEED_TRUE_THETA)


def _drive(steer_amplitude: float, duration: float = 30.0, dt: float = 0.005, noise: float = 0.02):
    """A torque-free recording (speed, steer, IMU) of a weaving drive at ≈ 15 m/s."""
    t = np.arange(0.0, duration, dt)
    steer = steer_amplitude * np.sin(2 * np.pi * t / 3.0) * np.sin(2 * np.pi * t / 17.0)
    torque = 150.0 + 80.0 * np.sin(2 * np.pi * t / 6.0)
    inputs = Inputs(0.0, dt, steer, 0.6 * torque, 0.4 * torque)
    vehicle = default_vehicle()
    ys, ok = simulate(THETA, inputs, vehicle, v0=15.0)
    assert ok
    rng = np.random.default_rng(0)
    cols = {"t": t, "steer": steer}
    for i, c in enumerate(CHANNELS):
        cols[c] = ys[:, i] + rng.normal(0.0, noise * (0.05 if c == "vx" else 1.0), len(t))
    return build_recording(cols, "torque-free.csv"), vehicle


def test_slip_stiffness_is_not_identified_without_torques_and_cornering_stiffness_is(x64):
    rec, vehicle = _drive(0.03)
    problem = make_problem(rec, vehicle, ProblemSettings(longitudinal="speed", max_window=10.0))
    info = identifiability(problem, THETA, vehicle.default_prior())
    for name in ("C_kappa_f", "C_kappa_r"):
        assert not info[name]["identified"] and "zero information" in info[name]["reason"]
        assert info[name]["posterior_std"] == pytest.approx(info[name]["prior_std"])
    for name in ("C_alpha_f", "C_alpha_r"):
        assert info[name]["identified"], info[name]
        assert info[name]["posterior_std"] < 0.2 * info[name]["prior_std"]


def test_cog_height_is_not_identified_in_the_linear_tyre_range(x64):
    # |ay| stays far below μg/2: Dugoff is linear, so the load transfer h_cog drives changes nothing.
    rec, vehicle = _drive(0.004)
    problem = make_problem(rec, vehicle, ProblemSettings(longitudinal="speed", max_window=10.0))
    info = identifiability(problem, THETA, vehicle.default_prior())
    assert not info["h_cog"]["identified"]
    assert info["h_cog"]["ratio"] > 0.5


def test_simulate_predicts_a_torque_free_recording_from_its_own_state(tmp_path):
    rec, vehicle = _drive(0.03, duration=12.0)
    rec_path, veh_path, out = tmp_path / "rec.csv", tmp_path / "vehicle.json", tmp_path / "pred.csv"
    rec.to_csv(rec_path)
    veh_path.write_text(__import__("json").dumps(vehicle.to_dict()))
    theta = __import__("json").dumps(SEED_TRUE_THETA)
    args = ["simulate", "--vehicle", str(veh_path), "--inputs", str(rec_path), "--theta", theta]
    args += ["--noise", "none"]
    assert main([*args, "--out", str(out)]) == 0
    pred = pd.read_csv(out)
    measured = read_recording(rec_path)
    # Speed mode by default (no torque columns): vx is the measurement itself, the lateral
    # channels are predicted from the recording's initial speed and yaw rate.
    np.testing.assert_allclose(pred["vx"], measured.channels["vx"], rtol=1e-6)  # a float32 ulp or two
    for c in ("ay", "yaw_rate"):
        err = pred[c].to_numpy() - measured.channels[c]
        # The recording's own sensor noise (0.02) plus a few per cent of the signal.
        assert np.sqrt(np.mean(err**2)) < 0.02 * 1.2 + 0.03 * np.std(measured.channels[c]), c


def test_determined_directions_are_in_log_space_of_positive_parameters_only():
    # A bias whose prior spans zero has no logarithm: it is left out, however narrow its posterior.
    from vdsbi.diagnostics import determined_directions

    rng = np.random.default_rng(0)
    names = ["C_alpha_f", "sensor_bias.ax"]
    prior = np.stack([rng.uniform(2e4, 2e5, 4000), rng.uniform(-0.5, 0.5, 4000)], 1)
    post = np.stack([rng.normal(8e4, 2e3, 4000), rng.normal(0.3, 0.004, 4000)], 1)
    (d,) = determined_directions(post, prior, names, names)
    assert set(d["weights"]) == {"C_alpha_f"} and 0 < d["ratio"] < 0.1


def test_a_parameter_is_identified_by_information_and_flagged_when_model_error_widens_it():
    from types import SimpleNamespace

    from vdsbi.api._identify_report import _flag
    from vdsbi.problem import Box

    box = Box.from_dict({"a": (0.0, 1.0), "b": (0.0, 1.0), "c": (0.0, 1.0), "d": (0.0, 1.0)})
    prior_std = 1.0 / np.sqrt(12.0)
    fit = SimpleNamespace(theta=np.full(4, 0.5), free=("a", "b", "c"), disagreement={})
    # a: informed, narrow; b: informed, widened past the rule by model error; c: uninformed; d: not fitted
    informed = np.array([0.1, 0.1, 0.6, 1.0]) * prior_std
    reported = np.array([0.2, 0.7, 0.9, 1.0]) * prior_std
    params = {n: {"std": float(s)} for n, s in zip(box.names, reported)}
    _flag(params, fit, box, informed)
    assert [params[n]["identified"] for n in "abcd"] == [True, True, False, False]
    assert [("model_error" in params[n]) for n in "abcd"] == [False, True, False, False]
    assert "60%" in params["c"]["not_identified_because"]
    assert "do not depend" in params["d"]["not_identified_because"]


def test_a_combination_whose_draws_near_a_singularity_is_not_determined():
    # The yaw-rate gain v/(L + K·v²) of draws whose understeer gradient K nears the critical
    # −L/v² is unbounded: a few such draws give it a huge std and a meaningless interval.
    from vdsbi.diagnostics import vehicle_combinations
    from vdsbi.problem import Box, parameter_names, prior_box
    from vdsbi.simulator import PARAM_NAMES, default_vehicle

    veh = default_vehicle()
    names = parameter_names()
    box = Box.from_dict(prior_box(veh), PARAM_NAMES)
    rng = np.random.default_rng(0)
    prior = np.asarray(box.low) + rng.uniform(size=(4000, 6)) * np.asarray(box.width)
    # a posterior tight on everything but a rear stiffness spread from oversteer to understeer
    post = np.tile(np.asarray(box.low + 0.5 * box.width), (4000, 1))
    post[:, 4] = 16.5 * veh.mass * 9.81 / 2  # a passenger car's front axle, whatever the box allows
    post[:, 5] = np.linspace(0.7, 1.3, 4000) * post[0, 4] * (veh.wheelbase - post[0, 0]) / post[0, 0]
    out = vehicle_combinations(post, names, veh, 30.0, prior, post)
    gain = out["yaw_rate_gain"]
    assert not gain["identified"]
    # the same car with its stiffnesses pinned: determined
    post[:, 5] = post[0, 4] * 1.2
    assert vehicle_combinations(post + rng.normal(0, 1e-6, post.shape), names, veh, 30.0, prior)[
        "yaw_rate_gain"
    ]["identified"]
