"""Whether a fix improves the held-out fit: both fits scored on the same held-out samples."""

from __future__ import annotations

import numpy as np
from scipy import stats

#: A fix counts as an improvement where the channels' mean held-out χ²/dof falls by more than this
#: share, beyond the held-out part's own sampling noise, and no channel's grows by more than it or
#: by more than two standard deviations of its χ²/dof (2·√(2τ/N) relative, N samples correlated
#: over τ) where that is more. A change within the noise is no fix either way.
HELD_OUT_SLACK = 0.02
#: Held-out blocks from which the fall of the mean is judged by their paired differences.
PAIRED_BLOCKS = 4


def held_out_improves(before: dict, after: dict, tau: dict | None = None) -> bool:
    """Whether a fix improves the held-out fit: the channels' mean χ²/dof falls by more than
    `HELD_OUT_SLACK` and by more than its noise, and no channel's grows by more than its own
    slack. A fix that trades one channel's fit for another's is not one, nor one that moves it
    within the noise. The fall's noise: both fits are scored on the same samples, so where at
    least `PAIRED_BLOCKS` blocks of them are scored (`chi2_blocks`), the blocks' paired
    differences must show it (Student's t, one-sided 2.5 %); otherwise each mean's own sampling
    noise is allowed for. `tau`: each channel's residual autocorrelation time (default 1)."""
    tau = tau or {}

    def slack(c):
        n = before[c].get("samples")
        return max(HELD_OUT_SLACK, 2.0 * np.sqrt(2.0 * tau.get(c, 1.0) / n)) if n else HELD_OUT_SLACK

    mean = lambda h: float(np.mean([v["chi2_dof"] for v in h.values()]))
    worse = any(after[c]["chi2_dof"] > (1 + slack(c)) * before[c]["chi2_dof"] for c in before)
    falls = mean(after) < (1 - HELD_OUT_SLACK) * mean(before)
    paired = _paired_fall(before, after)
    if paired is None:
        # The mean's own noise: the channels' relative slacks, combined as independent.
        noise = float(np.sqrt(np.mean([slack(c) ** 2 for c in before]) / len(before)))
        paired = mean(after) < (1 - noise) * mean(before)
    return bool(falls and paired and not worse)


def _paired_fall(before: dict, after: dict) -> bool | None:
    """Whether the blocks' mean χ²/dof falls beyond the noise of their paired differences
    (Student's t at one-sided 2.5 %); None with fewer than `PAIRED_BLOCKS` blocks."""
    if not all("chi2_blocks" in h[c] for h in (before, after) for c in before):
        return None
    d = np.mean([np.subtract(before[c]["chi2_blocks"], after[c]["chi2_blocks"]) for c in before], axis=0)
    if d.size < PAIRED_BLOCKS:
        return None
    return bool(d.mean() > stats.t.ppf(0.975, d.size - 1) * d.std(ddof=1) / np.sqrt(d.size))
