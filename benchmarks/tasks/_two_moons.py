"""two_moons (Greenberg et al. 2019; sbibm): bimodal crescent posterior."""

import math

import jax
import jax.numpy as jnp
import numpy as np

from vdsbi.inference import BoxPrior

from ._base import AbstractTask, rejection


class TwoMoons(AbstractTask):
    """θ ~ U(-1, 1)²; a ~ U(-π/2, π/2), r ~ N(0.1, 0.01²), p = (r cos a + 0.25, r sin a);
    x = p + (-|θ₁ + θ₂| / √2, (-θ₁ + θ₂) / √2)."""

    name = "two_moons"
    dim_theta = 2
    dim_x = 2

    @property
    def prior(self):
        return BoxPrior(-jnp.ones(2), jnp.ones(2))

    def simulate_one(self, key, theta):
        ka, kr = jax.random.split(key)
        a = jax.random.uniform(ka, (), minval=-math.pi / 2, maxval=math.pi / 2)
        r = 0.1 + 0.01 * jax.random.normal(kr, ())
        p = jnp.stack([r * jnp.cos(a) + 0.25, r * jnp.sin(a)])
        shift = jnp.stack([-jnp.abs(theta[0] + theta[1]), -theta[0] + theta[1]]) / math.sqrt(2.0)
        return p + shift

    def _sample_reference(self, key, x_o, n):
        # Exact: the map θ -> shift is an isometry on each half-plane θ₁+θ₂ ≷ 0, so drawing the
        # noise p, a random branch, inverting, and rejecting outside the prior is exact.
        def propose(k, m):
            ka, kr, ks = jax.random.split(k, 3)
            a = np.asarray(jax.random.uniform(ka, (m,), minval=-math.pi / 2, maxval=math.pi / 2), np.float64)
            r = 0.1 + 0.01 * np.asarray(jax.random.normal(kr, (m,)), np.float64)
            sign = np.where(np.asarray(jax.random.bernoulli(ks, 0.5, (m,))), 1.0, -1.0)
            q0 = x_o[0] - (r * np.cos(a) + 0.25)
            q1 = x_o[1] - r * np.sin(a)
            s = -math.sqrt(2.0) * q0  # = |θ₁ + θ₂|, must be >= 0
            d = math.sqrt(2.0) * q1  # = θ₂ - θ₁
            th = np.stack([(sign * s - d) / 2, (sign * s + d) / 2], axis=1)
            th[s < 0] = np.nan
            return th

        ok = lambda th: np.all(np.abs(th) <= 1.0, axis=1)  # NaN compares False
        return rejection(key, propose, ok, n)
