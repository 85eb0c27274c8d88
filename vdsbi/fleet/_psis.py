"""Pareto-smoothed importance sampling (Vehtari, Simpson, Gelman, Yao, Gabry 2024, JMLR 25:72):
the largest importance weights replaced by the quantiles of a generalized Pareto distribution
fitted to them, and its shape k̂, the diagnostic. k̂ < 0.7 (at a few hundred draws): the
importance-weighted estimates are reliable; above it the proposal misses the target's bulk.
"""

from __future__ import annotations

import numpy as np


def gpd_fit(exceedances: np.ndarray) -> tuple[float, float]:
    """(k, σ) of a generalized Pareto distribution fitted to positive `exceedances` (sorted
    ascending): Zhang & Stephens' (2009) profile posterior, k shrunk toward 0.5 by a weak prior
    (10 pseudo-observations), as in the PSIS paper's reference code."""
    x = np.asarray(exceedances, float)
    n = len(x)
    m = 30 + int(np.sqrt(n))
    b = 1.0 - np.sqrt(m / (np.arange(1, m + 1) - 0.5))
    b = b / (3.0 * x[int(n / 4 + 0.5) - 1]) + 1.0 / x[-1]
    k = np.log1p(-b[:, None] * x).mean(axis=1)
    log_lik = n * (np.log(-b / k) - k - 1.0)
    with np.errstate(over="ignore"):  # a grid point far below the best weighs exactly 0
        weights = 1.0 / np.exp(log_lik[None, :] - log_lik[:, None]).sum(axis=1)
    b_post = float(np.sum(b * weights))
    k_post = float(np.log1p(-b_post * x).mean())
    sigma = -k_post / b_post
    return (n * k_post + 10 * 0.5) / (n + 10), sigma


def psis(log_weights: np.ndarray) -> tuple[np.ndarray, float]:
    """(normalised smoothed weights, k̂) of S raw log importance weights (−inf allowed: a draw
    the target rules out). The tail is the largest min(S/5, 3√S) weights."""
    lw = np.asarray(log_weights, float)
    finite = np.isfinite(lw)
    if finite.sum() < 2:
        return np.where(finite, 1.0 / max(finite.sum(), 1), 0.0), np.inf
    lw = np.where(finite, lw - lw[finite].max(), -np.inf)
    s = int(finite.sum())
    tail = int(np.ceil(min(0.2 * s, 3.0 * np.sqrt(s))))
    order = np.argsort(lw)
    cutoff = lw[order[-tail - 1]]
    idx = order[-tail:]
    exceed = np.exp(lw[idx]) - np.exp(cutoff)
    if tail < 5 or np.sum(exceed > 0) < 5:  # too few distinct large weights to fit a tail to
        w = np.exp(lw)
        return w / w.sum(), np.inf
    with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
        k, sigma = gpd_fit(exceed)
        if not np.isfinite(k):  # the weights' tail has no finite fit: no estimate
            w = np.exp(lw)
            return w / w.sum(), np.inf
        p = (np.arange(1, tail + 1) - 0.5) / tail
        quantiles = np.exp(cutoff) + (
            sigma / k * np.expm1(-k * np.log1p(-p)) if k != 0 else -sigma * np.log1p(-p)
        )
        lw[idx] = np.minimum(np.log(quantiles), 0.0)
    w = np.exp(lw)
    return w / w.sum(), float(k)
