"""The vehicle identification pipeline: embeddings, statistics, and a small seeded run."""

import json

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import pytest

from vdsbi.inference import StatisticsMLP, TrajectoryCNN
from vdsbi.inference._cnn import CNNEmbedding
from vdsbi.inference._embeddings import embedding_from_spec
from vdsbi.inference._standardize import TrajectoryStandardization
from vdsbi.inference._summaries import summary_statistics
from vdsbi.inference._vehicle import seed_prior


def test_cnn_embedding_any_length_and_reconstructable(getkey):
    emb = CNNEmbedding(getkey(), in_channels=5, out_dim=16)
    for t in (400, 1001, 4001):
        out = emb(jax.random.normal(getkey(), (t, 5)))
        assert out.shape == (16,)
        assert bool(jnp.all(jnp.isfinite(out)))
    skeleton = embedding_from_spec("CNNEmbedding", emb.spec())
    assert jax.tree.structure(skeleton) == jax.tree.structure(emb)
    with pytest.raises(ValueError, match="expects"):
        emb(jnp.zeros((400, 3)))


def test_cnn_embedding_is_sensitive_to_timing(getkey):
    """Adaptive pooling keeps coarse timing: a pulse early vs late gives different features
    (far beyond float32 rounding), though its global mean and std are the same."""
    emb = CNNEmbedding(getkey(), in_channels=1, out_dim=8)
    early = jnp.zeros((800, 1)).at[50:100].set(5.0)
    late = jnp.zeros((800, 1)).at[700:750].set(5.0)
    scale = float(jnp.abs(emb(early)).max())
    assert float(jnp.abs(emb(early) - emb(late)).max()) > 1e-3 * scale


def test_cnn_calibration_normalises_head_input_and_is_frozen(getkey):
    """Global statistics that barely vary across simulations must reach the head at O(1)
    scale (else the flow ignores them), and training must not move the normalisation."""
    emb = CNNEmbedding(getkey(), in_channels=2, out_dim=4)
    base = jax.random.normal(getkey(), (64, 400, 2))
    level = 1.0 + 0.01 * jax.random.normal(getkey(), (64, 1, 1))  # a 1 % scale difference
    xs = base * level
    cal = emb.calibrate(xs)
    f = (jax.vmap(cal.features)(xs) - cal.feature_mean) / cal.feature_std
    np.testing.assert_allclose(np.asarray(f.mean(0)), 0.0, atol=1e-4)
    np.testing.assert_allclose(np.asarray(f.std(0)), 1.0, rtol=1e-3)
    np.testing.assert_allclose(np.asarray(cal(xs[0])), np.asarray(cal.head(f[0])), rtol=1e-4, atol=1e-5)
    grads = eqx.filter_grad(lambda e: jnp.sum(jax.vmap(e)(xs) ** 2))(cal)
    assert float(jnp.abs(grads.feature_mean).max()) == 0.0
    assert float(jnp.abs(grads.feature_std).max()) == 0.0


def test_cnn_front_filters_see_what_averaging_erases(getkey):
    """A 25 Hz burst at 200 Hz averages to exactly zero over 8 samples, so without the full-rate
    branch its sign is invisible; with it, it is not (slip-stiffness information lives in such
    wheel oscillations)."""
    t = jnp.arange(800)
    burst = jnp.where((t >= 200) & (t < 264), 5 * jnp.sin(2 * jnp.pi * t / 8 + 0.3), 0.0)[:, None]
    plain = CNNEmbedding(getkey(), in_channels=1, out_dim=8, front_filters=0)
    blind = float(jnp.abs(plain(burst) - plain(-burst)).max())
    emb = CNNEmbedding(getkey(), in_channels=1, out_dim=8)
    seen = float(jnp.abs(emb(burst) - emb(-burst)).max())
    scale = float(jnp.abs(emb(burst)).max())
    assert blind < 1e-6 * scale  # float32 rounding only
    assert seen > 1e-3 * scale


def test_cnn_dense_products_equal_the_convolutions(getkey):
    """The trunk and the full-rate front run as dense products (fast inside the compiled
    training loop); they must compute exactly what the equinox convolutions they hold do."""
    from vdsbi.inference._cnn import _conv_as_products

    emb = CNNEmbedding(getkey(), in_channels=3, out_dim=4, front_filters=5)
    x = jax.random.normal(getkey(), (403, 3))
    t = (x.shape[0] // emb.downsample) * emb.downsample
    padded = jnp.pad(x[:t].T, ((0, 0), (0, emb.downsample)))
    ref = emb.front(padded)
    np.testing.assert_allclose(np.asarray(_conv_as_products(emb.front, padded)), np.asarray(ref), atol=1e-5)
    h = jax.random.normal(getkey(), (emb.in_channels + emb.front_filters, 50))
    for conv in emb.convs:  # strided, dilated, "SAME" and explicit padding
        out = conv(h)
        np.testing.assert_allclose(np.asarray(_conv_as_products(conv, h)), np.asarray(out), atol=1e-5)
        h = jax.nn.gelu(out)


def test_summary_statistics_properties(getkey):
    x = jax.random.normal(getkey(), (20000, 3))
    s = summary_statistics(x, lags=(1, 5))
    c = 3
    assert s.shape == (c * (2 + 2) + c * (c - 1) // 2,)
    np.testing.assert_allclose(s[:c], 0.0, atol=0.03)  # means
    np.testing.assert_allclose(s[c : 2 * c], 0.0, atol=0.05)  # log variances of unit noise
    np.testing.assert_allclose(s[2 * c : 4 * c], 0.0, atol=0.03)  # white: no autocorrelation
    # A copied channel has cross-correlation 1 with its source.
    y = jnp.concatenate([x[:, :1], x[:, :1]], axis=1)
    assert float(summary_statistics(y, lags=(1,))[-1]) == pytest.approx(1.0, abs=1e-5)
    # Scale invariance of the correlations, log-variance shifts by 2·log(scale).
    s2 = summary_statistics(3.0 * x, lags=(1, 5))
    np.testing.assert_allclose(s2[2 * c :], s[2 * c :], atol=1e-5)
    np.testing.assert_allclose(s2[c : 2 * c] - s[c : 2 * c], 2 * np.log(3.0), atol=1e-4)


def test_seed_prior_is_physical():
    prior = seed_prior()
    assert np.all(np.asarray(prior.low)[2:] > 0)  # no negative stiffness
    assert float(prior.high[0]) > 1.5  # the true l_f = 1.5 is interior
    literal = seed_prior(literal=True)
    assert float(literal.low[2]) < 0 and float(literal.high[0]) == 1.5


def test_identify_settings_train_each_embedding_by_its_own_default():
    from vdsbi.inference import IdentifySettings, NPEConfig, TrainingSettings, as_record
    from vdsbi.io import InputError

    cnn, stats = IdentifySettings(embedding=TrajectoryCNN()), IdentifySettings(embedding=StatisticsMLP())
    # round 1 runs a fixed decaying schedule, shorter for the costly CNN
    assert cnn.config.training.cosine_decay and stats.config.training.cosine_decay
    assert cnn.config.training.max_epochs < stats.config.training.max_epochs
    assert isinstance(cnn.config.flow.x_standardize, TrajectoryStandardization)
    # the CNN's later rounds are capped (bounded Table II time); the cheap statistics' are not
    assert cnn.config.sequential.later_max_epochs is not None
    assert stats.config.sequential.later_max_epochs is None
    assert cnn.truncate and stats.truncate  # TSNPE, not the atomic loss (experiments/paper_table2.py)
    # the CNN's spline interval is wider than the default: base draws past ±3 escaped to the box edges
    assert cnn.config.flow.tail_bound > NPEConfig().flow.tail_bound
    mine = NPEConfig(training=TrainingSettings(max_epochs=7))
    kept = IdentifySettings(embedding=TrajectoryCNN(), config=mine)
    assert kept.config is mine  # an explicit one is kept, its standardisation included
    assert not isinstance(kept.config.flow.x_standardize, TrajectoryStandardization)
    with pytest.raises(InputError, match="embedding"):
        IdentifySettings(embedding="cnn")
    # the run's record names each typed choice
    assert as_record(stats)["embedding"] == "stats"
    assert as_record(cnn.config)["flow"]["x_standardize"] == "trajectory"
    assert as_record(cnn.config)["flow"]["theta_map"] == "logit"


@pytest.mark.slow
def test_paper_table2_quick_recovers_l_f(tmp_path):
    from experiments.paper_table2 import main

    argv = ["--quick", "--embedding", "stats", "--out", str(tmp_path), "--seed", "0", "--round-diagnostics"]
    result = main(argv)
    lf = result["params"]["l_f"]
    assert lf["q025"] <= lf["true"] <= lf["q975"]
    # It learned something: narrower than the prior's std (0.7/√12 ≈ 0.20 m).
    assert lf["std"] < 0.7 / np.sqrt(12)
    saved = json.loads((tmp_path / "table2_quick_stats.json").read_text())
    assert set(saved["wall_s"]) == {"simulation", "training", "sampling", "total", "round_diagnostics"}
    # the per-round spread diagnostics ran after each round; the samples are kept
    assert len(saved["round_spread"]) == 2 and 0.0 <= saved["spread"]["l_f"]["far_fraction"] <= 1.0
    assert np.load(tmp_path / "table2_quick_stats_samples.npz")["samples"].shape == (10_000, 6)
    assert (tmp_path / "fig3_quick_stats.png").stat().st_size > 10_000
