"""Calibration of a posterior estimator: SBC ranks and expected coverage."""

import numpy as np
from scipy import stats


def sbc_ranks(samples: np.ndarray, truths: np.ndarray) -> np.ndarray:
    """Rank of each true value among its posterior samples.

    Args:
        samples: (M, L, d) posterior samples for M held-out simulations.
        truths: (M, d) the parameters that made them.

    Returns:
        (M, d) integer ranks in [0, L]; uniform if the posterior is calibrated.
    """
    return (samples < truths[:, None, :]).sum(axis=1)


def sbc_ks_pvalues(ranks: np.ndarray, num_samples: int) -> np.ndarray:
    """Kolmogorov–Smirnov p-value of rank uniformity per parameter (jittered to continuous)."""
    rng = np.random.default_rng(0)
    u = (ranks + rng.uniform(size=ranks.shape)) / (num_samples + 1)
    return np.array([stats.kstest(u[:, j], "uniform").pvalue for j in range(ranks.shape[1])])


def expected_coverage(samples: np.ndarray, truths: np.ndarray, levels) -> np.ndarray:
    """Fraction of truths inside the central credible interval at each level.

    Returns:
        (len(levels), d) empirical coverage per level and parameter.
    """
    out = []
    for level in levels:
        lo = np.quantile(samples, (1 - level) / 2, axis=1)
        hi = np.quantile(samples, (1 + level) / 2, axis=1)
        out.append(((truths >= lo) & (truths <= hi)).mean(0))
    return np.array(out)
