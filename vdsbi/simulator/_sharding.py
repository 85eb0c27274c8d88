"""Draws along a leading batch axis, split evenly over all JAX devices."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
from jax.sharding import Mesh, NamedSharding, PartitionSpec


def shard_draws(tree, n: int):
    """Pad every leaf's leading axis of length `n` to a multiple of the device count (with copies
    of the first draw) and split it over a 1-D mesh of all devices.

    Returns:
        the placed tree; slice results back with `[:n]`.
    """
    n_dev = jax.device_count()
    pad = (-n) % n_dev
    if pad:
        tree = jax.tree.map(lambda a: jnp.concatenate([a, jnp.repeat(a[:1], pad, axis=0)]), tree)
    if n_dev == 1:
        return tree
    mesh = Mesh(np.array(jax.devices()), ("batch",))
    return jax.device_put(tree, NamedSharding(mesh, PartitionSpec("batch")))
