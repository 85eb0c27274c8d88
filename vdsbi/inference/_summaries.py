"""Handcrafted summary statistics (the SNL Lotka–Volterra recipe the seed used)."""

import jax.numpy as jnp
from jaxtyping import Array, Float

#: Auto-correlation lags in samples (at 200 Hz: 5 ms … 1 s).
DEFAULT_LAGS: tuple[int, ...] = (1, 2, 5, 10, 20, 50, 100, 200)


def summary_statistics(x: Float[Array, "T C"], lags: tuple[int, ...] = DEFAULT_LAGS) -> Float[Array, " S"]:
    """Per channel: mean, log variance, auto-correlations at `lags`; per channel pair: the
    cross-correlation at lag 0. S = C·(2 + len(lags)) + C·(C−1)/2.
    """
    t, c = x.shape
    mean = x.mean(0)
    xc = x - mean
    var = (xc**2).mean(0)
    sd = jnp.sqrt(var + 1e-12)
    z = xc / sd
    auto = jnp.stack([(z[lag:] * z[:-lag]).mean(0) for lag in lags if lag < t])
    cross = (z.T @ z) / t
    iu = jnp.triu_indices(c, 1)
    return jnp.concatenate([mean, jnp.log(var + 1e-12), auto.reshape(-1), cross[iu]])
