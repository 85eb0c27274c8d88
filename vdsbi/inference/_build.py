"""A fresh estimator for a round: its standardisations fitted on the data, initialised compiled."""

import functools
from collections.abc import Callable

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import PRNGKeyArray

from ._config import FlowMatchingSettings, SplineFlowSettings
from ._embeddings import AbstractEmbedding
from ._estimator import AbstractEstimator
from ._flow import ConditionalFlow
from ._flow_matching import FlowMatchingEstimator, FlowMatchingLoss
from ._loss import MaximumLikelihoodLoss
from ._prior import BoxPrior
from ._standardize import ChannelStandardization


def build_flow(
    key: PRNGKeyArray,
    prior: BoxPrior,
    embedding: AbstractEmbedding,
    theta: np.ndarray,
    x: np.ndarray,
    settings: SplineFlowSettings | FlowMatchingSettings,
) -> AbstractEstimator:
    """A fresh estimator of ``settings``' kind whose θ (in the space of ``settings.theta_map``)
    and x standardisations are fitted on ``theta``/``x``."""
    z, _ = jax.vmap(lambda t: settings.theta_map.forward(prior, t))(jnp.asarray(theta))
    x_standardizer = settings.x_standardize.fit(jnp.asarray(x))
    # data-dependent initialisation of the embedding (a fixed subset bounds the cost)
    embedding = embedding.calibrate(jax.vmap(x_standardizer)(jnp.asarray(x[:2048])))
    theta_standardizer = ChannelStandardization().fit(z)

    parts = (prior, embedding, x.shape[1:], settings, theta_standardizer, x_standardizer)
    return _init_compiled(key, parts)


def _make(key, prior, embedding, x_shape, settings, theta_standardizer, x_standardizer):
    """One estimator of ``settings``' kind, its weights drawn from ``key``."""
    if isinstance(settings, FlowMatchingSettings):
        return FlowMatchingEstimator(
            key,
            prior,
            embedding,
            x_shape,
            settings,
            theta_standardizer=theta_standardizer,
            x_standardizer=x_standardizer,
        )
    return ConditionalFlow(
        key,
        prior,
        embedding,
        x_shape,
        settings,
        theta_standardizer=theta_standardizer,
        x_standardizer=x_standardizer,
    )


# XLA's CPU backend at optimisation level 1 (default 2+), for the initialisation only: the
# training steps would compile faster too, but their results would not be bit-identical to the
# default level's.
_INIT_CPU_OPTIONS = {"xla_backend_optimization_level": 1}


@functools.lru_cache(maxsize=16)
def _init_program(backend: str, treedef, leaves: tuple) -> Callable:
    """The compiled initialisation for one static structure of the estimator's parts.

    Cached on the structure (not on a closure, which is new every call), so a second fit with
    the same settings and shapes neither re-traces nor re-compiles it.
    """
    static = jax.tree_util.tree_unflatten(treedef, leaves)

    def arrays(key, dynamic):
        return eqx.filter(_make(key, *eqx.combine(dynamic, static)), eqx.is_array)

    return jax.jit(arrays, compiler_options=_INIT_CPU_OPTIONS if backend == "cpu" else None)


def _init_compiled(key: PRNGKeyArray, parts: tuple):
    """``_make(key, *parts)`` as one compiled program (on the CPU at XLA optimisation
    level 1), compiled once per static structure of ``parts``.

    Built op by op, the initialisation would compile dozens of small kernels; as one program
    at the CPU's default level its random draws are slow to compile for a program that runs
    once. Level 1 gives the same weights bit for bit, compiled faster.
    """
    dynamic, static = eqx.partition(parts, eqx.is_array)
    leaves, treedef = jax.tree_util.tree_flatten(static)
    try:
        program = _init_program(jax.default_backend(), treedef, tuple(leaves))
    except TypeError:  # an unhashable non-array leaf (e.g. in a user's embedding): not cached
        program = _init_program.__wrapped__(jax.default_backend(), treedef, tuple(leaves))
    arrays = program(key, dynamic)
    shapes = eqx.filter_eval_shape(_make, key, *parts)
    static_out = eqx.filter(shapes, lambda a: isinstance(a, jax.ShapeDtypeStruct), inverse=True)
    return eqx.combine(arrays, static_out)


def first_round_loss(
    settings: SplineFlowSettings | FlowMatchingSettings,
) -> MaximumLikelihoodLoss | FlowMatchingLoss:
    """The loss on prior (or truncated-prior) draws: maximum likelihood, or flow matching."""
    return FlowMatchingLoss() if isinstance(settings, FlowMatchingSettings) else MaximumLikelihoodLoss()
