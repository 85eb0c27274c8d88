"""Common task interface: prior, batched simulator, fixed observations, reference posteriors."""

import abc
import functools
import zlib

import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Bool, Float, PRNGKeyArray

from vdsbi.inference import BoxPrior

OBSERVATION_SEED = 20240601
REFERENCE_SEED = 20240602
NUM_OBSERVATIONS = 10


class AbstractTask(abc.ABC):
    """A benchmark task (as defined in sbibm) with exact reference posterior samples.

    Observations ``1..10`` are fixed: ``θ_o ~ prior`` and ``x_o ~ simulator(θ_o)`` drawn with
    keys folded from :data:`OBSERVATION_SEED` (sbibm's own observation files are not used).
    """

    name: str
    dim_theta: int
    dim_x: int

    @property
    @abc.abstractmethod
    def prior(self) -> BoxPrior: ...

    @abc.abstractmethod
    def simulate_one(self, key: PRNGKeyArray, theta: Float[Array, " d"]) -> Float[Array, " dx"]:
        """One simulation for one θ."""

    def simulate(self, key: PRNGKeyArray, theta: Float[Array, "n d"]) -> tuple[Array, Bool[Array, " n"]]:
        """Batched simulator in the ``apt`` convention: ``(x (n, dx), valid (n,))``."""
        keys = jax.random.split(key, theta.shape[0])
        x = _vsim(self, keys, jnp.asarray(theta))
        return x, jnp.all(jnp.isfinite(x), axis=-1)

    def observation(self, num: int) -> tuple[Float[Array, " d"], Float[Array, " dx"]]:
        """``(θ_true, x_o)`` of observation ``num`` (1-based)."""
        return _observation(self, num)

    #: whether `posterior_samples` is exact (False: MCMC, as slcp's)
    exact_posterior: bool = True

    def reference_posterior_samples(self, num: int, n: int = 10_000) -> np.ndarray:
        """``n`` exact (or MCMC) samples from ``p(θ | x_o)`` of observation ``num``; cached."""
        return _reference(self, num, n)

    def posterior_samples(self, key: PRNGKeyArray, x_o: np.ndarray, n: int) -> np.ndarray:
        """``n`` samples (float32) from ``p(θ | x_o)`` for any ``x_o`` of shape ``(dim_x,)``:
        exact where `exact_posterior`, else MCMC."""
        samples = np.asarray(self._sample_reference(key, np.asarray(x_o, np.float64), n), np.float32)
        if samples.shape != (n, self.dim_theta):
            raise AssertionError(f"{self.name}: {samples.shape} samples, not {(n, self.dim_theta)}")
        return samples

    @abc.abstractmethod
    def _sample_reference(self, key: PRNGKeyArray, x_o: np.ndarray, n: int) -> np.ndarray: ...

    def __hash__(self):
        return hash(self.name)

    def __eq__(self, other):
        return isinstance(other, AbstractTask) and other.name == self.name


@functools.partial(jax.jit, static_argnums=0)
def _vsim(task, keys, theta):
    return jax.vmap(task.simulate_one)(keys, theta)


@functools.cache
def _observation(task: AbstractTask, num: int):
    if not 1 <= num <= NUM_OBSERVATIONS:
        raise ValueError(f"observation number must be in 1..{NUM_OBSERVATIONS}, got {num}")
    k = jax.random.fold_in(jax.random.key(OBSERVATION_SEED), num)
    k_theta, k_x = jax.random.split(jax.random.fold_in(k, zlib.crc32(task.name.encode()) % 2**31))
    theta = task.prior.sample(k_theta, 1)
    x, _ = task.simulate(k_x, theta)
    return theta[0], x[0]


@functools.lru_cache(maxsize=64)
def _reference(task: AbstractTask, num: int, n: int) -> np.ndarray:
    _, x_o = task.observation(num)
    key = jax.random.fold_in(jax.random.key(REFERENCE_SEED), num)
    key = jax.random.fold_in(key, zlib.crc32(task.name.encode()) % 2**31)
    return task.posterior_samples(key, x_o, n)


def rejection(key, propose, accept_fn, n: int, chunk: int = 100_000) -> np.ndarray:
    """Collect ``n`` accepted draws: ``propose(key, chunk) -> (chunk, d)``, ``accept_fn(theta) -> bool``."""
    out, got = [], 0
    while got < n:
        key, k = jax.random.split(key)
        cand = np.asarray(propose(k, chunk))
        acc = cand[np.asarray(accept_fn(cand))]
        out.append(acc)
        got += acc.shape[0]
    return np.concatenate(out)[:n]
