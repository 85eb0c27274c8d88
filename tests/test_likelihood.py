"""The likelihood posterior: the best fit through the simulator, the model-error noise model and the
Laplace covariance."""

import numpy as np
import pytest

from vdsbi.estimation import FitRequest, ModelError, fit_likelihood
from vdsbi.estimation._start import prior_mean
from vdsbi.io import build_recording
from vdsbi.problem import Box, ProblemSettings, make_problem, prior_box, simulate_draws, windowed_model
from vdsbi.problem.validation import channel_scores
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


def _drive(duration=24.0, dt=0.005, noise=(0.05, 0.002), steer_delay=0.0):
    t = np.arange(0.0, duration, dt)
    steer = 0.02 * np.sin(2 * np.pi * t / 3.0) + 0.01 * np.sin(2 * np.pi * t / 1.3)
    torque = np.full_like(t, 150.0)
    acting = np.interp(t - steer_delay, t, steer)
    inputs = Inputs(0.0, dt, acting, 0.6 * torque, 0.4 * torque)
    ys, ok = simulate(THETA, inputs, default_vehicle(), v0=15.0)
    assert ok
    rng = np.random.default_rng(1)
    cols = {"t": t, "steer": steer, "torque_front": 0.6 * torque, "torque_rear": 0.4 * torque}
    for i, c in enumerate(CHANNELS):
        cols[c] = ys[:, i]
    cols["ay"] = cols["ay"] + noise[0] * rng.standard_normal(len(t))
    cols["yaw_rate"] = cols["yaw_rate"] + noise[1] * rng.standard_normal(len(t))
    return build_recording(cols, "drive.csv")


def test_the_fit_recovers_the_stiffnesses_from_a_poor_start_and_its_interval_holds_them(x64, getkey):
    # The torque-driven model of a torque-driven drive: the model is right, the residual is noise.
    veh = default_vehicle()
    settings = ProblemSettings(longitudinal="torque", max_window=6.0, channels=("ay", "yaw_rate"))
    prob = make_problem(_drive(), veh, settings)
    box = Box.from_dict(prior_box(veh), PARAM_NAMES)
    start = THETA.copy()
    start[4:] *= 0.7
    request = FitRequest(free=("C_alpha_f", "C_alpha_r"), noise=ModelError(passes=1), max_steps=20)
    post = fit_likelihood(prob, start, box, request)
    assert post.free == ("C_alpha_f", "C_alpha_r")
    np.testing.assert_allclose(post.theta[:4], start[:4], rtol=1e-3)  # fixed ones stay
    for name, truth in zip(PARAM_NAMES[4:], THETA[4:]):
        assert abs(post.theta[PARAM_NAMES.index(name)] / truth - 1) < 0.03, name
    assert np.all(post.noise.model_error_ratio < 1.5), post.noise.to_dict()
    draws = np.asarray(post.sample(getkey(), 4000))
    z = np.abs(post.theta - THETA) / draws.std(0)
    assert np.all(z[4:] < 3.0), z  # the truth within three posterior standard deviations
    assert post.mahalanobis2(post.theta)[0] < 1e-6
    # The interval is the draws' central 90 %: quantiles map exactly through the monotone box.
    q = np.quantile(draws, [0.05, 0.95], axis=0).T
    np.testing.assert_allclose(post.interval(0.9)[4:], q[4:], rtol=2e-3)


def test_a_wrong_start_speed_is_corrected_per_window_and_leaves_the_estimate_where_it_was(x64):
    # Torque-driven windows start from the measured speed; here it reads 0.5 m/s high (a 3 %
    # wheel-radius error). Without a correction the simulated speed keeps that offset and the fit
    # bends l_f and the stiffnesses by ~3 σ; with it the estimate stays within ½ σ of the right-speed one.
    import dataclasses

    veh = default_vehicle()
    settings = ProblemSettings(longitudinal="torque", max_window=6.0, channels=("ay", "yaw_rate"))
    box = Box.from_dict(prior_box(veh), PARAM_NAMES)
    free = ("C_alpha_f", "C_alpha_r")  # the neighbouring tests' fits: one compilation
    prob = make_problem(_drive(), veh, settings)
    right = fit_likelihood(prob, THETA, box, FitRequest(free=free, noise=ModelError(passes=1), max_steps=20))
    biased = dataclasses.replace(prob, v0=prob.v0 + 0.5)
    high = fit_likelihood(biased, THETA, box, FitRequest(free=free, noise=ModelError(passes=1), max_steps=20))
    fitted = np.asarray(prob.train).any(1)
    assert fitted.sum() >= 2 and np.all(right.v0_offset[~fitted] == 0.0)
    np.testing.assert_allclose(high.v0_offset[fitted] - right.v0_offset[fitted], -0.5, atol=0.05)
    sd = np.sqrt(np.diag(right.cov_z))
    assert np.all(np.abs(high.z - right.z) < 0.5 * sd), (high.z - right.z) / sd
    i = [PARAM_NAMES.index(n) for n in free]
    np.testing.assert_allclose(np.sqrt(np.diag(high.cov_z))[i], sd[i], rtol=0.1)

    # Simulated from the starts the fit inferred, each window is what the fit saw: at the noise.
    def chi2(p):
        pred = np.asarray(simulate_draws(None, windowed_model(p), high.theta[None])[0][0])
        return [v["chi2_dof"] for v in channel_scores(p, pred, p.train).values()]

    assert max(chi2(high.with_fitted_starts(biased))) < 1.3 < min(chi2(biased)) / 3
    # Following the measured speed there is nothing to correct.
    speed = make_problem(_drive(), veh, ProblemSettings(longitudinal="speed", max_window=6.0))
    assert not np.any(fit_likelihood(speed, THETA, box, FitRequest(free=free, max_steps=20)).v0_offset)


def test_the_start_speed_columns_of_the_jacobian_come_from_one_tangent(x64):
    import jax
    import jax.numpy as jnp

    from vdsbi.estimation._start_speed import residual_and_jacobian

    x = jnp.asarray(np.random.default_rng(0).standard_normal((5, 2)))
    # Window w's five residuals depend on the two shared coordinates and on its own correction.
    fn = lambda p: (jnp.sin(x @ p[:2])[None, :] * (1.0 + p[2:, None]) ** 2 + p[2:, None] ** 3).ravel()
    p = jnp.asarray([0.3, -0.2, 0.1, 0.4, -0.5])
    r, jac = residual_and_jacobian(fn, 2, p)
    np.testing.assert_allclose(r, fn(p), rtol=1e-12)
    np.testing.assert_allclose(jac, jax.jacfwd(fn)(p), rtol=1e-12, atol=1e-14)


def test_marginalising_the_start_speeds_leaves_the_theta_block_of_the_joint_covariance():
    from vdsbi.estimation._start_speed import V0_STD, profiled

    rng = np.random.default_rng(2)
    W, K, C, P = 3, 7, 2, 4
    jac, jac_v = rng.standard_normal((W, K, C, P)), rng.standard_normal((W, K, C))
    jac_v[2] = 0.0  # a window with no fitted sample
    prec = np.full(P, 0.3)
    joint = np.zeros((W * K * C, P + W))
    joint[:, :P] = jac.reshape(-1, P)
    for w in range(W):
        joint[w * K * C : (w + 1) * K * C, P + w] = jac_v[w].ravel()
    cov = np.linalg.inv(joint.T @ joint + np.diag(np.concatenate([prec, np.full(W, V0_STD**-2)])))
    flat = profiled(jac, jac_v).reshape(-1, P)
    np.testing.assert_allclose(np.linalg.inv(flat.T @ flat + np.diag(prec)), cov[:P, :P], rtol=1e-10)
    np.testing.assert_array_equal(profiled(jac, jac_v)[2], jac[2])


def test_a_model_error_widens_the_interval_by_its_own_scale_and_correlation(x64):
    # The drive's steer acts 0.15 s late; the model has no delay. The residual is then model
    # error, far above the sensor noise, and the interval widens with it.
    veh = default_vehicle()
    settings = ProblemSettings(longitudinal="speed", max_window=6.0)
    box = Box.from_dict(prior_box(veh), PARAM_NAMES)
    free = ("C_alpha_f", "C_alpha_r")
    clean = fit_likelihood(
        make_problem(_drive(), veh, settings), THETA, box, FitRequest(free=free, max_steps=20)
    )
    late_drive = make_problem(_drive(steer_delay=0.15), veh, settings)
    late = fit_likelihood(late_drive, THETA, box, FitRequest(free=free, max_steps=20))
    assert np.all(late.noise.model_error_ratio > 3.0 * clean.noise.model_error_ratio)
    i = [PARAM_NAMES.index(n) for n in free]
    assert np.all(np.sqrt(np.diag(late.cov_z))[i] > 3.0 * np.sqrt(np.diag(clean.cov_z))[i])
    # What the information alone allows is never wider than the reported posterior.
    for post in (clean, late):
        assert np.all(np.linalg.eigvalsh(post.cov_z - post.cov_information) > -1e-12)


def _halves(rng, shift, prec):
    # A linear model whitened by its noise, two halves of different excitation; half A's first
    # coefficient is moved by `shift` (what an effect the model lacks does to one half).
    n, theta = 400, np.array([0.5, -0.3, 0.2])
    half = np.arange(n) < n // 2
    x = rng.standard_normal((n, 3)) * np.where(half, 1.0, 2.0)[:, None]
    y = x @ theta + np.where(half, shift, 0.0) * x[:, 0] + rng.standard_normal(n)
    h = x.T @ x + np.diag(prec)
    z = np.linalg.solve(h, x.T @ y)
    exact = [np.linalg.solve(x[m].T @ x[m] + np.diag(prec / 2), x[m].T @ y[m]) for m in (half, ~half)]
    args = (np.linalg.inv(h), x[None, :, None, :], (x @ z - y)[None, :, None], z, prec)
    return args, [("first against second half", half[None, :, None])], exact[0] - exact[1]


def test_halves_that_share_one_theta_rarely_widen_and_a_moved_half_is_caught():
    from vdsbi.estimation._widening import JOINT_LEVEL, consistent_covariance, tempered

    rng = np.random.default_rng(0)
    prec = np.full(3, 5.0)  # a prior strong enough that leaving its gradient out would show
    rejected = 0
    for _ in range(300):
        args, splits, _ = _halves(rng, 0.0, prec)
        cov, shifts, joint = consistent_covariance(*args, splits)
        rejected += joint is not None
        if joint is None and not shifts:
            np.testing.assert_array_equal(cov, args[0])  # consistent halves leave it as it was
    assert abs(rejected / 300 - (1 - JOINT_LEVEL)) < 0.03  # the test's level under a right model
    args, splits, exact = _halves(rng, 0.4, prec)
    cov, shifts, joint = consistent_covariance(*args, splits)
    assert joint is not None and joint["scale"] == joint["D2"] / 3 > 1.0
    assert list(shifts) == [0] and shifts[0]["z_shift"] == pytest.approx(abs(exact[0]), rel=1e-6)
    assert np.all(np.diag(cov) >= np.diag(tempered(args[0], prec, joint["scale"])) - 1e-12)


def test_tempering_divides_the_data_information_and_leaves_the_prior():
    from vdsbi.estimation._widening import tempered

    rng = np.random.default_rng(1)
    x = rng.standard_normal((200, 3))
    x[:, 2] = 0.0  # a parameter the data do not inform
    prec, scale = np.array([0.5, 0.5, 0.3]), 7.0
    cov = np.linalg.inv(x.T @ x + np.diag(prec))
    widened = tempered(cov, prec, scale)
    np.testing.assert_allclose(widened, np.linalg.inv(x.T @ x / scale + np.diag(prec)), rtol=1e-9, atol=1e-12)
    assert widened[2, 2] == pytest.approx(1 / prec[2], rel=1e-9)  # the prior's, not scale times it
    flat = np.full(3, 1e-9)
    cov_flat = np.linalg.inv(x[:, :2].T @ x[:, :2] + np.diag(flat[:2]))
    np.testing.assert_allclose(tempered(cov_flat, flat[:2], scale), scale * cov_flat, rtol=1e-6)


def test_the_parameters_a_drive_informs_are_those_its_channels_depend_on(x64):
    # The step test agrees with the Jacobian's non-zero columns; following the measured speed, the
    # longitudinal slip stiffnesses act on nothing compared.
    import jax
    import jax.numpy as jnp

    from vdsbi.estimation._start import informed_parameters
    from vdsbi.problem import windowed_model
    from vdsbi.problem.points import split_parameters

    veh = default_vehicle()
    box = Box.from_dict(prior_box(veh), PARAM_NAMES)
    box = Box(jnp.asarray(box.low, jnp.float64), jnp.asarray(box.high, jnp.float64), PARAM_NAMES)
    z0 = np.asarray(box.to_unbounded(THETA))
    for mode in ("speed", "torque"):
        prob = make_problem(_drive(duration=8.0), veh, ProblemSettings(longitudinal=mode, max_window=6.0))
        wm = windowed_model(prob)
        compared = lambda z, wm=wm: wm(*split_parameters(box.from_unbounded(z), ()))[0]
        jac = jax.jacfwd(compared)(jnp.asarray(z0))
        jac = np.where(np.asarray(prob.valid)[..., None, None], np.asarray(jac), 0.0)
        depends = {n for n, col in zip(PARAM_NAMES, np.moveaxis(jac, -1, 0)) if np.any(col != 0.0)}
        assert set(informed_parameters(wm, prob, box, z0, (), batch=4)) == depends, mode
        assert ("C_kappa_f" in depends) == (mode == "torque"), mode


def test_a_starting_noise_model_must_be_of_the_problems_channels():
    from vdsbi.estimation._likelihood import NoiseModel

    veh = default_vehicle()
    prob = make_problem(_drive(duration=8.0), veh, ProblemSettings(longitudinal="speed", max_window=6.0))
    box = Box.from_dict(prior_box(veh), PARAM_NAMES)
    other = NoiseModel(("ax",), np.ones(1), np.ones(1), np.ones(1), np.ones(1))
    with pytest.raises(ValueError, match="noise model"):
        fit_likelihood(prob, THETA, box, FitRequest(noise=ModelError(start=other)))


def test_prediction_draws_from_the_information_and_the_intervals_from_the_widened_covariance(getkey):
    import jax

    from vdsbi.estimation import NoiseModel
    from vdsbi.estimation._likelihood import LikelihoodPosterior

    box = Box(np.array([0.0, 0.0]), np.array([1.0, 1.0]), ("a", "b"))
    info = np.array([[0.04, 0.01], [0.01, 0.09]])
    ones = np.ones(1)
    noise = NoiseModel(("ay",), ones, ones, ones, ones)
    post = LikelihoodPosterior(box, np.zeros(2), 6.0 * info, info, ("a", "b"), noise, True, (3,))
    to_z = jax.vmap(box.to_unbounded)
    for draws, cov in (
        (post.predictive_draws(getkey(), 20000), info),
        (post.sample(getkey(), 20000), 6.0 * info),
    ):
        np.testing.assert_allclose(np.cov(np.asarray(to_z(draws)).T), cov, rtol=0.1, atol=2e-3)


def test_the_screen_keeps_a_quadratic_posterior_and_cuts_draws_past_a_wall(x64, getkey):
    # A well-specified drive: the cost is as quadratic as the fit assumed, so nearly every draw
    # stays. The same posterior told its cost is nearly flat (as a wall looks from the fit, e.g. a
    # high CoG that spins a hard-cornering car) with a 10× wider Gaussian: the screen keeps only
    # the draws the likelihood allows, about as spread as the real posterior.
    import equinox as eqx

    from vdsbi.estimation import screened_sample

    veh = default_vehicle()
    settings = ProblemSettings(longitudinal="torque", max_window=6.0, channels=("ay", "yaw_rate"))
    prob = make_problem(_drive(), veh, settings)
    box = Box.from_dict(prior_box(veh), PARAM_NAMES)
    request = FitRequest(free=("C_alpha_f", "C_alpha_r"), noise=ModelError(passes=1), max_steps=20)
    post = fit_likelihood(prob, THETA, box, request)
    draws, kept = screened_sample(getkey(), post, prob, 256)
    assert draws.shape == (256, len(PARAM_NAMES)) and kept > 0.9, kept
    i = PARAM_NAMES.index("C_alpha_f")
    spread = np.asarray(post.sample(getkey(), 4000))[:, i].std()
    flat = eqx.tree_at(lambda p: (p.cov_z, p.curvature), post, (100 * post.cov_z, 1e-6 * post.curvature))
    wide = np.asarray(flat.sample(getkey(), 4000))[:, i].std()
    draws, kept = screened_sample(getkey(), flat, prob, 256)
    assert wide > 5 * spread and kept < 0.5
    assert draws[:, i].std() < 2 * spread


def test_a_delay_the_model_lacks_moves_the_transient_half_against_the_steady_one():
    from types import SimpleNamespace

    from vdsbi.estimation._widening import consistent_covariance, data_splits

    # One gain fitted to a lateral response that lags its input by 0.1 s: steady cornering
    # (a plateau) says the gain is 1, the fast slalom says less; noise 0.02.
    rng = np.random.default_rng(3)
    t = np.arange(0.0, 20.0, 0.02)
    u = lambda s: np.where(s < 10.0, np.clip(s / 2.0, 0.0, 1.0), np.cos(2 * np.pi * 1.2 * (s - 10.0)))  # noqa: E731
    y = u(t - 0.1) + 0.02 * rng.standard_normal(t.size)
    x = u(t)
    gain = float(x @ y / (x @ x + 1e-6))
    data = SimpleNamespace(y=y[None, :, None], channels=("ay",))
    mask = np.ones((1, t.size), bool)
    splits = dict(data_splits(data, mask))
    assert list(splits) == [
        "high against low lateral motion",
        "transient against steady lateral motion",
        "first against second half",
    ]
    for half in splits.values():
        assert 0.45 < half.mean() < 0.55
    jac, r = (x / 0.02)[None, :, None, None], ((gain * x - y) / 0.02)[None, :, None]
    cov = np.array([[1.0 / (jac.ravel() @ jac.ravel() + 1e-6)]])
    transient = "transient against steady lateral motion"
    _, shifts, _ = consistent_covariance(
        cov, jac, r, np.array([gain]), np.array([1e-6]), [(transient, splits[transient])]
    )
    assert shifts and shifts[0]["sigmas"] > 2.0


def test_the_prior_sits_at_an_effects_start_and_at_the_least_effect_a_box_allows():
    from vdsbi.simulator.effects import EFFECTS

    friction = EFFECTS["tyre_friction"]
    names = (*PARAM_NAMES, "tyre_friction.scale_front", "tyre_friction.scale_rear")
    veh = default_vehicle()
    bounds = prior_box(veh, ("tyre_friction",))
    box = Box.from_dict(bounds, names)
    mode = np.asarray(box.from_unbounded(prior_mean(box, (friction,))))
    np.testing.assert_allclose(mode[6:], friction.start, rtol=1e-6)  # not the box's centre, 1.1
    np.testing.assert_allclose(mode[:6], 0.5 * (np.asarray(box.low) + np.asarray(box.high))[:6], rtol=1e-6)
    # A grip floor above the start: the mode is just inside the floor.
    floored = Box.from_dict(prior_box(veh, ("tyre_friction",), grip=1.2), names)
    mode = np.asarray(floored.from_unbounded(prior_mean(floored, (friction,))))
    low, high = np.asarray(floored.low)[6:], np.asarray(floored.high)[6:]
    assert np.all(low > 1.0)
    np.testing.assert_allclose(mode[6:], low + 0.05 * (high - low), rtol=1e-6)


def test_a_start_that_does_not_simulate_is_an_infinitely_bad_fit_not_a_crash(x64, monkeypatch):
    import jax.numpy as jnp

    import vdsbi.estimation._likelihood as likelihood
    from vdsbi.estimation._least_squares import LeastSquaresResult

    veh = default_vehicle()
    # A window length no other test here uses: the jitted fit traces afresh, with the stand-in.
    prob = make_problem(_drive(), veh, ProblemSettings(longitudinal="torque", max_window=5.5))
    box = Box.from_dict(prior_box(veh), PARAM_NAMES)

    def nowhere(fn, z0, **kw):  # what the solver returns when its start evaluates to NaN
        r = jnp.full(fn(z0).shape, jnp.nan)
        jac = jnp.full((*r.shape, *z0.shape), jnp.nan)
        return LeastSquaresResult(z0, r, jac, jnp.asarray(jnp.inf), jnp.asarray(0), jnp.asarray(False))

    monkeypatch.setattr(likelihood, "levenberg_marquardt", nowhere)
    post = fit_likelihood(prob, THETA, box, FitRequest(free=("C_alpha_f", "C_alpha_r"), max_steps=5))
    assert post.chi2_dof == np.inf and not post.converged
    assert np.all(np.isfinite(post.cov_z)) and np.all(np.isfinite(post.interval(0.9)))
