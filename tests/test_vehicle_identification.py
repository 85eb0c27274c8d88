"""The vehicle identification pipeline: embeddings, statistics, and a small seeded run."""

import json

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from vdsbi.inference import CNNEmbedding, embedding_from_spec, seed_prior, summary_statistics


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


@pytest.mark.slow
def test_paper_table2_quick_recovers_l_f(tmp_path):
    from experiments.paper_table2 import main

    result = main(["--quick", "--embedding", "stats", "--out", str(tmp_path), "--seed", "0"])
    lf = result["params"]["l_f"]
    assert lf["q025"] <= lf["true"] <= lf["q975"]
    # It learned something: narrower than the prior's std (0.7/√12 ≈ 0.20 m).
    assert lf["std"] < 0.7 / np.sqrt(12)
    saved = json.loads((tmp_path / "table2_quick_stats.json").read_text())
    assert set(saved["wall_s"]) == {"simulation", "training", "sampling", "total"}
    assert (tmp_path / "fig3_quick_stats.png").stat().st_size > 10_000
