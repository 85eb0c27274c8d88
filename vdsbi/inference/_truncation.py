"""TSNPE's proposal: the prior truncated to the posterior's highest-density region.

Rejection from the whole prior box keeps a share equal to the region's prior mass, which falls
as (posterior width / prior width)^d: about 1.4e-5 for a 10-d posterior a tenth of the box
wide. Filling a round with posterior draws instead would not do: maximum likelihood on posterior
draws learns the posterior times the proposal, too narrow. Candidates therefore come from an
ellipsoid around the region whenever it is smaller than the box: drawn uniformly in it and kept
when inside the box and the region, they are exactly the truncated (uniform) prior as long as
the ellipsoid holds the region, which is checked: the ellipsoid grows while kept draws reach its
outer shell.
"""

import dataclasses
import math
import warnings
from functools import partial
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, PRNGKeyArray

from ._estimator import AbstractEstimator
from ._posterior import flow_log_prob, sample_flow
from ._prior import BoxPrior

_BATCHES = 200  # rejection batches per attempt, max(n, 10 000) candidates each
_GROWTHS = 6  # at most this many enlargements of the ellipsoid
_SHELL = 0.95  # a kept draw beyond this share of the radius means the region may stick out
_MIN_SHARE = 0.01  # "auto" skips an ellipsoid mostly outside the box (too many draws per kept one)
_SCALE = 1.25  # first ellipsoid: through the farthest posterior draw in the region, enlarged


@dataclasses.dataclass(frozen=True)
class _Ellipsoid:
    """``{θ : |L⁻¹(θ - mean)| ≤ radius}`` with ``L`` the Cholesky factor of a covariance."""

    mean: np.ndarray
    chol: np.ndarray
    radius: float

    @classmethod
    def around(cls, points: np.ndarray, scale: float) -> "_Ellipsoid":
        """The points' covariance ellipsoid through the farthest point, enlarged by ``scale``."""
        points = np.asarray(points, np.float64)
        d = points.shape[1]
        cov = np.atleast_2d(np.cov(points, rowvar=False))
        cov += np.eye(d) * 1e-12 * max(np.trace(cov) / d, 1e-300)  # a flat direction stays invertible
        ell = cls(points.mean(0), np.linalg.cholesky(cov), 1.0)
        return dataclasses.replace(ell, radius=scale * float(ell.distance(points).max()))

    def distance(self, theta: np.ndarray) -> np.ndarray:
        """Mahalanobis distance of each row of ``theta`` from the centre."""
        z = np.linalg.solve(self.chol, (np.asarray(theta, np.float64) - self.mean).T)
        return np.sqrt(np.sum(z * z, axis=0))

    def log_volume(self) -> float:
        d = self.mean.shape[0]
        log_unit_ball = 0.5 * d * math.log(math.pi) - math.lgamma(0.5 * d + 1)
        return log_unit_ball + d * math.log(self.radius) + float(np.sum(np.log(np.diag(self.chol))))

    def sample(self, key: PRNGKeyArray, n: int) -> np.ndarray:
        """``n`` draws uniform in the ellipsoid."""
        d = self.mean.shape[0]
        k_dir, k_rad = jax.random.split(key)
        u = np.asarray(jax.random.normal(k_dir, (n, d)), np.float64)
        u /= np.linalg.norm(u, axis=1, keepdims=True)
        r = self.radius * np.asarray(jax.random.uniform(k_rad, (n, 1)), np.float64) ** (1.0 / d)
        return self.mean + (r * u) @ self.chol.T


def _in_box(prior: BoxPrior, theta: np.ndarray) -> np.ndarray:
    return np.all((theta >= np.asarray(prior.low)) & (theta <= np.asarray(prior.high)), axis=1)


def _box_share(key, ell: _Ellipsoid, prior: BoxPrior) -> float:
    """The share of the ellipsoid inside the box (Monte Carlo, floored at 10⁻³)."""
    return max(float(np.mean(_in_box(prior, ell.sample(key, 20_000)))), 1e-3)


def _in_box_draws(key, m: int, ell: _Ellipsoid, prior: BoxPrior, share: float) -> np.ndarray:
    """``m`` draws uniform on the ellipsoid's part inside the box (``share`` of it, estimated),
    in chunks of at most 10⁶; the draws outside cost no flow evaluation. Exactly ``m``, so the
    flow is evaluated on one shape (no recompilation)."""

    def chunk(k, _):
        cand = ell.sample(k, int(min(1.2 * m / share, 10**6)))
        return cand[_in_box(prior, cand)]

    return _fill(key, chunk, m)


def _box_draws(key, m: int, prior: BoxPrior) -> np.ndarray:
    return np.asarray(prior.sample(key, m), np.float64)


def _fill(key, propose, m: int) -> np.ndarray:
    """Exactly ``m`` draws of ``propose`` (bounded)."""
    out, got = [], 0
    for _ in range(1000):
        key, k = jax.random.split(key)
        out.append(propose(k, m))
        got += out[-1].shape[0]
        if got >= m:
            break
    return np.concatenate(out)[:m]


def _reject(key, propose, keep, n: int) -> tuple[np.ndarray, int]:
    """Up to ``n`` kept draws of ``propose(key, m)`` (bounded batches) and the number drawn."""
    out, kept, drawn = [], 0, 0
    for _ in range(_BATCHES):
        key, k = jax.random.split(key)
        cand = propose(k, max(n, 10_000))
        drawn += cand.shape[0]
        out.append(cand[keep(cand)])
        kept += out[-1].shape[0]
        if kept >= n:
            break
    return np.concatenate(out), drawn


def truncated_prior(
    key: PRNGKeyArray,
    flow: AbstractEstimator,
    prior: BoxPrior,
    x_o: Array,
    n: int,
    epsilon: float = 1e-4,
    num_samples: int = 10_000,
    *,
    ellipsoid: bool | None = None,
) -> tuple[Array, dict[str, Any]]:
    """``n`` draws of the prior restricted to the ``1 - epsilon`` HPD region of ``flow`` at
    ``x_o``, whose level is the ``epsilon`` quantile of the flow's log density at
    ``num_samples`` of its own draws.

    ``ellipsoid``: where candidates are drawn. None (default): from an ellipsoid around the
    posterior's draws when its part inside the box is smaller than the box (a posterior with
    far-flung draws can make it larger), else from the prior; True or False forces the
    ellipsoid or the prior (both are exact). A round that finds fewer than ``n``
    is filled up (``info["num_filled"]``, warned) with draws of the proposal itself: uniform on
    the box, or on the ellipsoid around all the posterior's draws, it is a truncated prior too,
    only a wider one, so the fit stays unbiased; posterior draws would not.
    """
    k_ref, k_draw, k_fill = jax.random.split(key, 3)
    ref = np.asarray(sample_flow(flow, k_ref, x_o, num_samples))
    lp = np.asarray(flow_log_prob(flow, jnp.asarray(ref), x_o))
    top = float(np.max(lp))
    threshold = top - (top - float(np.quantile(lp, epsilon)))  # the level, as a depth below the top

    def keep(theta):  # the flow's density is -inf outside the box
        return np.asarray(flow_log_prob(flow, jnp.asarray(theta, jnp.float32), x_o)) >= threshold

    ell = _Ellipsoid.around(ref[lp >= threshold], _SCALE)
    box_log_volume = float(jnp.sum(jnp.log(prior.high - prior.low)))
    for growth in range(_GROWTHS + 1):
        k_pilot, k_draw = jax.random.split(k_draw)
        share = 1.0 if ellipsoid is False else _box_share(k_pilot, ell, prior)
        smaller = ell.log_volume() + math.log(share) < box_log_volume
        if ellipsoid is False or (ellipsoid is None and (not smaller or share < _MIN_SHARE)):
            propose = partial(_box_draws, prior=prior)
            acc, drawn = _reject(k_draw, propose, keep, n)
            info = {"region_proposal": "prior"}
            break
        propose = partial(_in_box_draws, ell=ell, prior=prior, share=share)
        acc, drawn = _reject(k_draw, propose, keep, n)
        covered = acc.shape[0] == 0 or ell.distance(acc).max() <= _SHELL * ell.radius
        info = {"region_proposal": "ellipsoid", "ellipsoid_growths": growth, "region_covered": bool(covered)}
        if covered:
            break
        ell = dataclasses.replace(ell, radius=1.5 * ell.radius)
    info.update(acceptance=acc.shape[0] / drawn, num_filled=max(0, n - acc.shape[0]))
    acc = acc[:n]
    if acc.shape[0] < n:  # region too small to reach by rejection: the wider proposal fills in
        warnings.warn(
            f"TSNPE: only {acc.shape[0]} of {n} draws found in the posterior's HPD region; the rest "
            f"are drawn from the wider {info['region_proposal']} region (unbiased, less informative)",
            stacklevel=2,
        )
        acc = np.concatenate([acc, _fill(k_fill, propose, n - acc.shape[0])])
    return jnp.asarray(acc, jnp.float32), info
