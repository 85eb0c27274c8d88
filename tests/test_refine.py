"""The refined point estimate: least squares through the simulator, channels weighted by their misfit."""

import numpy as np

from vdsbi.diagnostics import refine
from vdsbi.io import build_recording
from vdsbi.problem import ProblemSettings, make_problem, prior_box
from vdsbi.simulator import (
    CHANNELS,
    PARAM_NAMES,
    SEED_TRUE_THETA,
    Inputs,
    default_vehicle,
    simulate,
    theta_from_dict,
)

THETA = np.asarray(theta_from_dict(SEED_TRUE_THETA))


def _drive(duration=24.0, dt=0.005, noise=(0.05, 0.002)):
    t = np.arange(0.0, duration, dt)
    steer = 0.02 * np.sin(2 * np.pi * t / 3.0) + 0.01 * np.sin(2 * np.pi * t / 1.3)
    torque = np.full_like(t, 150.0)
    inputs = Inputs(0.0, dt, steer, 0.6 * torque, 0.4 * torque)
    ys, ok = simulate(THETA, inputs, default_vehicle(), v0=15.0)
    assert ok
    rng = np.random.default_rng(1)
    cols = {"t": t, "steer": steer}
    for i, c in enumerate(CHANNELS):
        cols[c] = ys[:, i]
    cols["ay"] = cols["ay"] + noise[0] * rng.standard_normal(len(t))
    cols["yaw_rate"] = cols["yaw_rate"] + noise[1] * rng.standard_normal(len(t))
    return build_recording(cols, "drive.csv")


def test_refinement_recovers_the_cornering_stiffnesses_from_a_poor_start(x64):
    veh = default_vehicle()
    prob = make_problem(_drive(), veh, ProblemSettings(longitudinal="speed", max_window=6.0))
    box = prior_box(veh)
    start = THETA.copy()
    start[4:] *= 0.7
    ref = refine(prob, start, box, free=("C_alpha_f", "C_alpha_r"), reweights=1, max_steps=20)
    fitted = dict(zip(PARAM_NAMES, ref.theta))
    assert ref.free == ("C_alpha_f", "C_alpha_r")
    np.testing.assert_allclose(ref.theta[:4], start[:4])  # fixed ones stay
    for name, truth in zip(PARAM_NAMES[4:], THETA[4:]):
        assert abs(fitted[name] / truth - 1) < 0.03, (name, fitted[name], truth)
    # The channel scales are profiled to the misfit, here the (filtered) noise level.
    assert ref.scale["ay"] < 0.05 and ref.scale["yaw_rate"] < 0.004
