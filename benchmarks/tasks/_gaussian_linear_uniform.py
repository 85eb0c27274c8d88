"""gaussian_linear_uniform (sbibm): x ~ N(θ, 0.1 I), θ ~ U(-1, 1)¹⁰."""

import jax
import jax.numpy as jnp
import numpy as np
import scipy.stats

from vdsbi.inference import BoxPrior

from ._base import AbstractTask

_VAR = 0.1


class GaussianLinearUniform(AbstractTask):
    name = "gaussian_linear_uniform"
    dim_theta = 10
    dim_x = 10

    @property
    def prior(self):
        return BoxPrior(-jnp.ones(10), jnp.ones(10))

    def simulate_one(self, key, theta):
        return theta + jnp.sqrt(_VAR) * jax.random.normal(key, theta.shape)

    def _sample_reference(self, key, x_o, n):
        # Exact: independent truncated normals N(x_o,i, 0.1) on [-1, 1].
        seed = int(np.asarray(jax.random.randint(key, (), 0, 2**31 - 1)))
        sd = np.sqrt(_VAR)
        a, b = (-1.0 - x_o) / sd, (1.0 - x_o) / sd
        rng = np.random.default_rng(seed)
        return scipy.stats.truncnorm.rvs(a, b, loc=x_o, scale=sd, size=(n, 10), random_state=rng)
