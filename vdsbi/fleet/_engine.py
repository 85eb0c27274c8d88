"""The distributed engine: Dask.distributed. A local cluster of single-threaded worker processes
by default (one per core), or an existing scheduler's workers by address.

Each worker compiles a JAX program once and keeps it in JAX's persistent compilation cache, which
every worker (and every later run) reads, so a fleet compiles its programs once per machine. The
scheduler reschedules the task of a worker that dies (a killed process, an out-of-memory kill) on
another worker, up to `ALLOWED_FAILURES` times.
"""

from __future__ import annotations

import contextlib
import dataclasses
import logging
import os
from collections.abc import Iterator
from pathlib import Path

from ..simulator import ENV_CPU_DEVICES

#: XLA flags that keep a worker's programs on one thread: the cluster's parallelism is the workers.
SINGLE_THREAD_FLAGS = "--xla_cpu_multi_thread_eigen=false intra_op_parallelism_threads=1"
#: Deaths of the worker running a drive before that drive is given up (this run; a re-run retries).
ALLOWED_FAILURES = 3
#: The engine's settings. A worker's memory is JAX's, not Dask's: spilling has nothing to spill
#: and pausing a worker stalls its drive for good, so only a runaway worker is restarted (its
#: drive retried).
DASK_CONFIG = {
    "distributed.scheduler.allowed-failures": ALLOWED_FAILURES,
    "distributed.worker.memory.target": False,
    "distributed.worker.memory.spill": False,
    "distributed.worker.memory.pause": False,
    "distributed.worker.memory.terminate": 0.95,
}
#: Size limit of the persistent compilation cache.
CACHE_MAX_BYTES = 2 * 1024**3


@dataclasses.dataclass(frozen=True)
class Cluster:
    """Where the fleet runs.

    Attributes:
        address: an existing Dask scheduler ("tcp://host:8786"); None starts a local cluster.
        workers: local worker processes (default: one per core).
        compilation_cache: the folder of compiled programs the workers share (None: none).
        xla_flags: XLA_FLAGS of the local workers (the single-thread flags are added).
    """

    address: str | None = None
    workers: int | None = None
    compilation_cache: Path | None = None
    xla_flags: str = ""

    def __post_init__(self):
        if self.workers is not None and self.workers < 1:
            raise ValueError(f"Cluster.workers must be >= 1, got {self.workers}")


class JaxSetup:
    """Worker plugin: JAX's persistent compilation cache in `folder` (process-wide JAX settings, so
    set in each worker, before its first compilation)."""

    def __init__(self, folder: str | None):
        self.folder = folder

    def setup(self, worker=None):
        if self.folder is None:
            return
        import jax

        jax.config.update("jax_compilation_cache_dir", self.folder)
        jax.config.update("jax_compilation_cache_max_size", CACHE_MAX_BYTES)

    def teardown(self, worker=None):
        return None


def _plugin(folder: str | None):
    from distributed.diagnostics.plugin import WorkerPlugin

    return type("VdsbiJaxSetup", (JaxSetup, WorkerPlugin), {})(folder)


def _cores() -> int:
    try:
        return len(os.sched_getaffinity(0))
    except AttributeError:  # not Linux
        return os.cpu_count() or 1


@contextlib.contextmanager
def open_client(cluster: Cluster) -> Iterator:
    """A `distributed.Client` on `cluster`, its workers set up (`JaxSetup`); closed on exit."""
    import dask
    from distributed import Client, LocalCluster

    folder = None if cluster.compilation_cache is None else str(cluster.compilation_cache)
    with dask.config.set(DASK_CONFIG):
        if cluster.address is not None:
            client = Client(cluster.address)
            local = None
        else:
            workers = cluster.workers or os.cpu_count() or 1
            env = {
                "XLA_FLAGS": " ".join([cluster.xla_flags, SINGLE_THREAD_FLAGS]).strip(),
                "OMP_NUM_THREADS": "1",
                "OPENBLAS_NUM_THREADS": "1",
                "MKL_NUM_THREADS": "1",
                # The cores shared out: a worker splits its batches of draws over its share only.
                ENV_CPU_DEVICES: os.environ.get(ENV_CPU_DEVICES) or str(max(1, _cores() // workers)),
            }
            local = LocalCluster(
                n_workers=workers,
                threads_per_worker=1,
                processes=True,
                dashboard_address=None,
                silence_logs=logging.ERROR,
                env=env,
            )
            client = Client(local)
        try:
            client.register_plugin(_plugin(folder), name="vdsbi-jax")
            yield client
        finally:
            client.close()
            if local is not None:
                local.close()
