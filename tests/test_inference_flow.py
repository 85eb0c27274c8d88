import warnings

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import pytest

from vdsbi.inference import (
    BoxPrior,
    ChannelStandardization,
    IdentityEmbedding,
    MLPEmbedding,
    Posterior,
    SplineFlowSettings,
)
from vdsbi.inference._flow import ConditionalFlow
from vdsbi.inference._standardize import GlobalStandardization, Standardizer, TrajectoryStandardization
from vdsbi.inference._theta_map import IdentityMap


def _perturbed(flow, key, scale):
    """Perturb the trainable weights so the density is far from the initial near-identity flow."""
    params, static = eqx.partition(flow.layers, eqx.is_inexact_array)
    leaves, tree = jax.tree.flatten(params)
    keys = jax.random.split(key, len(leaves))
    leaves = [leaf + scale * jax.random.normal(k, leaf.shape) for leaf, k in zip(leaves, keys)]
    return eqx.tree_at(lambda f: f.layers, flow, eqx.combine(jax.tree.unflatten(tree, leaves), static))


def test_flow_density_integrates_to_one(getkey):
    prior = BoxPrior(jnp.array([-1.0, 0.0]), jnp.array([2.0, 1.5]))
    flow = ConditionalFlow(
        getkey(), prior, IdentityEmbedding(1), (1,), SplineFlowSettings(num_layers=3, num_bins=6, hidden=16)
    )
    flow = _perturbed(flow, getkey(), 0.1)
    n = 600
    g0 = jnp.linspace(-1.0, 2.0, n + 1)
    g1 = jnp.linspace(0.0, 1.5, n + 1)
    c0, c1 = 0.5 * (g0[1:] + g0[:-1]), 0.5 * (g1[1:] + g1[:-1])
    grid = jnp.stack(jnp.meshgrid(c0, c1, indexing="ij"), -1).reshape(-1, 2)
    cell = (3.0 / n) * (1.5 / n)
    for x in (jnp.array([0.3]), jnp.array([-2.0])):
        lp = Posterior(flow, x).log_prob(grid)
        total = float(jnp.sum(jnp.exp(lp)) * cell)
        assert abs(total - 1.0) < 5e-3, total
        # and it is not the uniform density: the test would be vacuous otherwise
        assert float(jnp.std(jnp.exp(lp))) > 0.05


def test_samples_never_leave_prior_box(getkey):
    prior = BoxPrior(jnp.array([-1.0, 5.0, 0.0]), jnp.array([1.0, 5.001, 100.0]))
    flow = ConditionalFlow(
        getkey(), prior, IdentityEmbedding(2), (2,), SplineFlowSettings(num_layers=2, num_bins=4, hidden=8)
    )
    flow = _perturbed(flow, getkey(), 3.0)  # wild weights push mass against the box edges
    post = Posterior(flow, jnp.array([50.0, -50.0]))
    s = np.asarray(post.sample(getkey(), 20_000))
    u = (s - np.asarray(prior.low)) / np.asarray(prior.high - prior.low)
    assert np.mean((u < 1e-3) | (u > 1 - 1e-3)) > 0.1  # the test really probes the edges
    assert np.all(s >= np.asarray(prior.low)) and np.all(s <= np.asarray(prior.high))
    # strictly inside where float32 can resolve it (dims 0 and 2)
    assert np.all(s[:, [0, 2]] > np.asarray(prior.low)[[0, 2]])
    assert np.all(s[:, [0, 2]] < np.asarray(prior.high)[[0, 2]])
    assert np.all(np.isfinite(np.asarray(post.log_prob(s))))
    # log_prob is -inf outside the box
    out = jnp.array([[1.5, 5.0005, 50.0], [0.0, 4.9, 50.0]])
    assert np.all(np.isneginf(np.asarray(post.log_prob(out))))


def test_flow_with_time_channel_inputs(getkey):
    # x of shape (T, C) standardised per channel, embedded by an MLP
    t, c = 20, 3
    xs = jax.random.normal(getkey(), (64, t, c)) * jnp.array([1.0, 10.0, 100.0]) + 5.0
    std = ChannelStandardization().fit(xs)
    assert std.mean.shape == (c,)
    np.testing.assert_allclose(np.asarray(jax.vmap(std)(xs)).reshape(-1, c).std(0), 1.0, rtol=1e-4)
    assert GlobalStandardization().fit(xs).mean.shape == ()
    prior = BoxPrior(jnp.zeros(2), jnp.ones(2))
    emb = MLPEmbedding(getkey(), t * c, 8, 16, 1)
    flow = ConditionalFlow(
        getkey(), prior, emb, (t, c), SplineFlowSettings(num_layers=2, hidden=8), x_standardizer=std
    )
    lp = jax.vmap(flow.log_prob)(jnp.full((64, 2), 0.5), xs)
    assert lp.shape == (64,) and np.all(np.isfinite(np.asarray(lp)))


def test_trajectory_standardisation_exposes_small_deviations(getkey, tmp_path):
    # simulations sharing one time base: a large common manoeuvre, a small θ-driven part, and an
    # input channel identical in every example
    n, t = 256, 50
    base = jnp.linspace(0.0, 100.0, t)  # speed ramp dwarfs the signal
    a = jax.random.normal(getkey(), (n, 1, 1))
    sig = base[None, :, None] + 0.01 * a * jnp.ones((1, t, 1))
    inp = jnp.broadcast_to(jnp.sin(jnp.arange(t) / 5.0)[None, :, None], (n, t, 1))
    xs = jnp.concatenate([sig, inp], -1)
    std = TrajectoryStandardization().fit(xs)
    assert std.mean.shape == std.std.shape == (t, 2)
    z = np.asarray(jax.vmap(std)(xs))
    # the small part is O(1) and carries a: per-channel scaling would leave it at ~3e-4
    np.testing.assert_allclose(z[:, 0, 0], np.asarray(a[:, 0, 0] - a.mean()) / np.asarray(a.std()), atol=1e-2)
    per_channel = np.asarray(jax.vmap(ChannelStandardization().fit(xs))(xs))
    assert np.std(per_channel[:, 0, 0]) < 1e-3
    # the input channel is kept (per-channel standardised), not zeroed
    np.testing.assert_allclose(z[0, :, 1].std(), 1.0, rtol=1e-3)
    # and the flow round-trips through save/load with the (T, C)-shaped statistics
    prior = BoxPrior(jnp.zeros(2), jnp.ones(2))
    flow = ConditionalFlow(
        getkey(),
        prior,
        MLPEmbedding(getkey(), t * 2, 8, 16, 1),
        (t, 2),
        SplineFlowSettings(num_layers=2, hidden=8),
        x_standardizer=std,
    )
    post = Posterior(flow, xs[0])
    post.save(tmp_path / "p.npz")
    back = Posterior.load(tmp_path / "p.npz")
    np.testing.assert_array_equal(np.asarray(back.flow.x_standardizer.mean), np.asarray(std.mean))
    s = post.sample(jax.random.key(1), 10)
    np.testing.assert_allclose(np.asarray(back.log_prob(s)), np.asarray(post.log_prob(s)), rtol=1e-5)


def _grid_mass(post, low, high, n=400):
    g0, g1 = jnp.linspace(low[0], high[0], n + 1), jnp.linspace(low[1], high[1], n + 1)
    c0, c1 = 0.5 * (g0[1:] + g0[:-1]), 0.5 * (g1[1:] + g1[:-1])
    grid = jnp.stack(jnp.meshgrid(c0, c1, indexing="ij"), -1).reshape(-1, 2)
    lp = post.log_prob(grid)
    return float(jnp.sum(jnp.exp(lp)) * (high[0] - low[0]) * (high[1] - low[1]) / n**2), lp


def test_a_conditional_flow_is_normalised_conditional_and_round_trips(getkey, tmp_path):
    prior = BoxPrior(jnp.array([-1.0, 0.0]), jnp.array([2.0, 1.5]))
    architecture = SplineFlowSettings(num_layers=3, num_bins=6, hidden=16)
    flow = ConditionalFlow(getkey(), prior, IdentityEmbedding(1), (1,), architecture)
    flow = _perturbed(flow, getkey(), 0.1)
    masses, lps = zip(
        *(
            _grid_mass(Posterior(flow, x), (-1.0, 0.0), (2.0, 1.5))
            for x in (jnp.array([0.3]), jnp.array([-2.0]))
        )
    )
    for m in masses:
        assert abs(m - 1.0) < 5e-3, m
    assert float(jnp.max(jnp.abs(lps[0] - lps[1]))) > 0.1  # the context matters
    post = Posterior(flow, jnp.array([0.3]))
    post.save(tmp_path / "g.npz")
    back = Posterior.load(tmp_path / "g.npz")
    s = post.sample(getkey(), 50)
    np.testing.assert_allclose(np.asarray(back.log_prob(s)), np.asarray(post.log_prob(s)), rtol=1e-5)


def test_affine_theta_map_cuts_the_density_at_the_box_and_samples_inside(getkey, tmp_path):
    prior = BoxPrior(jnp.array([-1.0, 0.0]), jnp.array([2.0, 1.5]))
    # θ-scale standardisation wider than the box: a good share of the flow's mass leaks out
    std = Standardizer(mean=jnp.array([0.5, 0.75]), std=jnp.array([1.5, 0.75]))
    flow = ConditionalFlow(
        getkey(),
        prior,
        IdentityEmbedding(1),
        (1,),
        SplineFlowSettings(num_layers=2, num_bins=6, hidden=16, theta_map=IdentityMap()),
        theta_standardizer=std,
    )
    flow = _perturbed(flow, getkey(), 0.1)
    x = jnp.array([0.3])
    post = Posterior(flow, x)
    # the raw flow's share of draws inside the box is the density's mass on the box
    eps = jax.random.normal(getkey(), (200_000, 2))
    raw = jax.vmap(lambda e: std.inverse(flow._from_noise(e, flow.context(x))[0]))(eps)
    inside = float(jnp.mean(jnp.all((raw >= prior.low) & (raw <= prior.high), axis=1)))
    assert 0.2 < inside < 0.8  # not vacuous: the cut matters
    mass, _ = _grid_mass(post, (-1.0, 0.0), (2.0, 1.5))
    assert abs(mass - inside) < 5e-3, (mass, inside)
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # enough mass in the box: no warning
        s = np.asarray(post.sample(getkey(), 20_000))
        jax.effects_barrier()
    assert np.all(s >= np.asarray(prior.low)) and np.all(s <= np.asarray(prior.high))
    np.testing.assert_allclose(
        s.mean(0),
        np.asarray(raw[np.asarray(jnp.all((raw >= prior.low) & (raw <= prior.high), axis=1))].mean(0)),
        atol=0.02,
    )
    # nearly all mass outside: the draws still lie in the box
    far = eqx.tree_at(
        lambda f: f.theta_standardizer, flow, Standardizer(mean=jnp.array([30.0, 30.0]), std=std.std)
    )
    with pytest.warns(RuntimeWarning, match="only 0 of 1000"):
        s = np.asarray(Posterior(far, x).sample(getkey(), 1000))
        jax.effects_barrier()
    assert np.all(s >= np.asarray(prior.low)) and np.all(s <= np.asarray(prior.high))
    # about 0.3 % inside, under the 1 % that 100 rounds of rejection fill: the slots left over
    # repeat accepted draws instead of piling clipped ones on the box's faces
    thin = eqx.tree_at(
        lambda f: f.theta_standardizer, flow, Standardizer(mean=jnp.array([0.5, 3.5]), std=std.std)
    )
    assert 1e-3 < float(thin.box_mass(getkey(), thin.context(x), 200_000)) < 1e-2
    with pytest.warns(RuntimeWarning, match="leaked out of the box"):
        s = np.asarray(Posterior(thin, x).sample(getkey(), 20_000))
        jax.effects_barrier()
    assert np.all((s > np.asarray(prior.low)) & (s < np.asarray(prior.high)))  # none on a face
    distinct = np.unique(s, axis=0)
    assert 20 < len(distinct) < 20_000  # some accepted (~0.3 % of 2·10⁶ tries), all repeated
    counts = np.unique(s, axis=0, return_counts=True)[1]
    assert counts.max() - counts.min() <= 1  # repeated in turn, evenly
    post.save(tmp_path / "a.npz")
    assert Posterior.load(tmp_path / "a.npz").flow.theta_map == IdentityMap()
