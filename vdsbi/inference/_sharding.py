"""Data parallelism: shard the batch axis over a 1-D mesh of all devices, replicate the rest."""

import equinox as eqx
import jax
import numpy as np
from jax.sharding import Mesh, NamedSharding, PartitionSpec as P


def data_mesh(devices=None) -> Mesh:
    """1-D mesh named ``"batch"`` over ``devices`` (default: all of ``jax.devices()``)."""
    devices = jax.devices() if devices is None else devices
    return Mesh(np.asarray(devices), ("batch",))


def shard_batch(tree, mesh: Mesh):
    """Place every array leaf with its leading (batch) axis split across the mesh."""
    return jax.device_put(tree, NamedSharding(mesh, P("batch")))


def replicate(tree, mesh: Mesh):
    """Place every array leaf of ``tree`` (e.g. a model, an optimiser state) on all devices."""
    arrays, static = eqx.partition(tree, eqx.is_array)
    arrays = jax.device_put(arrays, NamedSharding(mesh, P()))
    return eqx.combine(arrays, static)


def stack_batches(tree, mesh: Mesh):
    """Place leaves shaped ``(num_batches, batch, ...)`` with the batch (second) axis split."""
    return jax.device_put(tree, NamedSharding(mesh, P(None, "batch")))
