"""Uniform box prior; its bijection to ℝⁿ is the problem's one (`vdsbi.problem.Box`)."""

import equinox as eqx
import jax
import jax.numpy as jnp
from jaxtyping import Array, Float, PRNGKeyArray

from ..problem import Box

#: A flow's draws keep this far (a share of the width) from the box's faces.
EDGE = 1e-6


class BoxPrior(eqx.Module):
    """Independent uniform prior on the box ``[low, high]``.

    Args:
        low: lower bounds, shape ``(d,)``.
        high: upper bounds, shape ``(d,)``.
        names: optional parameter names (length ``d``).
    """

    box: Box
    named: bool = eqx.field(static=True)

    def __init__(self, low, high, names=None):
        low = jnp.asarray(low, dtype=float).reshape(-1)
        high = jnp.asarray(high, dtype=float).reshape(-1)
        self.named = names is not None
        names = tuple(names) if self.named else tuple(f"theta_{i}" for i in range(low.size))
        self.box = Box(low, high, names)

    @property
    def low(self) -> Float[Array, " d"]:
        return self.box.low

    @property
    def high(self) -> Float[Array, " d"]:
        return self.box.high

    @property
    def names(self) -> tuple[str, ...] | None:
        return self.box.names if self.named else None

    @property
    def dim(self) -> int:
        return self.box.dim

    def sample(self, key: PRNGKeyArray, n: int) -> Float[Array, "n d"]:
        """``n`` independent draws."""
        u = jax.random.uniform(key, (n, self.dim), dtype=self.low.dtype)
        return self.low + u * self.box.width

    def log_prob(self, theta: Float[Array, "*batch d"]) -> Float[Array, "*batch"]:
        """Log density; ``-inf`` outside the (closed) box."""
        lp = -jnp.sum(jnp.log(self.box.width))
        return jnp.where(self.box.contains(theta), lp, -jnp.inf)

    def to_unbounded(self, theta: Float[Array, " d"]) -> tuple[Float[Array, " d"], Float[Array, ""]]:
        """``z`` of one θ (`Box.to_unbounded`) and ``log|dz/dθ|`` there."""
        z = self.box.to_unbounded(theta, edge=EDGE)
        return z, -self.box.log_det_from_unbounded(z)

    def from_unbounded(self, z: Float[Array, " d"]) -> Float[Array, " d"]:
        """Inverse of :meth:`to_unbounded`. A flow's draw lands strictly inside the box (where
        the working precision resolves it), so every draw maps back to the z it came from."""
        return self.box.from_unbounded(z, edge=EDGE)
