"""Draws along a leading batch axis, split evenly over all JAX devices.

On a CPU, JAX gives one device by default and XLA runs a vmapped simulation on one core, so a
batch of draws would leave the other cores idle. When this module is imported before JAX has
started, vdsbi asks JAX for one CPU device per core (at most ``MAX_CPU_DEVICES``) through JAX's
own option ``jax_num_cpu_devices``, and batches of draws are split over them
(``benchmarks/simulator.py`` measures the gain). ``VDSBI_CPU_DEVICES=N`` sizes it and ``=1``
turns it off. Training keeps to the first CPU device (see `data_mesh` in `vdsbi/inference/_sharding.py`). The
setting is skipped if the user already chose (``jax_num_cpu_devices`` set, or
``--xla_force_host_platform_device_count`` in ``XLA_FLAGS``) or JAX already ran something.
"""

from __future__ import annotations

import os

import jax
import jax.numpy as jnp
import numpy as np
from jax.sharding import Mesh, NamedSharding, PartitionSpec


def shard_draws(tree, n: int, minimum: int = 1):
    """Pad every leaf's leading axis of length `n` to at least `minimum`, then to a multiple of
    the device count (with copies of the first draw), and split it over a 1-D mesh of all devices.

    Returns:
        the placed tree; slice results back with `[:n]`.
    """
    n_dev = jax.device_count()
    size = max(n, minimum)
    pad = size - n + (-size) % n_dev
    if pad:
        tree = jax.tree.map(lambda a: jnp.concatenate([a, jnp.repeat(a[:1], pad, axis=0)]), tree)
    if n_dev == 1:
        return tree
    mesh = Mesh(np.array(jax.devices()), ("batch",))
    return jax.device_put(tree, NamedSharding(mesh, PartitionSpec("batch")))


MAX_CPU_DEVICES = 8
ENV_CPU_DEVICES = "VDSBI_CPU_DEVICES"


def cpu_devices_wanted(env: dict | None = None) -> int:
    """CPU devices vdsbi asks JAX for: ``VDSBI_CPU_DEVICES`` (unset or ``auto``: one per core)."""
    env = os.environ if env is None else env
    raw = env.get(ENV_CPU_DEVICES, "auto").strip().lower() or "auto"
    if raw == "auto":
        return max(1, min(len(os.sched_getaffinity(0)), MAX_CPU_DEVICES))
    try:
        n = int(raw)
    except ValueError:
        raise ValueError(f"{ENV_CPU_DEVICES} must be 'auto' or a positive integer, got {raw!r}") from None
    if n < 1:
        raise ValueError(f"{ENV_CPU_DEVICES} must be 'auto' or a positive integer, got {raw!r}")
    return n


def use_cpu_cores() -> bool:
    """Ask JAX for ``cpu_devices_wanted()`` CPU devices if nobody chose and JAX has not started.

    Returns whether the setting was made (called once when vdsbi is imported).
    """
    n = cpu_devices_wanted()
    user_chose = jax.config.jax_num_cpu_devices != -1 or "xla_force_host_platform_device_count" in (
        os.environ.get("XLA_FLAGS", "")
    )
    if n <= 1 or user_chose:
        return False
    try:
        jax.config.update("jax_num_cpu_devices", n)
    except RuntimeError:  # backends already initialised by the caller: leave them as they are
        return False
    return True


use_cpu_cores()
