"""A recording becomes one problem: windows, held-out part, noise, initial states, validation."""

import dataclasses
import logging

import jax
import numpy as np
import pytest

from vdsbi.io import build_recording
from vdsbi.problem import ProblemSettings, dof_factor, make_problem, simulate_draws, windowed_model
from vdsbi.problem._noise import lag1_autocorrelation
from vdsbi.problem._problem import yaw_at_zero_steer
from vdsbi.problem.validation import predict, validate
from vdsbi.simulator import (
    CHANNELS,
    SEED_TRUE_THETA,
    Inputs,
    default_vehicle,
    random_profile,
    simulate,
    theta_from_dict,
)

THETA = theta_from_dict(SEED_TRUE_THETA)


def _recording(inputs: Inputs, *, v0: float, noise: float = 0.0, torques: bool = True, seed: int = 0):
    vehicle = default_vehicle()
    ys, ok = simulate(THETA, inputs, vehicle, v0=v0)
    assert ok
    rng = np.random.default_rng(seed)
    cols = {"t": np.asarray(inputs.ts), "steer": np.asarray(inputs.steer)}
    if torques:
        cols |= {
            "torque_front": np.asarray(inputs.torque_front),
            "torque_rear": np.asarray(inputs.torque_rear),
        }
    for i, c in enumerate(CHANNELS):
        cols[c] = ys[:, i] + noise * rng.standard_normal(ys.shape[0]) * (0.05 if c == "vx" else 1.0)
    return build_recording(cols, "synthetic.csv"), vehicle


def _cornering_drive(duration: float = 40.0, dt: float = 0.005):
    """Cornering at 2–4 m/s² with slow steering changes: every window starts mid-corner."""
    t = np.arange(0.0, duration, dt)
    steer = 0.02 + 0.01 * np.sin(2 * np.pi * t / 7.0)
    torque = 120.0 + 60.0 * np.sin(2 * np.pi * t / 5.0)
    return Inputs(0.0, dt, steer, 0.6 * torque, 0.4 * torque)


@pytest.fixture(scope="module")
def long_drive():
    return _recording(_cornering_drive(), v0=15.0, noise=0.02)


def test_a_long_drive_is_many_windows_and_its_end_is_held_out(long_drive):
    rec, vehicle = long_drive
    prob = make_problem(rec, vehicle, ProblemSettings(max_window=5.0))
    roles = [w.role for w in prob.windows]
    assert len(roles) >= 6 and roles == sorted(roles, key=lambda r: r == "held")  # train first, then held
    held_time = sum(w.duration for w in prob.windows if w.role == "held")
    total = sum(w.duration for w in prob.windows)
    assert 0.2 * total <= held_time <= 0.4 * total
    # Masks: held samples only in held windows, train samples only in train windows, no overlap.
    assert not np.any(prob.train & prob.held)
    for i, w in enumerate(prob.windows):
        assert prob.held[i].any() == (w.role == "held") and prob.train[i].any() == (w.role == "train")
    # The burn-in: no fitted sample in a window's first second.
    first = np.array([w.t0 for w in prob.windows])[:, None]
    assert np.all(
        prob.t_out[prob.train | prob.held]
        >= np.broadcast_to(first + 1.0 - 1e-9, prob.t_out.shape)[prob.train | prob.held]
    )


def test_a_short_drive_holds_out_the_end_of_its_window():
    rec, vehicle = _recording(
        random_profile(__import__("jax").random.key(1), duration=12.0), v0=12.0, noise=0.02
    )
    prob = make_problem(rec, vehicle)
    assert len(prob.windows) == 1 and prob.windows[0].split is not None
    last_train = prob.t_out[prob.train].max()
    first_held = prob.t_out[prob.held].min()
    assert last_train < first_held
    assert first_held == pytest.approx(prob.windows[0].split, abs=2 * prob.dt)


def test_noise_std_is_estimated(long_drive):
    rec, vehicle = long_drive
    prob = make_problem(rec, vehicle, ProblemSettings(max_window=5.0))
    sigma = dict(zip(prob.channels, prob.sigma))
    assert sigma["ay"] == pytest.approx(0.02, rel=0.15)
    assert all(prob.noise_source[c] == "estimated from the recording" for c in prob.channels)


def test_a_slow_log_gets_the_same_model_rate_noise_from_the_vehicle_file_and_the_estimate(long_drive):
    # The 200-Hz drive taken at 25 Hz with σ = 0.05 m/s² per sample on ay: the vehicle file's
    # σ and the estimate both become the model-rate equivalent σ·sqrt(200/25).
    rec, vehicle = long_drive
    rng = np.random.default_rng(1)
    cols = {"t": rec.t[::8], "steer": rec.steer[::8], "torque_front": rec.torque_front[::8]}
    cols |= {"torque_rear": rec.torque_rear[::8]}
    cols |= {c: v[::8] for c, v in rec.channels.items()}
    cols["ay"] = cols["ay"] + rng.normal(0.0, 0.05, len(cols["t"]))
    slow = build_recording(cols, "slow.csv")
    settings = ProblemSettings(max_window=5.0, bandwidth=None)
    told = dataclasses.replace(vehicle, noise_std={"ay": 0.05})
    for veh in (vehicle, told):
        prob = make_problem(slow, veh, settings)
        sigma = dict(zip(prob.channels, prob.sigma))
        assert sigma["ay"] == pytest.approx(0.05 * np.sqrt(8.0), rel=0.2), prob.noise_source["ay"]


def test_draws_in_chunks_are_the_draws_of_one_call(long_drive):
    import jax

    rec, vehicle = long_drive
    prob = make_problem(rec, vehicle, ProblemSettings(max_window=5.0))
    wm = windowed_model(prob)
    theta = np.asarray(THETA)[None] * np.linspace(0.9, 1.1, 7)[:, None]
    key = jax.random.key(3)
    for k in (None, key):
        kw = dict(sigma_raw=prob.sigma_raw) if k is not None else {}
        whole = simulate_draws(k, wm, theta, **kw)
        parts = simulate_draws(k, wm, theta, max_batch=3, **kw)
        np.testing.assert_array_equal(np.asarray(parts[1]), np.asarray(whole[1]))
        # The same keys and θ; float32 results differ only as XLA vectorises another batch size.
        scale = np.abs(np.asarray(whole[0])).max(axis=(0, 1, 2))
        assert np.max(np.abs(np.asarray(parts[0]) - np.asarray(whole[0])) / scale) < 1e-3


def test_truth_predicts_every_window_even_mid_corner(x64, long_drive):
    # Windows start mid-corner: with the estimated initial lateral state, the truth predicts
    # each window (train and held-out) to the noise level; a window started laterally at rest
    # (the old assumption) would not (checked below by zeroing the measured yaw rate).
    rec, vehicle = long_drive
    prob = make_problem(rec, vehicle, ProblemSettings(max_window=5.0, burn_in=0.0, quiet_edges=False))
    assert np.all(np.abs(prob.r0[1:]) > 0.05)  # really mid-corner
    pred, ok = predict(prob, THETA)
    assert ok
    mask = prob.train | prob.held
    iy = prob.channels.index("yaw_rate")
    err = (pred - prob.y)[..., iy][mask]
    assert np.sqrt(np.mean(err**2)) < 3 * 0.02
    at_rest = dataclasses.replace(prob, r0=np.zeros_like(prob.r0), train=prob.train, held=prob.held)
    pred0, _ = predict(at_rest, THETA)
    early = mask & (prob.t_out < np.array([w.t0 for w in prob.windows])[:, None] + 0.5)
    early[0] = False  # the first window starts at rest anyway
    assert np.sqrt(np.mean(((pred - prob.y)[..., iy][early]) ** 2)) < 2.5 * 0.02
    assert np.sqrt(np.mean(((pred0 - prob.y)[..., iy][early]) ** 2)) > 3 * np.sqrt(
        np.mean(((pred - prob.y)[..., iy][early]) ** 2)
    )


def test_validation_scores_the_truth_near_the_noise(x64, long_drive):
    rec, vehicle = long_drive
    prob = make_problem(rec, vehicle, ProblemSettings(max_window=5.0))
    good = validate(prob, THETA)["channels"]
    bad_theta = np.array(THETA)
    bad_theta[4] *= 0.6
    bad = validate(prob, bad_theta)["channels"]
    for c in ("ay", "yaw_rate"):
        assert good[c]["chi2_dof"] < 2.5  # the linear steady-state start costs a little at 4 m/s²
        assert bad[c]["nrmse"] > good[c]["nrmse"]


def test_speed_mode_conditions_on_the_lateral_channels_through_a_shared_filter(x64, long_drive):
    rec, vehicle = long_drive
    prob = make_problem(rec, vehicle, ProblemSettings(longitudinal="speed", max_window=5.0))
    assert prob.channels == ("ay", "yaw_rate")
    assert prob.decimator is not None and prob.y.shape[1] == prob.decimator.num_out(prob.t.shape[1])
    # The filtered noise std is the raw std times the filter's noise gain (< 1).
    assert np.all(prob.sigma < prob.sigma_raw)
    pred, ok = predict(prob, THETA)
    assert ok
    iy = prob.channels.index("yaw_rate")
    err = (pred - prob.y)[..., iy][prob.train | prob.held]
    assert np.sqrt(np.mean(err**2)) < 0.01  # free rolling vs slight slip: small, not zero


def test_no_torques_means_speed_mode_and_torque_mode_is_refused(long_drive):
    rec, vehicle = long_drive
    cols = {"t": rec.t, "steer": rec.steer, **rec.channels}
    bare = build_recording(cols, "bare.csv")
    assert make_problem(bare, vehicle).longitudinal == "speed"
    with pytest.raises(Exception, match="torque"):
        make_problem(bare, vehicle, ProblemSettings(longitudinal="torque"))


def test_correlated_residuals_count_as_fewer_samples():
    rng = np.random.default_rng(0)
    e = rng.standard_normal((4, 5000))
    ar = np.zeros_like(e)
    for k in range(1, e.shape[1]):
        ar[:, k] = 0.8 * ar[:, k - 1] + e[:, k]
    rho = lag1_autocorrelation(np.stack([e, ar], -1), np.ones((4, 5000), bool))
    assert rho[0] == pytest.approx(0.0, abs=0.03) and rho[1] == pytest.approx(0.8, abs=0.03)
    assert dof_factor(rho)[1] == pytest.approx(0.2 / 1.8, rel=0.15)


def test_window_starts_move_to_quiet_moments():
    # A weave with straight moments: windows start near them rather than mid-corner.
    t = np.arange(0.0, 40.0, 0.005)
    steer = 0.03 * np.sin(2 * np.pi * t / 8.0)
    inputs = Inputs(0.0, 0.005, steer, np.full_like(t, 90.0), np.full_like(t, 60.0))
    rec, vehicle = _recording(inputs, v0=15.0, noise=0.02)
    quiet = make_problem(rec, vehicle, ProblemSettings(max_window=6.0))
    plain = make_problem(rec, vehicle, ProblemSettings(max_window=6.0, quiet_edges=False))
    assert np.mean(np.abs(quiet.r0[1:])) < 0.5 * np.mean(np.abs(plain.r0[1:]))
    # Still contiguous; each edge moved by at most 30 % of a window, none shorter than half of one.
    spans = [(w.t0, w.t1) for w in quiet.windows]
    assert all(abs(b0 - a1) < 1e-9 for (_, a1), (b0, _) in zip(spans, spans[1:]))
    assert all(3.0 - 1e-9 <= b - a <= 1.6 * 6.0 + 1e-9 for a, b in spans[1:-1])


def test_a_steer_zero_off_the_straight_ahead_shows_as_yaw_at_zero_steer(x64):
    """A log whose steer reads 2 mrad less than the wheels act: the car yaws at a logged zero
    as it does steered steadily by 2 mrad; the honest log of the same drive shows nothing."""
    from vdsbi.problem import default_effects

    dt, offset = 0.005, 0.002
    t = np.arange(0.0, 40.0, dt)
    acting = offset + 0.004 * np.sin(2 * np.pi * t / 6.0)
    torque = np.full_like(t, 20.0)
    rec, vehicle = _recording(Inputs(0.0, dt, acting, 0.6 * torque, 0.4 * torque), v0=12.0, noise=0.02)
    steady, ok = simulate(
        THETA,
        Inputs(0.0, dt, np.full(4000, offset), 0.6 * torque[:4000], 0.4 * torque[:4000]),
        vehicle,
        v0=12.0,
    )
    assert ok
    r_steady = float(steady[-1, CHANNELS.index("yaw_rate")])

    def problem(steer):
        return make_problem(build_recording({"t": rec.t, "steer": steer, **rec.channels}, "log.csv"), vehicle)

    yaw, share = yaw_at_zero_steer(problem(acting - offset))
    assert share > 0.1 and yaw == pytest.approx(r_steady, rel=0.25)
    named = lambda prob: [name for name, _ in default_effects(prob)]
    assert "steer_offset" in named(problem(acting - offset))
    _, share = yaw_at_zero_steer(problem(acting))
    assert abs(share) < 0.05
    assert "steer_offset" not in named(problem(acting))


def test_a_new_recording_length_compiles_the_measured_filter_as_one_program(long_drive, caplog):
    """Each fleet drive has its own length: the measurement's filter and decimation must not
    compile op by op for each (a third of a second per drive)."""
    rec, vehicle = long_drive

    def cut(n):
        return dataclasses.replace(
            rec,
            t=rec.t[:n],
            steer=rec.steer[:n],
            torque_front=rec.torque_front[:n],
            torque_rear=rec.torque_rear[:n],
            channels={c: v[:n] for c, v in rec.channels.items()},
        )

    speed = ProblemSettings(longitudinal="speed")  # filtered and decimated
    assert make_problem(cut(6000), vehicle, speed).decimator is not None
    with jax.log_compiles(), caplog.at_level(logging.WARNING):
        make_problem(cut(6100), vehicle, speed)
    compiled = [r.getMessage() for r in caplog.records if r.getMessage().startswith("Compiling")]
    # Eagerly, the filter's convolution compiles as a program of its own; inside the filter's
    # one program (compiled here, or already by an earlier test of this length) it does not.
    eager = [m for m in compiled if m.startswith("Compiling jit(conv_general_dilated)")]
    assert not eager and len(compiled) <= 3, compiled
