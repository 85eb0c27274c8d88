"""The amortized answer checked against the likelihood through the simulator, by importance
sampling with Pareto-smoothed weights.

Draws z ~ t₅(mean, spread²·cov) around a drive's Gaussian posterior (the amortized one, or the
Laplace one of a likelihood fit started from it; heavier tails than the Gaussian, so that the
weights stay bounded where it is too narrow) are simulated on every window of the drive; each is
weighted by prior × likelihood / proposal. The likelihood is identify's quasi-likelihood
(`vdsbi.estimation`): per channel, the residual's scale s_c and autocorrelation time τ_c (the
fit's, or measured at the best simulated point), Σ r²/(s_c²·τ_c). Parameters the
channels do not depend on (a step of 0.1 in z moves no fitted sample) are drawn from their prior
afterwards: the likelihood cannot weigh them.

The check passes at k̂ ≤ min(1 − 1/log10 S, 0.7) for S draws (Vehtari et al. 2024: past it
the importance-weighted estimates' error no longer falls with S; 0.58 at 256 draws, 0.52 at 128);
the drive's answer is then the importance-weighted draws.

The check also returns its best-fitting simulated point (the proposal's mean or a draw, by the
check's own likelihood) and the noise model of that likelihood: a failed check's simulations then
start the likelihood fit and weigh its channels, so the fit simulates no candidates of its own.
"""

from __future__ import annotations

import dataclasses

import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import PRNGKeyArray
from scipy import stats

from ..estimation import PRIOR_Z_STD, NoiseModel, measure_noise
from ..problem import CLEAN_BATCH, Box, Problem, simulate_draws, windowed_model
from ..problem.points import split_parameters
from ._amortized import Proposal
from ._psis import psis

#: Points simulated per check: one probe per parameter, the mean, the proposal's draws.
DRAWS = 256
#: The t proposal's degrees of freedom.
DOF = 5.0
#: Logit step of the probes that find the parameters the channels depend on.
PROBE_STEP = 0.1
#: k̂ above which the importance-weighted answer is not trusted, at most 0.7.
K_MAX = 0.7


def k_threshold(draws: int) -> float:
    """The largest k̂ at which `draws` importance draws are trusted."""
    return min(1.0 - 1.0 / np.log10(draws), K_MAX)


@dataclasses.dataclass(frozen=True)
class CheckResult:
    """The check's verdict and the drive's answer if it passed.

    Attributes:
        k_hat: the Pareto shape of the weights.
        ess: relative effective sample size of the smoothed weights (0–1).
        theta: (S, P) draws in parameter units.
        weights: (S,) their normalised Pareto-smoothed importance weights.
        informed: (P,) whether the channels depend on each parameter.
        noise_ratio: {channel: residual scale / sensor noise} at the best simulated point.
        failed_share: share of the draws whose simulation left the model's domain.
        noise: the noise model of the likelihood.
        best: (P,) the simulated point (the proposal's mean or a draw, as simulated: before the
            uninformed parameters are redrawn) of the highest likelihood, in parameter units.
    """

    k_hat: float
    ess: float
    theta: np.ndarray
    weights: np.ndarray
    informed: np.ndarray
    noise_ratio: dict
    failed_share: float
    noise: NoiseModel
    best: np.ndarray

    @property
    def passed(self) -> bool:
        return self.k_hat <= k_threshold(len(self.weights))


def _t_draws(key: PRNGKeyArray, proposal: Proposal, spread: float, n: int) -> tuple[np.ndarray, np.ndarray]:
    """(n, P) multivariate-t draws and their log density."""
    scale = spread**2 * proposal.cov
    dist = stats.multivariate_t(loc=proposal.mean, shape=scale, df=DOF)
    seed = int(jax.random.randint(key, (), 0, 2**31 - 1))
    z = np.atleast_2d(dist.rvs(size=n, random_state=np.random.default_rng(seed)))
    return z, dist.logpdf(z)


def _log_prior(z: np.ndarray) -> np.ndarray:
    """Log density of z under a uniform θ in the box (logistic per coordinate), up to a constant."""
    return -np.sum(np.logaddexp(0.0, z) + np.logaddexp(0.0, -z), axis=-1)


def importance_check(
    key: PRNGKeyArray,
    problem: Problem,
    box: Box,
    effects,
    proposal: Proposal,
    *,
    spread: float = 1.5,
    noise: NoiseModel | None = None,
    draws: int = DRAWS,
) -> CheckResult:
    """Check `proposal` (a drive's posterior in the box's logit coordinates) on `problem`
    (module docstring): `draws` points simulated (the probes, the mean and its draws spread by
    `spread` over it), the likelihood with `noise` (default: measured at the best simulated
    point)."""
    k_draw, k_prior = jax.random.split(key)
    p = box.dim
    if draws < 2 * (p + 1):
        raise ValueError(f"{draws} draws for {p} parameters: at least {2 * (p + 1)}")
    z, _ = _t_draws(k_draw, proposal, spread, draws - p - 1)
    probes = proposal.mean[None] + PROBE_STEP * np.concatenate([np.zeros((1, p)), np.eye(p)])
    theta = np.asarray(jax.vmap(box.from_unbounded)(jnp.asarray(np.concatenate([probes, z]))), np.float32)
    wm = windowed_model(problem, effects)
    th, ep = split_parameters(theta, effects)
    # Fewer draws than the simulator's shared batch run as their own batch, not padded to it.
    batch = draws if draws < CLEAN_BATCH else None
    pred, ok = simulate_draws(None, wm, th, effect_params=ep, max_batch=batch)
    pred, ok = np.asarray(pred, float), np.asarray(ok)
    mask = np.asarray(problem.train)
    moved = np.any(np.where(mask[None, ..., None], pred[1 : p + 1] != pred[:1], False), axis=(1, 2, 3))
    informed = moved | ~ok[1 : p + 1] | ~ok[0]
    # The mean and the draws (the probes only find the informed parameters).
    pred, ok = np.concatenate([pred[:1], pred[p + 1 :]]), np.concatenate([ok[:1], ok[p + 1 :]])
    simulated = np.concatenate([theta[:1], theta[p + 1 :]]).astype(float)
    resid = np.where(mask[None, ..., None], pred - problem.y[None], 0.0)
    sensor = np.asarray(problem.sigma, float)
    sq = np.sum(resid**2 / sensor**2, axis=(1, 2))  # (S, C) against sensor noise alone
    best = int(np.argmin(np.where(ok, sq.sum(1), np.inf)))
    if noise is None:
        noise = measure_noise(resid[best], mask, sensor, problem.channels)
    log_lik = -0.5 * np.sum(sq * sensor**2 / (noise.scale**2 * noise.tau), axis=1)
    best = int(np.argmin(np.where(ok, -log_lik, np.inf)))
    log_lik, ok = log_lik[1:], ok[1:]
    # Uninformed parameters: the likelihood is flat in them; their draws come from the prior.
    u = np.asarray(jax.random.uniform(k_prior, z.shape, minval=1e-6, maxval=1 - 1e-6))
    z_prior = np.log(u) - np.log1p(-u)
    z = np.where(informed[None], z, z_prior)
    zi = z[:, informed]
    q = _marginal_logpdf(proposal, spread, informed, zi)
    log_w = np.where(ok, _log_prior(zi) + log_lik - q, -np.inf)
    weights, k_hat = psis(log_w)
    ess = float(1.0 / np.sum(weights**2) / len(weights))
    theta = np.asarray(jax.vmap(box.from_unbounded)(jnp.asarray(z)), float)
    ratio = {c: round(float(r), 3) for c, r in zip(problem.channels, noise.model_error_ratio)}
    return CheckResult(
        float(k_hat), ess, theta, weights, informed, ratio, float(1 - ok.mean()), noise, simulated[best]
    )


def _marginal_logpdf(proposal: Proposal, spread: float, informed: np.ndarray, z: np.ndarray) -> np.ndarray:
    """Log density of the proposal's marginal over the informed coordinates (a t's marginal is a
    t with the sub-matrix)."""
    if not informed.any():
        return np.zeros(len(z))
    sub = spread**2 * proposal.cov[np.ix_(informed, informed)]
    return stats.multivariate_t(loc=proposal.mean[informed], shape=sub, df=DOF).logpdf(z)


def weighted_summary(theta: np.ndarray, weights: np.ndarray, box: Box, informed: np.ndarray) -> dict:
    """{name: {estimate, mean, std, q05, q50, q95, identified}} of weighted draws. The estimate
    is the weighted median; a parameter is identified where the channels depend on it and its
    posterior std in the logit coordinates is below half the prior's."""
    z = np.asarray(jax.vmap(box.to_unbounded)(jnp.asarray(theta)), float)
    out = {}
    for j, name in enumerate(box.names):
        order = np.argsort(theta[:, j])
        cdf = np.cumsum(weights[order])
        q = {
            f"q{int(100 * a):02d}": float(theta[order[min(np.searchsorted(cdf, a), len(cdf) - 1)], j])
            for a in (0.05, 0.5, 0.95)
        }
        mean = float(np.sum(weights * theta[:, j]))
        std = float(np.sqrt(np.sum(weights * (theta[:, j] - mean) ** 2)))
        mz = np.sum(weights * z[:, j])
        std_z = float(np.sqrt(np.sum(weights * (z[:, j] - mz) ** 2)))
        identified = bool(informed[j]) and std_z < 0.5 * PRIOR_Z_STD
        out[name] = {"estimate": q["q50"], "mean": mean, "std": std, **q, "identified": identified}
    return out
