"""Amortised NPE on simulations the caller already has (no simulator, no rounds)."""

import functools
from collections.abc import Callable
from typing import Any

import jax
import numpy as np
from jaxtyping import PRNGKeyArray

from ._build import build_flow, first_round_loss
from ._config import NPEConfig
from ._embeddings import AbstractEmbedding
from ._estimator import AbstractEstimator
from ._prior import BoxPrior
from ._train import Examples, fit


def npe(
    key: PRNGKeyArray,
    prior: BoxPrior,
    theta: np.ndarray,
    x: np.ndarray,
    *,
    embedding: AbstractEmbedding,
    config: NPEConfig = NPEConfig(),
    mesh=None,
    on_epoch_end: Callable[[int, int, float, float], None] | None = None,
) -> tuple[AbstractEstimator, dict[str, Any]]:
    """Train ``q(θ | x)`` on the pairs ``(theta, x)`` (prior draws): by maximum likelihood, or
    by flow matching with ``config.flow`` a `FlowMatchingSettings`.

    The same estimator as round 1 of :func:`apt`, for a fixed set of simulations (e.g. to
    compare with another toolkit on identical data). A random ``validation_fraction`` of
    the pairs is held out for early stopping. Returns ``(flow, info)``; wrap the flow in a
    :class:`Posterior` to sample at an observation. ``on_epoch_end(0, epoch, train_loss,
    val_loss)`` is called after every epoch (progress, profiling).
    """
    theta, x = np.asarray(theta, np.float32), np.asarray(x, np.float32)
    if theta.ndim != 2 or theta.shape[1] != prior.dim or x.shape[0] != theta.shape[0]:
        raise ValueError(f"need theta (N, {prior.dim}) and x (N, ...), got {theta.shape} and {x.shape}")
    k_split, k_init, k_train = jax.random.split(key, 3)
    m = theta.shape[0]
    is_val = np.zeros(m, bool)
    n_val = max(1, round(config.training.validation_fraction * m))
    is_val[np.asarray(jax.random.permutation(k_split, m))[:n_val]] = True
    flow = build_flow(k_init, prior, embedding, theta[~is_val], x[~is_val], config.flow)
    loss = first_round_loss(config.flow)
    examples = Examples(theta, x, np.ones(m, bool), is_val)
    report = None if on_epoch_end is None else functools.partial(on_epoch_end, 0)
    return fit(k_train, flow, examples, loss, config.training, mesh=mesh, on_epoch_end=report)
