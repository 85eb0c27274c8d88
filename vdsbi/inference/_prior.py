"""Uniform box prior and the fixed bijection from the box to R^n."""

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float, PRNGKeyArray

# Unit-box coordinates are kept in [EDGE, 1 - EDGE] so logit stays finite in float32.
EDGE = 1e-6


class BoxPrior(eqx.Module):
    """Independent uniform prior on the box ``[low, high]``.

    Args:
        low: lower bounds, shape ``(d,)``.
        high: upper bounds, shape ``(d,)``.
        names: optional parameter names (length ``d``).
    """

    low: Float[Array, " d"]
    high: Float[Array, " d"]
    names: tuple[str, ...] | None = eqx.field(static=True, default=None)

    def __init__(self, low, high, names=None):
        self.low = jnp.asarray(low, dtype=float).reshape(-1)
        self.high = jnp.asarray(high, dtype=float).reshape(-1)
        self.names = None if names is None else tuple(names)

    def __check_init__(self):
        if self.low.shape != self.high.shape:
            raise ValueError(f"low {self.low.shape} and high {self.high.shape} must have the same shape")
        if not np.all(np.asarray(self.high) > np.asarray(self.low)):
            raise ValueError("BoxPrior needs high > low in every dimension")
        if self.names is not None and len(self.names) != self.low.shape[0]:
            raise ValueError(f"{len(self.names)} names for {self.low.shape[0]} parameters")

    @property
    def dim(self) -> int:
        return self.low.shape[0]

    def sample(self, key: PRNGKeyArray, n: int) -> Float[Array, "n d"]:
        """``n`` independent draws."""
        u = jax.random.uniform(key, (n, self.dim), dtype=self.low.dtype)
        return self.low + u * (self.high - self.low)

    def log_prob(self, theta: Float[Array, "*batch d"]) -> Float[Array, "*batch"]:
        """Log density; ``-inf`` outside the (closed) box."""
        inside = jnp.all((theta >= self.low) & (theta <= self.high), axis=-1)
        lp = -jnp.sum(jnp.log(self.high - self.low))
        return jnp.where(inside, lp, -jnp.inf)

    def to_unbounded(self, theta: Float[Array, " d"]) -> tuple[Float[Array, " d"], Float[Array, ""]]:
        """``z = logit((theta - low) / (high - low))`` for one θ; returns ``(z, log|dz/dθ|)``."""
        u = jnp.clip((theta - self.low) / (self.high - self.low), EDGE, 1.0 - EDGE)
        z = jnp.log(u) - jnp.log1p(-u)
        logdet = -jnp.sum(jnp.log(u) + jnp.log1p(-u) + jnp.log(self.high - self.low))
        return z, logdet

    def from_unbounded(self, z: Float[Array, " d"]) -> Float[Array, " d"]:
        """Inverse of :meth:`to_unbounded`.

        The result lies inside the closed box always, and strictly inside unless the box is
        narrower than ~1e-6 of its offset in the working precision.
        """
        u = jnp.clip(jax.nn.sigmoid(z), EDGE, 1.0 - EDGE)
        return jnp.clip(self.low + u * (self.high - self.low), self.low, self.high)
