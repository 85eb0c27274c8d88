"""Affine standardisation with statistics frozen at fit time, and the ways to fit them."""

from typing import ClassVar

import equinox as eqx
import jax.numpy as jnp
from jaxtyping import Array, Float


class Standardizer(eqx.Module):
    """``(x - mean) / std`` on ONE example, broadcasting ``mean``/``std`` over its shape.

    ``mean``/``std`` have shape ``(C,)`` (per channel: statistics over all axes but
    the last, so for vector data this is per feature), ``()`` (one global scale) or the
    example's shape (`TrajectoryStandardization`).
    """

    mean: Float[Array, "..."]
    std: Float[Array, "..."]

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


class AbstractStandardization(eqx.Module):
    """How a `Standardizer`'s statistics are fitted to a batch ``x`` of shape ``(n, ..., C)``."""

    name: eqx.AbstractClassVar[str]

    def fit(self, x: Float[Array, "n ..."]) -> Standardizer:
        raise NotImplementedError


def _moments(x: Float[Array, "n ..."], axes) -> Standardizer:
    std = jnp.std(x, axis=axes)
    return Standardizer(mean=jnp.mean(x, axis=axes), std=jnp.where(std > 1e-12, std, 1.0))


class ChannelStandardization(AbstractStandardization):
    """Per channel: statistics over all axes but the last."""

    name: ClassVar[str] = "channel"

    def fit(self, x):
        x = jnp.asarray(x)
        return _moments(x, tuple(range(x.ndim - 1)) if x.ndim > 1 else None)


class GlobalStandardization(AbstractStandardization):
    """One mean and one scale over everything."""

    name: ClassVar[str] = "global"

    def fit(self, x):
        return _moments(jnp.asarray(x), None)


class TrajectoryStandardization(AbstractStandardization):
    """For examples that share one time base and input (every simulation driven by the same
    recorded inputs): subtract the mean trajectory and divide each channel by the std of the
    deviations from it. θ-driven differences that are small beside the manoeuvre's own variation
    (wheel slip is ~1 % of ω) then become O(1) instead of vanishing under a per-channel scale.
    Channels that never deviate (the inputs themselves) get per-channel standardisation
    instead, so they are kept. Needs ``(n, T, C)`` data."""

    name: ClassVar[str] = "trajectory"

    def fit(self, x):
        x = jnp.asarray(x)
        if x.ndim < 3:
            raise ValueError(f"trajectory standardisation needs (n, T, C) data, got {x.shape}")
        axes = tuple(range(x.ndim - 1))
        traj = jnp.mean(x, axis=0)
        dev = jnp.std(x - traj, axis=axes)
        raw_mean, raw_std = jnp.mean(x, axis=axes), jnp.std(x, axis=axes)
        const = dev <= 1e-6 * jnp.maximum(raw_std, 1e-12)
        mean = jnp.where(const, raw_mean, traj)
        std = jnp.where(const, jnp.where(raw_std > 1e-12, raw_std, 1.0), dev)
        return Standardizer(mean=mean, std=jnp.broadcast_to(std, traj.shape))


class NoStandardization(AbstractStandardization):
    """The identity (per channel for ``(n, ..., C)`` data, one scale for vectors)."""

    name: ClassVar[str] = "none"

    def fit(self, x):
        x = jnp.asarray(x)
        return Standardizer.identity(x.shape[-1] if x.ndim > 1 else 1, per_channel=x.ndim > 1)
