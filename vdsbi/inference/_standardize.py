"""Affine standardisation with statistics frozen at fit time."""

from typing import Literal

import equinox as eqx
import jax.numpy as jnp
from jaxtyping import Array, Float


class Standardizer(eqx.Module):
    """``(x - mean) / std`` on ONE example, broadcasting ``mean``/``std`` over its shape.

    ``mean``/``std`` have shape ``(C,)`` (per channel: statistics over all axes but
    the last, so for vector data this is per feature) or ``()`` (one global scale).
    """

    mean: Float[Array, "..."]
    std: Float[Array, "..."]

    @classmethod
    def fit(
        cls, x: Float[Array, "n ..."], mode: Literal["channel", "global", "none"] = "channel"
    ) -> "Standardizer":
        """Statistics from a batch ``x`` of shape ``(n, ..., C)``."""
        x = jnp.asarray(x)
        if mode == "none":
            return cls.identity(x.shape[-1] if x.ndim > 1 else 1, per_channel=x.ndim > 1)
        axes = tuple(range(x.ndim - 1)) if (mode == "channel" and x.ndim > 1) else None
        mean = jnp.mean(x, axis=axes)
        std = jnp.std(x, axis=axes)
        std = jnp.where(std > 1e-12, std, 1.0)
        return cls(mean=mean, std=std)

    @classmethod
    def identity(cls, channels: int, per_channel: bool = True) -> "Standardizer":
        shape = (channels,) if per_channel else ()
        return cls(mean=jnp.zeros(shape), std=jnp.ones(shape))

    def __call__(self, x: Float[Array, "..."]) -> Float[Array, "..."]:
        return (x - self.mean) / self.std

    def inverse(self, y: Float[Array, "..."]) -> Float[Array, "..."]:
        return y * self.std + self.mean

    def log_det(self) -> Float[Array, ""]:
        """``log|d standardise / dx|`` for a vector whose length matches ``std``."""
        return -jnp.sum(jnp.log(self.std))
