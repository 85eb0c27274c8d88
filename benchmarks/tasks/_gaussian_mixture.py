"""gaussian_mixture (sbibm): x ~ ½ N(θ, I) + ½ N(θ, 0.01 I), θ ~ U(-10, 10)²."""

import jax
import jax.numpy as jnp
import numpy as np

from vdsbi.inference import BoxPrior

from ._base import AbstractTask, rejection


class GaussianMixture(AbstractTask):
    name = "gaussian_mixture"
    dim_theta = 2
    dim_x = 2

    @property
    def prior(self):
        return BoxPrior(-10.0 * jnp.ones(2), 10.0 * jnp.ones(2))

    def simulate_one(self, key, theta):
        kc, kn = jax.random.split(key)
        scale = jnp.where(jax.random.bernoulli(kc, 0.5), 1.0, 0.1)
        return theta + scale * jax.random.normal(kn, theta.shape)

    def _sample_reference(self, key, x_o, n):
        # Exact: the posterior is the same mixture centred at x_o, restricted to the box.
        def propose(k, m):
            kc, kn = jax.random.split(k)
            scale = np.where(np.asarray(jax.random.bernoulli(kc, 0.5, (m, 1))), 1.0, 0.1)
            return x_o + scale * np.asarray(jax.random.normal(kn, (m, 2)), np.float64)

        return rejection(key, propose, lambda th: np.all(np.abs(th) <= 10.0, axis=1), n)
