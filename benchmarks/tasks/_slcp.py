"""slcp (Papamakarios et al. 2019; sbibm): simple likelihood, complex posterior."""

import functools
import math

import jax
import jax.numpy as jnp
import numpy as np

from vdsbi.inference import BoxPrior

from ._base import AbstractTask


def _params(theta):
    m = theta[:2]
    s1, s2 = theta[2] ** 2, theta[3] ** 2
    return m, s1, s2, jnp.tanh(theta[4])


def slcp_log_likelihood(theta, x):
    """Exact ``log p(x | θ)`` for one θ (5,) and one x (8,) = 4 iid 2-D Gaussian draws."""
    m, s1, s2, rho = _params(theta)
    xs = x.reshape(4, 2)
    z0, z1 = (xs[:, 0] - m[0]) / s1, (xs[:, 1] - m[1]) / s2
    a = jnp.abs(theta[4])
    log1mr2 = -2.0 * (a + jnp.log1p(jnp.exp(-2.0 * a)) - math.log(2.0))  # log(1 - tanh²)
    q = (z0**2 - 2.0 * rho * z0 * z1 + z1**2) / jnp.exp(log1mr2)
    per = -math.log(2 * math.pi) - jnp.log(s1) - jnp.log(s2) - 0.5 * log1mr2 - 0.5 * q
    return jnp.sum(per)


class SLCP(AbstractTask):
    """θ ~ U(-3, 3)⁵; m = θ₁,₂, s₁ = θ₃², s₂ = θ₄², ρ = tanh θ₅;
    x = 4 iid draws of N(m, [[s₁², ρ s₁ s₂], [ρ s₁ s₂, s₂²]]), flattened to 8."""

    name = "slcp"
    dim_theta = 5
    dim_x = 8
    exact_posterior = False  # posterior_samples: MCMC (no closed form)

    @property
    def prior(self):
        return BoxPrior(-3.0 * jnp.ones(5), 3.0 * jnp.ones(5))

    def simulate_one(self, key, theta):
        m, s1, s2, rho = _params(theta)
        e = jax.random.normal(key, (4, 2))
        x0 = m[0] + s1 * e[:, 0]
        x1 = m[1] + s2 * (rho * e[:, 0] + jnp.sqrt(1.0 - rho**2) * e[:, 1])
        return jnp.stack([x0, x1], axis=1).reshape(8)

    def _sample_reference(self, key, x_o, n):
        with jax.enable_x64(True):
            return np.asarray(_slcp_mcmc(key, jnp.asarray(x_o, jnp.float64), n))


def _slcp_mcmc(key, x_o, n, num_chains=1000, stages=10, stage_steps=200, thin=50):
    """Population random-walk Metropolis on the sign-folded space (θ₃, θ₄ >= 0).

    The likelihood depends on θ₃, θ₄ only through their squares, so the posterior has four
    mirror-image modes. We sample the folded target with a reflected (hence still symmetric)
    Gaussian random walk, initialised by sampling-importance-resampling from 10⁶ prior draws
    and adapted between stages from the population covariance (fixed within a stage), then
    restore the symmetry by independent random sign flips.
    """
    lo, hi = -3.0, 3.0

    def log_target(th):
        inside = jnp.all((th >= lo) & (th <= hi))
        ll = slcp_log_likelihood(jnp.where(inside, th, 1.0), x_o)
        return jnp.where(inside & jnp.isfinite(ll), ll, -jnp.inf)

    vlt = jax.jit(jax.vmap(log_target))
    k_init, k_res, k_run, k_flip = jax.random.split(key, 4)
    pool, logw = [], []
    for k in jax.random.split(k_init, 10):
        th = jax.random.uniform(k, (100_000, 5), jnp.float64, lo, hi)
        th = th.at[:, 2:4].set(jnp.abs(th[:, 2:4]))
        pool.append(th)
        logw.append(vlt(th))
    pool, logw = jnp.concatenate(pool), jnp.concatenate(logw)
    cdf = jnp.cumsum(jnp.exp(logw - jnp.max(logw)))
    u = jax.random.uniform(k_res, (num_chains,), cdf.dtype) * cdf[-1]
    chains = pool[jnp.minimum(jnp.searchsorted(cdf, u), pool.shape[0] - 1)]

    @functools.partial(jax.jit, static_argnums=3)
    def run(key, chains, chol, steps):
        def step(carry, k):
            th, lp = carry
            kp, ku = jax.random.split(k)
            prop = th + jax.random.normal(kp, th.shape, th.dtype) @ chol.T
            prop = prop.at[:, 2:4].set(jnp.abs(prop[:, 2:4]))
            lp_prop = jax.vmap(log_target)(prop)
            acc = jnp.log(jax.random.uniform(ku, lp.shape, lp.dtype)) < lp_prop - lp
            th = jnp.where(acc[:, None], prop, th)
            return (th, jnp.where(acc, lp_prop, lp)), (th, acc)

        (th, lp), (trace, acc) = jax.lax.scan(
            step, (chains, jax.vmap(log_target)(chains)), jax.random.split(key, steps)
        )
        return th, trace, jnp.mean(acc)

    keys = jax.random.split(k_run, stages + 1)
    for s in range(stages):
        cov = jnp.cov(chains.T) + 1e-8 * jnp.eye(5)
        chol = jnp.linalg.cholesky((2.38**2 / 5) * cov)
        chains, _, _ = run(keys[s], chains, chol, stage_steps)
    cov = jnp.cov(chains.T) + 1e-8 * jnp.eye(5)
    chol = jnp.linalg.cholesky((2.38**2 / 5) * cov)
    per_chain = -(-n // num_chains)
    _, trace, _ = run(keys[-1], chains, chol, per_chain * thin)
    samples = trace[thin - 1 :: thin].reshape(-1, 5)
    signs = jnp.where(jax.random.bernoulli(k_flip, 0.5, (samples.shape[0], 2)), 1.0, -1.0)
    samples = samples.at[:, 2:4].multiply(signs)
    perm = jax.random.permutation(jax.random.fold_in(k_flip, 1), samples.shape[0])
    return samples[perm][:n]
