"""The likelihood posterior's draws held against the likelihood itself.

The Laplace posterior is Gaussian in the logit coordinates around the best fit. Where the cost
rises far faster than its quadratic model (a wall: a centre of gravity so high that a
hard-cornering car spins out, a friction below the grip the drive used), the Gaussian reaches θ
the data rule out, and every interval and predictive band built on its draws widens into
nonsense. Each draw is simulated on the fitted part of the drive, and kept unless its cost
exceeds the best fit's by more than the quadratic model says plus half the χ²_k quantile `LEVEL`
(k free coordinates): a likelihood ratio against the Gaussian that the data make plain.
Directions in which the cost is as quadratic as the fit assumed keep their draws, the model-error
widening included.
"""

from __future__ import annotations

from collections.abc import Sequence

import jax
import numpy as np
from jaxtyping import PRNGKeyArray
from scipy.stats import chi2

from ..problem import CLEAN_BATCH, Problem, simulate_draws, windowed_model
from ..problem.points import split_parameters
from ..simulator.solvers import Solver
from ._laplace_posterior import LikelihoodPosterior
from ._likelihood import PRIOR_Z_STD

#: A draw goes when its cost exceeds the quadratic model by more than ½·χ²_k at this level.
LEVEL = 0.99
#: Candidates simulated per draw wanted, at most, and in all (each costs a simulation of the drive).
OVERSAMPLE, MAX_CANDIDATES = 4, 1024


def screened_sample(
    key: PRNGKeyArray,
    posterior: LikelihoodPosterior,
    problem: Problem,
    n: int,
    effects: Sequence[str] = (),
    *,
    information_only: bool = False,
    solver: Solver = Solver(),
) -> tuple[np.ndarray, float]:
    """`n` draws of `posterior.sample` (parameter units) that the likelihood does not rule out,
    and the share of candidates kept.

    Args:
        key: PRNG key.
        posterior: a fit of `problem`'s `posterior.part`.
        problem: the problem it was fitted on.
        n: draws wanted.
        effects: enabled effects, as fitted.
        information_only: draw from the drive's information alone (`predictive_draws`).

    Candidates are simulated a batch at a time until `n` are kept or min(`OVERSAMPLE`·n,
    `MAX_CANDIDATES`) were tried; if fewer were kept, the kept ones are repeated (and none kept:
    the unscreened draws).
    """
    if posterior.curvature is None or not posterior.free:
        return np.asarray(posterior.sample(key, n, information_only=information_only), float), 1.0
    idx = np.asarray([posterior.names.index(f) for f in posterior.free])
    limit = 0.5 * chi2.ppf(LEVEL, len(idx))
    cost = _cost_function(posterior, problem, effects, idx, solver)
    z_hat = np.asarray(posterior.z, np.float32)
    base = None
    kept, tried = [], 0
    budget = max(CLEAN_BATCH, min(OVERSAMPLE * n, MAX_CANDIDATES))
    while sum(len(k) for k in kept) < n and tried < budget:
        key, sub = jax.random.split(key)
        z = np.array(posterior.sample_z(sub, CLEAN_BATCH, information_only=information_only))
        if base is None:
            z[0] = z_hat  # the best fit's own cost, in the same program and precision
        # Only the fitted coordinates are tested: the others keep their prior spread, which the
        # fit's channels do not depend on.
        c = cost(np.where(np.isin(np.arange(z.shape[1]), idx), z, z_hat))
        if base is None:
            base, z, c = c[0], z[1:], c[1:]
        d = (z - z_hat)[:, idx]
        quadratic = 0.5 * np.einsum("np,pq,nq->n", d, posterior.curvature, d)
        kept.append(z[np.isfinite(c) & (c - base - quadratic <= limit)])
        tried += len(z)
    z = np.concatenate(kept)[:n]
    share = len(np.concatenate(kept)) / tried
    if not len(z):
        return np.asarray(posterior.sample(key, n, information_only=information_only), float), 0.0
    z = np.resize(z, (n, z.shape[1]))
    return np.asarray(jax.vmap(posterior.box.from_unbounded)(z), float), share


def _cost_function(posterior: LikelihoodPosterior, problem: Problem, effects, idx, solver):
    """z (N, P) -> the fit's cost of each draw on the fitted part (inf where it fails)."""
    data = posterior.with_fitted_starts(problem)
    mask = np.asarray(data.part(posterior.part))
    wm = windowed_model(data, effects, solver)
    weight = 1.0 / (np.asarray(posterior.noise.scale) ** 2 * np.asarray(posterior.noise.tau))
    mean = 0.0 if posterior.prior_mean is None else np.asarray(posterior.prior_mean)[idx]

    def cost(z: np.ndarray) -> np.ndarray:
        theta = jax.vmap(posterior.box.from_unbounded)(z)
        th, ep = split_parameters(theta, effects)
        pred, ok = simulate_draws(None, wm, th, effect_params=ep)
        r2 = np.where(mask[..., None], (np.asarray(pred, float) - data.y) ** 2, 0.0)
        c = (
            0.5 * np.sum(r2 * weight, axis=(1, 2, 3))
            + 0.5 * np.sum((z[:, idx] - mean) ** 2, 1) / PRIOR_Z_STD**2
        )
        return np.where(np.asarray(ok), np.nan_to_num(c, nan=np.inf), np.inf)

    return cost
