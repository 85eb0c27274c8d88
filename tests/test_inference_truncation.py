"""TSNPE's truncated prior: exact (the same law whichever proposal finds it) and reachable in
regions far smaller than the prior box."""

import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from scipy import stats

from vdsbi.inference import (
    BoxPrior,
    IdentityEmbedding,
    NPEConfig,
    RoundSchedule,
    SplineFlowSettings,
    TrainingSettings,
    _truncation,
    apt,
)
from vdsbi.inference._build import build_flow
from vdsbi.inference._posterior import flow_log_prob
from vdsbi.inference._theta_map import IdentityMap

FLOW = SplineFlowSettings(num_layers=2, num_bins=4, hidden=8, theta_map=IdentityMap())
SAMPLES = 4000  # posterior draws that locate the region's level


def _region(key, d, width, centre=0.5):
    """An untrained flow whose density is ~ N(centre, width²) per coordinate in the box [-5, 5]^d."""
    prior = BoxPrior(-5.0 * np.ones(d), 5.0 * np.ones(d))
    theta = centre + width * np.asarray(jax.random.normal(key, (2000, d)), np.float32)
    flow = build_flow(jax.random.fold_in(key, 1), prior, IdentityEmbedding(d), theta, theta, FLOW)
    return flow, prior, theta[0]


def test_ellipsoid_draws_are_uniform_inside_it(getkey):
    chol = np.array([[2.0, 0.0, 0.0], [0.5, 0.3, 0.0], [-1.0, 0.2, 0.7]])
    ell = _truncation._Ellipsoid(np.array([1.0, -2.0, 0.5]), chol, 1.5)
    draws = ell.sample(getkey(), 20_000)
    r = ell.distance(draws) / ell.radius
    assert r.max() <= 1.0 + 1e-9
    assert stats.kstest(r**3, "uniform").pvalue > 1e-3  # radius^d uniform: uniform in volume
    assert ell.log_volume() == pytest.approx(math.log(4 / 3 * math.pi * 1.5**3 * 2.0 * 0.3 * 0.7))
    unit = (draws - ell.mean) @ np.linalg.inv(chol).T  # isotropic once the covariance is undone
    assert np.abs(unit.mean(0)).max() < 0.05


@pytest.mark.parametrize("scale", [1.25, 0.4])
def test_ellipsoid_and_prior_rejection_draw_the_same_truncated_prior(getkey, monkeypatch, scale):
    """Both proposals are exact, so their draws agree in law; an ellipsoid started too small
    (scale 0.4 cuts the region) must grow until it holds the region. The region touches the
    box's face at 5, so the ellipsoid reaches outside the box."""
    monkeypatch.setattr(_truncation, "_SCALE", scale)
    flow, prior, x_o = _region(getkey(), d=3, width=0.3, centre=4.5)
    n, key = 2000, getkey()  # one key: the same reference draws, hence the same region
    by_prior, info_p = _truncation.truncated_prior(
        key, flow, prior, x_o, n, num_samples=SAMPLES, ellipsoid=False
    )
    by_ell, info_e = _truncation.truncated_prior(
        key, flow, prior, x_o, n, num_samples=SAMPLES, ellipsoid=True
    )
    assert info_p["num_filled"] == info_e["num_filled"] == 0
    assert info_e["region_covered"] and (info_e["ellipsoid_growths"] > 0) == (scale < 1)
    assert info_e["acceptance"] > 20 * info_p["acceptance"]
    assert np.asarray(by_prior).max() > 4.95  # the box cuts the region
    for a, b in zip(np.asarray(by_prior).T, np.asarray(by_ell).T, strict=True):
        assert stats.ks_2samp(a, b).pvalue > 1e-3
    lp_p, lp_e = (np.asarray(flow_log_prob(flow, t, x_o)) for t in (by_prior, by_ell))
    assert stats.ks_2samp(lp_p, lp_e).pvalue > 1e-3


def test_auto_reaches_a_ten_dimensional_region_without_posterior_draws(getkey):
    """Prior mass of the region ~1e-12: rejection from the box finds nothing, the ellipsoid does."""
    flow, prior, x_o = _region(getkey(), d=10, width=0.1)
    theta, info = _truncation.truncated_prior(getkey(), flow, prior, x_o, 1000, num_samples=SAMPLES)
    assert info["region_proposal"] == "ellipsoid" and info["region_covered"]
    assert info["num_filled"] == 0 and theta.shape == (1000, 10)
    assert np.all(np.isfinite(np.asarray(flow_log_prob(flow, theta, x_o))))


def test_unreachable_region_is_filled_from_the_wider_proposal_and_warned(getkey, monkeypatch):
    """Filled draws come from the proposal (here the box: a truncated prior too, only wider),
    never from the posterior, whose draws would bias maximum likelihood to a narrower fit."""
    monkeypatch.setattr(_truncation, "_BATCHES", 1)
    flow, prior, x_o = _region(getkey(), d=10, width=0.1)
    with pytest.warns(UserWarning, match="wider prior region"):
        theta, info = _truncation.truncated_prior(
            getkey(), flow, prior, x_o, 1000, num_samples=SAMPLES, ellipsoid=False
        )
    assert info["num_filled"] == 1000 - round(info["acceptance"] * 10_000) > 900
    theta = np.asarray(theta)
    assert theta.shape == (1000, 10) and np.all(np.abs(theta) <= 5.0)
    assert np.all(np.abs(theta.std(0) - 10 / np.sqrt(12)) < 0.4)  # the box's spread, not the region's 0.1


def test_tsnpe_rounds_propose_from_the_truncated_prior(getkey):
    """Later rounds draw from the truncated prior (none filled in from the posterior), which is
    narrower than the prior once the first round has learned something."""

    def simulate(key, theta):
        return theta + 0.03 * jax.random.normal(key, theta.shape), jnp.ones(theta.shape[0], bool)

    prior = BoxPrior(-np.ones(6), np.ones(6))
    config = NPEConfig(
        flow=SplineFlowSettings(num_layers=2, num_bins=4, hidden=16, theta_map=IdentityMap()),
        training=TrainingSettings(max_epochs=100),
    )
    emb = IdentityEmbedding(6)
    x_o = np.full(6, 0.2)
    _, state = apt(
        getkey(),
        simulate,
        prior,
        x_o,
        embedding=emb,
        schedule=RoundSchedule(rounds=2, sims_per_round=500, truncate=True),
        config=config,
    )
    later = state.history[1]
    assert later["proposal"] == "truncated_prior" and later["num_filled"] == 0
    assert np.all(state.theta[state.round_ids == 1].std(0) < 0.8 * state.theta[state.round_ids == 0].std(0))
