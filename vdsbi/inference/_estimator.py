"""What every neural posterior estimator is: a density ``q(θ | x)`` on the prior's box,
conditioned on ``c = embedding(standardise(x))``, for ONE θ and ONE x (vmap outside).

`ConditionalFlow` (a spline flow) and `FlowMatchingEstimator` (an ODE) implement it, so `fit`,
`Posterior` and its save and load take either.
"""

from typing import Any

import equinox as eqx
import jax.numpy as jnp
from jaxtyping import Array, Float, PRNGKeyArray

from ._embeddings import AbstractEmbedding, embedding_from_spec
from ._prior import BoxPrior
from ._standardize import Standardizer
from ._theta_map import AbstractThetaMap


class AbstractEstimator(eqx.Module):
    """``q(θ | x)`` on the box of ``prior``.

    Attributes:
        embedding: maps one standardised x to the context vector.
        prior: the box (fixes ``dim`` and the θ map's range).
        theta_standardizer: affine map in the θ map's space, shape ``(d,)``.
        x_standardizer: applied to x before the embedding.
        dim: number of parameters.
        x_shape: shape of ONE observation.
        theta_map: `LogitMap` or `IdentityMap`.
    """

    embedding: eqx.AbstractVar[AbstractEmbedding]
    prior: eqx.AbstractVar[BoxPrior]
    theta_standardizer: eqx.AbstractVar[Standardizer]
    x_standardizer: eqx.AbstractVar[Standardizer]
    dim: eqx.AbstractVar[int]
    x_shape: eqx.AbstractVar[tuple[int, ...]]
    theta_map: eqx.AbstractVar[AbstractThetaMap]

    def context(self, x: Float[Array, "..."]) -> Float[Array, " c"]:
        """Embedding of ONE observation."""
        return self.embedding(self.x_standardizer(x))

    def log_prob_context(self, theta: Float[Array, " d"], context: Float[Array, " c"]) -> Float[Array, ""]:
        """``log q(θ | x)`` for ONE θ given a precomputed context; ``-inf`` outside the box."""
        raise NotImplementedError

    def sample_context(self, key: PRNGKeyArray, context: Float[Array, " c"], n: int) -> Float[Array, "n d"]:
        """``n`` draws of θ inside the box given a precomputed context."""
        raise NotImplementedError

    def log_prob(self, theta: Float[Array, " d"], x: Float[Array, "..."]) -> Float[Array, ""]:
        """``log q(θ | x)`` for ONE θ and ONE x."""
        return self.log_prob_context(theta, self.context(x))

    def sample(self, key: PRNGKeyArray, x: Float[Array, "..."], n: int) -> Float[Array, "n d"]:
        """``n`` draws of θ from ``q(θ | x)`` for ONE x; always inside the prior box."""
        return self.sample_context(key, self.context(x), n)

    def structure(self) -> dict[str, Any]:
        """The estimator's own hyperparameters, as its ``*_from_spec`` rebuilds them."""
        raise NotImplementedError

    def spec(self) -> dict[str, Any]:
        """JSON-serialisable description from which the estimator's structure is rebuilt (the
        prior box, the observation's shape, the θ map, the embedding and `structure`)."""
        return {
            **self.structure(),
            "low": [float(v) for v in self.prior.low],
            "high": [float(v) for v in self.prior.high],
            "names": None if self.prior.names is None else list(self.prior.names),
            "x_shape": list(self.x_shape),
            "x_std_shape": list(self.x_standardizer.mean.shape),
            "theta_map": self.theta_map.name,
            "embedding": [type(self.embedding).__name__, self.embedding.spec()],
        }


def skeleton_parts(spec: dict[str, Any]) -> tuple[BoxPrior, AbstractEmbedding, tuple[int, ...], Standardizer]:
    """What every estimator's ``spec`` holds alike, rebuilt: the prior box, the embedding's
    skeleton, the observation shape and an identity x standardiser of the stored shape."""
    prior = BoxPrior(jnp.asarray(spec["low"]), jnp.asarray(spec["high"]), spec["names"])
    name, espec = spec["embedding"]
    xs = tuple(spec["x_std_shape"])
    xstd = Standardizer(mean=jnp.zeros(xs), std=jnp.ones(xs))
    return prior, embedding_from_spec(name, espec), tuple(spec["x_shape"]), xstd
