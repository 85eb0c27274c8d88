"""How the likelihood posterior's Laplace covariance is widened by the model error the data
reveal: `robust_covariance` takes each parameter's variance up to the block-sandwich estimate of
how much the fit moves between stretches of driving, `data_splits` names the ways to halve the
fitted samples (by channel, by excitation, by transience, by time), and `consistent_covariance`
scales the covariance when two halves cannot share one θ and adds a parameter's squared shift to
its variance where they disagree on it. Each takes whitened Jacobians and residuals as numpy
arrays and returns the widened covariance."""

from __future__ import annotations

import numpy as np
from scipy.stats import chi2

from ..problem import Problem

#: Blocks of the robust covariance span this many autocorrelation times.
BLOCK_TAUS = 4.0


def robust_covariance(cov: np.ndarray, jac: np.ndarray, r: np.ndarray, mask: np.ndarray, prec, block: float):
    """`cov` widened where the residual's effect on the fit varies more than it allows.

    The block sandwich H⁻¹(Σ_b g_b g_bᵀ)H⁻¹ (H = JᵀJ + prior precision, g_b = J_bᵀr_b the score
    of a block of `block` compared samples within a window) estimates how much the fit would
    move between stretches of driving: with model error that changes along the drive it
    exceeds the Laplace covariance. Each parameter's variance becomes the larger of the two;
    the correlations stay the Laplace's.

    Args:
        cov: (P, P) Laplace covariance.
        jac: (W, K, C, P) Jacobian of the residuals whitened by their scale.
        r: (W, K, C) the residuals whitened by their scale.
        mask: (W, K) fitted samples.
        prec: (P,) prior precision.
        block: block length in compared samples.
    """
    W, K = mask.shape
    n = max(1, int(round(block)))
    jac = np.where(mask[..., None, None], jac, 0.0)
    score = (jac * r[..., None]).sum(2)  # (W, K, P)
    pad = (-K) % n
    g = np.pad(score, ((0, 0), (0, pad), (0, 0))).reshape(W, -1, n, score.shape[-1]).sum(2)
    g = g.reshape(-1, score.shape[-1])
    g = g[np.any(g != 0.0, axis=1)]
    if len(g) < 2:
        return cov
    flat = jac.reshape(-1, jac.shape[-1])
    h_inv = np.linalg.pinv(flat.T @ flat + np.diag(prec))
    sandwich = h_inv @ (g.T @ g * len(g) / (len(g) - 1)) @ h_inv
    factor = np.sqrt(np.maximum(1.0, np.diag(sandwich) / np.diag(cov)))
    return cov * np.outer(factor, factor)


#: Two halves of the data disagree on a parameter when their estimates differ by more than this
#: many standard deviations of the difference.
DISAGREE_Z = 2.0
#: ... and on θ as a whole when the squared Mahalanobis distance of their difference exceeds this
#: quantile of χ²_P.
JOINT_LEVEL = 0.95


def data_splits(data: Problem, mask: np.ndarray) -> list[tuple[str, np.ndarray]]:
    """Ways to halve the fitted samples, as (name, (W, K, C) mask of half A; half B is the rest):
    by channel (a_y against yaw rate), by excitation (the samples with the larger measured lateral
    motion), by transience (the samples where it changes faster: a delay or a wrong yaw inertia
    acts on transients and not on steady cornering) and by time (the first windows against the
    last). A right model explains each half with the same θ; a missing effect usually does not
    act alike on both."""
    W, K, C = data.y.shape
    full = np.broadcast_to(mask[..., None], (W, K, C))
    out = []
    if "ay" in data.channels and "yaw_rate" in data.channels:
        out.append(("ay against yaw rate", full & (np.arange(C) == data.channels.index("ay"))))
    if "ay" in data.channels or "yaw_rate" in data.channels:
        lateral = np.asarray(data.y[..., data.channels.index("ay" if "ay" in data.channels else "yaw_rate")])
        for name, size in (
            ("high against low lateral motion", np.abs(lateral)),
            ("transient against steady lateral motion", np.abs(np.gradient(lateral, axis=1))),
        ):
            out.append((name, full & (size >= np.median(size[mask]))[..., None]))
    if W >= 2:
        out.append(("first against last windows", full & (np.arange(W) < W // 2)[:, None, None]))
    else:
        first = np.arange(K) < np.flatnonzero(mask[0]).mean()
        out.append(("first against second half", full & first[None, :, None]))
    return out


def consistent_covariance(cov: np.ndarray, jac: np.ndarray, r: np.ndarray, z: np.ndarray, prec, splits):
    """`cov` widened where halves of the data disagree.

    Each half's estimate is one Newton step from the joint fit ẑ, each half with half the prior:
    z_A = ẑ − H_A⁻¹(g_A + ½·prec·ẑ), H_A = J_AᵀJ_A + ½·prec, Σ_A = H_A⁻¹. With d = z_A − z_B:
    - jointly: when D² = dᵀ(Σ_A + Σ_B)⁻¹d exceeds χ²_P's `JOINT_LEVEL` point the halves cannot
      share one θ; the data's information is divided by D²/P (Birge's ratio, the Particle Data
      Group's scale factor for inconsistent measurements; `tempered`);
    - per parameter: one whose halves differ by |d_i| > `DISAGREE_Z`·sd(d_i) gets d_i² added to
      its variance (a systematic error of the size the halves reveal) and is reported as moved
      by model error.
    The largest of each over the splits.

    Args:
        cov: (P, P) covariance so far.
        jac: (W, K, C, P) Jacobian of the residuals whitened by their full per-sample std.
        r: (W, K, C) those residuals.
        z: (P,) the joint fit.
        prec: (P,) prior precision.
        splits: `data_splits`.

    Returns:
        the widened covariance, {parameter index: {"split", "z_shift", "sigmas"}} and
        {"split", "D2", "scale"} of the largest joint disagreement (None when no split rejects).
    """
    prec = np.asarray(prec)
    extra, shifts, joint = np.zeros(len(prec)), {}, None
    for name, half in splits:
        est, covs = [], []
        for m in (half, ~half):
            j = np.where(m[..., None], jac, 0.0).reshape(-1, jac.shape[-1])
            g = j.T @ np.where(m, r, 0.0).ravel() + 0.5 * prec * z
            h_inv = np.linalg.pinv(j.T @ j + np.diag(0.5 * prec))
            est.append(-h_inv @ g)
            covs.append(h_inv)
        d, s_d = est[0] - est[1], covs[0] + covs[1]
        d2 = float(d @ np.linalg.pinv(s_d) @ d)
        if d2 > chi2.ppf(JOINT_LEVEL, len(d)) and (joint is None or d2 > joint["D2"]):
            joint = {"split": name, "D2": d2, "scale": d2 / len(d)}
        sd = np.sqrt(np.diag(s_d))
        for i in np.flatnonzero(np.abs(d) > DISAGREE_Z * sd):
            if d[i] ** 2 > extra[i]:
                extra[i] = d[i] ** 2
                sigmas = abs(float(d[i] / sd[i]))
                shifts[int(i)] = {"split": name, "z_shift": abs(float(d[i])), "sigmas": sigmas}
    if joint is not None:
        cov = tempered(cov, prec, joint["scale"])
    factor = np.sqrt((np.diag(cov) + extra) / np.diag(cov))
    return cov * np.outer(factor, factor), shifts, joint


def tempered(cov: np.ndarray, prec, scale: float) -> np.ndarray:
    """The covariance with the data's information divided by `scale` and the prior's kept:
    (I/scale + diag(prec))⁻¹ with I = cov⁻¹ − diag(prec). Where the data dominate this is
    cov·scale; where the prior does, the variance stays the prior's (scaling the whole covariance
    would spread a parameter the drive does not inform beyond its prior box)."""
    prec = np.asarray(prec, float)
    info = np.linalg.inv(cov) - np.diag(prec)
    w, v = np.linalg.eigh(0.5 * (info + info.T))
    info = (v * np.clip(w, 0.0, None)) @ v.T  # a widened covariance can leave less than the prior
    return np.linalg.inv(info / scale + np.diag(prec))
