"""The one map between a parameter box and ℝⁿ: θ = low + (high − low)·sigmoid(z).

Fits, Laplace posteriors and flows work in z, where the box constraint vanishes and a
Gaussian is a sensible local shape; reports work in θ.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, ArrayLike, Float

#: Unit-box coordinates are kept in [EDGE, 1 − EDGE] so the logit stays finite in float32.
EDGE = 1e-6


class Box(eqx.Module):
    """A box [low, high] ⊂ ℝᵈ and its logit bijection to ℝᵈ (one θ per call; vmap outside).

    Attributes:
        low, high: (d,) bounds, high > low.
        names: parameter names, one per dimension.
    """

    low: Float[Array, " d"]
    high: Float[Array, " d"]
    names: tuple[str, ...] = eqx.field(static=True)

    def __check_init__(self):
        if self.low.shape != self.high.shape or self.low.ndim != 1:
            raise ValueError(f"low {self.low.shape} and high {self.high.shape} must be equal 1-D shapes")
        if not np.all(np.asarray(self.high) > np.asarray(self.low)):
            raise ValueError("a box needs high > low in every dimension")
        if len(self.names) != self.low.shape[0]:
            raise ValueError(f"{len(self.names)} names for {self.low.shape[0]} dimensions")

    @classmethod
    def from_dict(cls, bounds: Mapping[str, tuple[float, float]], names: Sequence[str] | None = None) -> Box:
        """The box of `bounds` ({name: (low, high)}) over `names` (default: all, in order)."""
        names = tuple(bounds if names is None else names)
        lo = jnp.asarray([float(bounds[n][0]) for n in names])
        hi = jnp.asarray([float(bounds[n][1]) for n in names])
        return cls(lo, hi, names)

    @property
    def dim(self) -> int:
        return int(self.low.shape[0])

    @property
    def width(self) -> Float[Array, " d"]:
        return self.high - self.low

    def to_unbounded(self, theta: Float[ArrayLike, " d"], edge: float = EDGE) -> Float[Array, " d"]:
        """z = logit((θ − low)/(high − low)), the unit coordinate clipped to [edge, 1 − edge]."""
        u = jnp.clip((jnp.asarray(theta) - self.low) / self.width, edge, 1.0 - edge)
        return jnp.log(u) - jnp.log1p(-u)

    def from_unbounded(self, z: Float[ArrayLike, " d"], edge: float = 0.0) -> Float[Array, " d"]:
        """θ = low + (high − low)·sigmoid(z): inside the closed box for every z; with `edge`, the
        unit coordinate is held in [edge, 1 − edge] as `to_unbounded` holds it (strictly inside
        the box where the working precision resolves it)."""
        u = jax.nn.sigmoid(jnp.asarray(z))
        if edge:
            u = jnp.clip(u, edge, 1.0 - edge)
        return jnp.clip(self.low + self.width * u, self.low, self.high)

    def log_det_from_unbounded(self, z: Float[ArrayLike, " d"]) -> Float[Array, ""]:
        """log|dθ/dz| at z."""
        z = jnp.asarray(z)
        return jnp.sum(jnp.log(self.width) + jax.nn.log_sigmoid(z) + jax.nn.log_sigmoid(-z))

    def dtheta_dz(self, z: Float[ArrayLike, " d"]) -> Float[Array, " d"]:
        """Diagonal of the Jacobian dθ/dz at z."""
        s = jax.nn.sigmoid(jnp.asarray(z))
        return self.width * s * (1.0 - s)

    def contains(self, theta: Float[ArrayLike, "*batch d"]) -> Array:
        theta = jnp.asarray(theta)
        return jnp.all((theta >= self.low) & (theta <= self.high), axis=-1)
