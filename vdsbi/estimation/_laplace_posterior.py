"""The likelihood posterior: the Laplace approximation at the best fit, in the box's logit
coordinates (`fit_likelihood` makes it)."""

from __future__ import annotations

import dataclasses

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float, PRNGKeyArray
from scipy.stats import norm

from ..problem import Box, Part, Problem
from ._noise import NoiseModel


class LikelihoodPosterior(eqx.Module):
    """The Laplace posterior at the best fit, in the box's logit coordinates.

    Attributes:
        box: the prior box (names, bounds, bijection).
        z: (P,) the best fit (MAP) in logit coordinates.
        cov_z: (P, P) covariance of z (Laplace, widened by the model error the data reveal);
            parameters not fitted keep their prior variance.
        cov_information: (P, P) the same before the halves' disagreement widens it (`consistent_covariance`):
            what the drive's information alone allows, which the identifiability rule reads.
        free: names of the fitted parameters (the others carry no information in this drive).
        noise: the noise model the fit ended with.
        converged: the last fit stopped by its tolerance, not its iteration cap.
        steps: iterations of each reweighted fit.
        disagreement: {name: {"split", "z_shift"}} for parameters on which two halves of the data
            (`data_splits`) disagree beyond their uncertainty: the model lacks something that moves
            them, and their variance was widened by the disagreement (`consistent_covariance`).
        inconsistency: {"split", "D2", "scale"} when two halves of the data cannot share one θ
            (`consistent_covariance`): the data's information was divided by "scale"; None when they can.
        v0_offset: (W,) start-speed corrections fitted per window, m/s (zeros where the problem
            follows the measured speed, or a window holds no fitted sample).
        curvature: (k, k) Gauss–Newton curvature of the fit's cost in the free coordinates, start
            speeds held at their fit: the quadratic model `screened_sample` holds draws against.
        part: the problem's part that was fitted ("train" or "valid").
        residual: (W, K, C) prediction minus measurement at the fit, channel units; 0 outside
            the fitted part.
        jacobian: (W, K, C, k + W') its derivative by the free coordinates (in `free`'s order),
            then by each corrected window's start speed (W' = 0 where none is corrected).
        prior_mean: (P,) the prior's mode in logit coordinates (`prior_mean`).
    """

    box: Box
    z: np.ndarray
    cov_z: np.ndarray
    cov_information: np.ndarray
    free: tuple[str, ...]
    noise: NoiseModel
    converged: bool
    steps: tuple[int, ...]
    disagreement: dict = eqx.field(default_factory=dict)
    inconsistency: dict | None = None
    v0_offset: np.ndarray | None = None
    curvature: np.ndarray | None = None
    part: Part = eqx.field(static=True, default="train")
    residual: np.ndarray | None = None
    jacobian: np.ndarray | None = None
    prior_mean: np.ndarray | None = None

    @property
    def chi2_dof(self) -> float:
        """Σ (residual/σ_sensor)² over the fitted samples per degree of freedom: the misfit
        against sensor noise alone (≈ 1 where the model explains the drive)."""
        n = self.noise.samples.sum() - self.jacobian.shape[-1]  # the free ones and the start speeds
        return float(np.sum((self.residual / self.noise.sensor) ** 2) / max(1.0, n))

    @property
    def names(self) -> tuple[str, ...]:
        return self.box.names

    @property
    def theta(self) -> np.ndarray:
        """The best fit (MAP), in parameter units."""
        return np.asarray(self.box.from_unbounded(self.z))

    def interval(self, level: float = 0.9) -> np.ndarray:
        """(P, 2) central `level` interval of each parameter, in parameter units: the Gaussian
        marginal in z mapped through the box (monotone, so its quantiles map exactly)."""
        half = norm.ppf(0.5 + level / 2) * np.sqrt(np.clip(np.diag(self.cov_z), 0.0, None))
        ends = np.stack([self.z - half, self.z + half])
        return np.asarray(jax.vmap(self.box.from_unbounded)(jnp.asarray(ends))).T

    def sample(self, key: PRNGKeyArray, n: int, *, information_only: bool = False) -> Float[Array, "n P"]:
        """`n` draws in parameter units (Gaussian in z, mapped into the box); with
        `information_only`, from `cov_information` (for the identifiability rule)."""
        return jax.vmap(self.box.from_unbounded)(self.sample_z(key, n, information_only=information_only))

    def sample_z(self, key: PRNGKeyArray, n: int, *, information_only: bool = False) -> Float[Array, "n P"]:
        """`sample`'s draws in the logit coordinates."""
        cov = self.cov_information if information_only else self.cov_z
        chol = np.linalg.cholesky(cov + 1e-12 * np.eye(len(self.z)))
        eps = jax.random.normal(key, (n, len(self.z)), dtype=jnp.float32)
        return jnp.asarray(self.z, jnp.float32) + eps @ jnp.asarray(chol.T, jnp.float32)

    def predictive_draws(self, key: PRNGKeyArray, n: int) -> Float[Array, "n P"]:
        """`n` parameter draws for predicting new driving: from the drive's information alone
        (`cov_information`). The model error enters a prediction once, through the noise model's
        scale added to each simulated draw; the widening by the halves' disagreement keeps the
        parameter intervals honest, and a band that also drew from it would count that error
        twice."""
        return self.sample(key, n, information_only=True)

    def with_fitted_starts(self, problem: Problem) -> Problem:
        """`problem` (the fitted one, or the same windows with another held-out part) with each
        window's start speed corrected as the fit found: the held-out part of a fitted window is
        then predicted from the start its fitted part inferred."""
        if self.v0_offset is None or not np.any(self.v0_offset):
            return problem
        if len(self.v0_offset) != len(problem.v0):
            raise ValueError(f"{len(self.v0_offset)} fitted start speeds, {len(problem.v0)} windows")
        return dataclasses.replace(problem, v0=np.asarray(problem.v0) + self.v0_offset)

    def mahalanobis2(self, theta) -> np.ndarray:
        """Squared Mahalanobis distance of θ (…, P) from the fit, in z (the posterior's
        50 % region is D² ≤ χ²_P(0.5))."""
        z = np.asarray(jax.vmap(self.box.to_unbounded)(jnp.atleast_2d(jnp.asarray(theta))))
        d = z - self.z
        return np.einsum("np,pq,nq->n", d, np.linalg.pinv(self.cov_z), d)
