"""Noise models: sensor noise (the seed's relative noise, additive noise) and the seed's
process noise on the stiffnesses."""

from __future__ import annotations

import equinox as eqx
import jax
import jax.numpy as jnp
from jaxtyping import Array, Float, PRNGKeyArray

from ._vehicle import CHANNELS, NOMINAL_THETA, PARAM_NAMES

#: The seed's sensor noise: std = 10 % of the value on accelerations, 5 % on rotational
#: channels (we also apply 5 % to vx, which the seed does not measure).
SEED_RELATIVE_NOISE: dict[str, float] = {
    "ax": 0.10,
    "ay": 0.10,
    "yaw_rate": 0.05,
    "omega_front": 0.05,
    "omega_rear": 0.05,
    "vx": 0.05,
}


class SensorNoise(eqx.Module):
    """y + ε·(relative·|y| + additive), ε ~ N(0, 1) independently per sample and channel.

    Attributes:
        relative: (6,) relative std per channel (CHANNELS order).
        additive: (6,) additive std per channel, channel units.
    """

    relative: Float[Array, "6"]
    additive: Float[Array, "6"]

    def __call__(self, key: PRNGKeyArray, ys: Float[Array, "T 6"]) -> Float[Array, "T 6"]:
        eps = jax.random.normal(key, ys.shape, ys.dtype)
        return ys + eps * (self.relative * jnp.abs(ys) + self.additive)

    def std(self, ys: Float[Array, "T 6"]) -> Float[Array, "T 6"]:
        return self.relative * jnp.abs(ys) + self.additive

    @classmethod
    def none(cls) -> SensorNoise:
        """No noise."""
        zeros = jnp.zeros(len(CHANNELS))
        return cls(zeros, zeros)

    @classmethod
    def seed(cls) -> SensorNoise:
        """The seed's relative noise (`SEED_RELATIVE_NOISE`)."""
        return cls(jnp.array([SEED_RELATIVE_NOISE[c] for c in CHANNELS]), jnp.zeros(len(CHANNELS)))

    @classmethod
    def additive_std(cls, noise_std: dict[str, float]) -> SensorNoise:
        """Additive noise of std ``noise_std[channel]`` (a vehicle file's ``noise_std``; 0 for
        channels it does not name)."""
        return cls(jnp.zeros(len(CHANNELS)), jnp.array([noise_std.get(c, 0.0) for c in CHANNELS]))


class StiffnessMixtureNoise(eqx.Module):
    """The seed's process noise: each stiffness is perturbed by a draw from a mixture of ten
    Gaussians whose means and stds are random, up to 5 % of the Table I nominal values.

    The mixture itself is generated once from `key` (means uniform in ±5 %, stds uniform
    in (0, 5 %], equal weights); each simulation then draws one perturbation per stiffness.
    """

    means: Float[Array, "10 4"]
    stds: Float[Array, "10 4"]

    def __init__(self, key: PRNGKeyArray, num_components: int = 10, fraction: float = 0.05):
        k1, k2 = jax.random.split(key)
        nominal = jnp.array([NOMINAL_THETA[n] for n in PARAM_NAMES[2:]])
        self.means = jax.random.uniform(k1, (num_components, 4), minval=-fraction, maxval=fraction) * nominal
        self.stds = jax.random.uniform(k2, (num_components, 4), minval=0.0, maxval=fraction)
        self.stds = jnp.maximum(self.stds, 1e-3 * fraction) * nominal

    def __call__(self, key: PRNGKeyArray, theta: Float[Array, "6"]) -> Float[Array, "6"]:
        k1, k2 = jax.random.split(key)
        comp = jax.random.randint(k1, (4,), 0, self.means.shape[0])
        idx = jnp.arange(4)
        eps = self.means[comp, idx] + self.stds[comp, idx] * jax.random.normal(k2, (4,))
        return theta.at[2:].add(eps)
