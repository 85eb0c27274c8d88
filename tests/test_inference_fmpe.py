"""Flow-matching posterior estimator: ODE invertibility, normalisation, change of variables,
a trained Gaussian case against its analytic posterior, and the Posterior file round trip."""

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import pytest

from vdsbi.inference import (
    BoxPrior,
    FlowMatchingSettings,
    IdentityEmbedding,
    NPEConfig,
    Posterior,
    RoundSchedule,
    TrainingSettings,
    apt,
    npe,
)
from vdsbi.inference._flow_matching import FlowMatchingEstimator
from vdsbi.inference._theta_map import IdentityMap, LogitMap


def _perturbed(est, key, scale):
    """Random vector-field weights, so the transport is far from any trivial map."""
    params, static = eqx.partition(est.vector_field, eqx.is_inexact_array)
    leaves, tree = jax.tree.flatten(params)
    keys = jax.random.split(key, len(leaves))
    leaves = [leaf + scale * jax.random.normal(k, leaf.shape, leaf.dtype) for leaf, k in zip(leaves, keys)]
    return eqx.tree_at(lambda e: e.vector_field, est, eqx.combine(jax.tree.unflatten(tree, leaves), static))


def _estimator(key, prior, theta_map, ode_steps=16):
    k1, k2 = jax.random.split(key)
    est = FlowMatchingEstimator(
        k1,
        prior,
        IdentityEmbedding(1),
        (1,),
        FlowMatchingSettings(hidden=16, num_blocks=2, ode_steps=ode_steps, theta_map=theta_map),
    )
    return _perturbed(est, k2, 0.3)


def test_ode_maps_noise_to_samples_and_back(getkey, x64):
    prior = BoxPrior(jnp.array([-1.0, 0.0, 2.0]), jnp.array([2.0, 1.5, 9.0]))
    k_est, k_z = getkey(), getkey()
    errors = []
    for steps in (10, 40):
        est = _estimator(k_est, prior, LogitMap(), ode_steps=steps)
        ctx = est.context(jnp.array([0.7]))
        z0 = jax.random.normal(k_z, (64, 3))
        z1 = est.transport(z0, ctx, 0.0, 1.0)
        assert float(jnp.max(jnp.abs(z1 - z0))) > 0.3  # the map really moves the points
        errors.append(float(jnp.max(jnp.abs(est.transport(z1, ctx, 1.0, 0.0) - z0))))
    assert errors[1] < 1e-6, errors
    assert errors[1] < errors[0] / 4**4  # fourth order at least (Tsit5 is fifth)


def test_density_integrates_to_one_and_matches_change_of_variables(getkey, x64):
    # logit map: all mass inside the box, so the grid integral must be 1
    prior = BoxPrior(jnp.array([-1.0, 0.0]), jnp.array([2.0, 1.5]))
    post = Posterior(_estimator(getkey(), prior, LogitMap(), ode_steps=12), jnp.array([0.3]))
    n = 64
    g0, g1 = (jnp.linspace(lo, hi, n + 1) for lo, hi in ((-1.0, 2.0), (0.0, 1.5)))
    mids = [0.5 * (g[1:] + g[:-1]) for g in (g0, g1)]
    grid = jnp.stack(jnp.meshgrid(*mids, indexing="ij"), -1).reshape(-1, 2)
    p = jnp.exp(post.log_prob(grid))
    assert abs(float(jnp.sum(p) * (3.0 / n) * (1.5 / n)) - 1.0) < 1e-2
    assert float(jnp.std(p)) > 0.05  # not the uniform density

    # affine map, identity standardisation, wide box: θ is the ODE state itself, so
    # log q(T(z0)) = log N(z0) - log|det ∂T/∂z0|, with T differentiated through the solver
    wide = BoxPrior(jnp.full(2, -50.0), jnp.full(2, 50.0))
    est = _estimator(getkey(), wide, IdentityMap(), ode_steps=24)
    ctx = est.context(jnp.array([-0.4]))
    z0 = jax.random.normal(getkey(), (5, 2))

    def expected(z):
        jac = jax.jacrev(lambda y: est.transport(y[None], ctx, 0.0, 1.0)[0])(z)
        return -0.5 * jnp.sum(z**2) - jnp.log(2 * jnp.pi) - jnp.linalg.slogdet(jac)[1]

    theta = est.transport(z0, ctx, 0.0, 1.0)
    got = jax.vmap(lambda t: est.log_prob_context(t, ctx))(theta)
    want = jax.vmap(expected)(z0)
    assert float(jnp.max(jnp.abs(want - jax.vmap(lambda z: -0.5 * jnp.sum(z**2))(z0)))) > 0.1
    np.testing.assert_allclose(np.asarray(got), np.asarray(want), atol=1e-5)


def test_trained_on_linear_gaussian_recovers_the_analytic_posterior(getkey):
    # x = A θ + N(0, s² I) with a box far wider than the posterior: q(θ | x) ≈ N(A⁻¹x, s² (AᵀA)⁻¹)
    a = np.array([[1.0, 0.6], [0.0, 0.8]])
    s = 0.3
    prior = BoxPrior(jnp.full(2, -4.0), jnp.full(2, 4.0))
    theta = np.asarray(prior.sample(getkey(), 4000))
    x = theta @ a.T + s * np.asarray(jax.random.normal(getkey(), theta.shape))
    cfg = NPEConfig(
        flow=FlowMatchingSettings(theta_map=IdentityMap(), hidden=32, num_blocks=2, ode_steps=8),
        training=TrainingSettings(batch_size=128, learning_rate=3e-3, max_epochs=40, patience=40),
    )
    est, info = npe(getkey(), prior, theta, x, embedding=IdentityEmbedding(2), config=cfg)
    assert info["val_losses"][-1] < 0.8 * info["val_losses"][0]
    cov = s**2 * np.linalg.inv(a.T @ a)
    for x_o in (np.array([0.5, -0.3]), np.array([-1.2, 1.0])):
        post = Posterior(est, jnp.asarray(x_o, jnp.float32))
        draws = np.asarray(post.sample(getkey(), 4000))
        mean = np.linalg.solve(a, x_o)
        # posterior sds are 0.3-0.5: a mean off by 0.1 or a covariance off by 35 % fails
        np.testing.assert_allclose(draws.mean(0), mean, atol=0.1)
        np.testing.assert_allclose(np.cov(draws.T), cov, rtol=0.35, atol=0.02)
        # log_prob is the analytic density's up to the fit: compare at the analytic mean
        lp = float(post.log_prob(jnp.asarray(mean, jnp.float32)))
        want = -np.log(2 * np.pi) - 0.5 * np.linalg.slogdet(cov)[1]
        assert abs(lp - want) < 0.35, (lp, want)


def test_posterior_file_round_trip_and_bad_configs(getkey, tmp_path):
    prior = BoxPrior(jnp.array([0.0, -2.0]), jnp.array([1.0, 2.0]), names=("a", "b"))
    post = Posterior(_estimator(getkey(), prior, IdentityMap(), ode_steps=6), jnp.array([0.2]))
    post.save(tmp_path / "fmpe.npz")
    back = Posterior.load(tmp_path / "fmpe.npz")
    assert isinstance(back.flow, FlowMatchingEstimator) and back.prior.names == ("a", "b")
    key = getkey()
    mine, theirs = np.asarray(post.sample(key, 300)), np.asarray(back.sample(key, 300))
    np.testing.assert_array_equal(mine, theirs)
    assert np.all((mine >= [0.0, -2.0]) & (mine <= [1.0, 2.0]))
    np.testing.assert_allclose(np.asarray(back.log_prob(mine)), np.asarray(post.log_prob(mine)), rtol=1e-6)
    with pytest.raises(ValueError, match="atomic"):
        apt(
            getkey(),
            lambda k, t: (t, jnp.ones(t.shape[0], bool)),
            prior,
            jnp.zeros(2),
            embedding=IdentityEmbedding(2),
            schedule=RoundSchedule(rounds=2, sims_per_round=100),
            config=NPEConfig(flow=FlowMatchingSettings()),
        )
