"""The measurement-noise model of a problem: level per channel and the residuals' correlation.

Sensor noise is modelled as white at the model rate with std σ_c per channel (vehicle.json's
`noise_std`, else estimated from the recording: everything above ≈ 5 Hz, vibration included,
counts as noise). When the problem low-passes and decimates its channels, simulated noise goes
through the same filter as the measurement, so what reaches the data is coloured exactly as
the measured noise would be if it were white before filtering; the std after filtering is
σ_c·‖h‖₂ (h the filter taps).

Correlated residuals in the evidence: a χ² over N correlated samples carries the information of
fewer independent ones. With lag-1 autocorrelation ρ of a channel's residual (AR(1) model), the
effective number of samples is N·(1 − ρ)/(1 + ρ) (Bartlett/Bayley–Hammersley); `dof_factor`
gives that factor, and the misspecification tests and χ²/dof figures divide by it.
"""

from __future__ import annotations

import numpy as np

from ..io import Recording, estimate_noise_std, noise_gain
from ..simulator import Vehicle


def raw_noise_std(
    rec: Recording, vehicle: Vehicle, channels: tuple[str, ...], segments
) -> tuple[np.ndarray, dict[str, str]]:
    """σ per channel at the model rate: vehicle.json's noise_std where given (a std per recorded
    sample, so scaled to the model-rate white noise of the same density,
    σ·sqrt(rate / original_rate)), else estimated."""
    est = None
    out, src = [], {}
    gain = noise_gain(rec.original_rate, rec.rate)
    for c in channels:
        if c in vehicle.noise_std and vehicle.noise_std[c] > 0:
            out.append(gain * float(vehicle.noise_std[c]))
            src[c] = "vehicle file"
        else:
            if est is None:
                est = estimate_noise_std(rec, segments=segments or None)
            # A floor so a perfectly quantised or noise-free channel cannot dominate the fit.
            scale = float(np.std(rec.channels[c])) + 1e-9
            out.append(max(float(est[c]), 1e-4 * scale))
            src[c] = "estimated from the recording"
    return np.asarray(out), src


def lag1_autocorrelation(residual: np.ndarray, mask: np.ndarray) -> np.ndarray:
    """Lag-1 autocorrelation per channel of a (W, T, C) residual over masked (W, T) samples."""
    r = np.where(mask[..., None], residual, 0.0)
    both = (mask[:, 1:] & mask[:, :-1])[..., None]
    num = np.sum(np.where(both, r[:, 1:] * r[:, :-1], 0.0), axis=(0, 1))
    den = np.sum(r * r, axis=(0, 1)) + 1e-300
    return np.clip(num / den, -0.99, 0.99)


def dof_factor(rho: np.ndarray) -> np.ndarray:
    """Effective independent samples per sample for AR(1) residuals: (1 − ρ)/(1 + ρ), ≤ 1."""
    rho = np.clip(np.asarray(rho, dtype=float), 0.0, 0.99)
    return (1.0 - rho) / (1.0 + rho)


def integrated_autocorrelation_time(residual: np.ndarray, mask: np.ndarray, max_lag: int = 250) -> np.ndarray:
    """τ = 1 + 2·Σ_k ρ_k per channel of a (W, K, C) residual over masked (W, K) samples.

    N correlated samples carry the information of N/τ independent ones. The autocovariance is
    pooled over windows (lags never cross a window edge) and summed by Geyer's initial positive
    sequence (pairs ρ_{2j} + ρ_{2j+1} while positive), so a slowly varying model error gets a
    large τ and white noise τ ≈ 1. τ never exceeds the longest window's sample count.
    """
    mask = np.asarray(mask, bool)
    r = np.where(mask[..., None], residual, 0.0)
    r = r - np.sum(r, axis=(0, 1)) / max(mask.sum(), 1)
    r = np.where(mask[..., None], r, 0.0)
    lags = min(max_lag, r.shape[1] - 1)
    cov = np.empty((lags + 1, r.shape[-1]))
    for k in range(lags + 1):
        both = (mask[:, k:] & mask[:, : r.shape[1] - k])[..., None]
        cov[k] = np.sum(np.where(both, r[:, k:] * r[:, : r.shape[1] - k], 0.0), axis=(0, 1))
    rho = cov / (cov[0] + 1e-300)
    tau = np.ones(r.shape[-1])
    for c in range(r.shape[-1]):
        total = -1.0  # ρ_0 counted once: τ = −1 + 2·Σ_j (ρ_2j + ρ_2j+1)
        for j in range(0, lags, 2):
            pair = rho[j, c] + rho[j + 1, c]
            if pair <= 0:
                break
            total += 2.0 * pair
        tau[c] = max(1.0, total)
    return np.minimum(tau, max(1, int(mask.sum(1).max())))
