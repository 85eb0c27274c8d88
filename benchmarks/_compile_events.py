"""A pytest plugin for `suite_profile.py`: per test, the seconds JAX spent compiling.

Loaded with ``-p _compile_events`` (``benchmarks/`` on ``PYTHONPATH``). It listens to JAX's
monitoring events (tracing, lowering to MLIR, XLA's backend compile, persistent-cache savings)
and writes, at the end of the session, one JSON per process (each xdist worker its own) into
``$VDSBI_COMPILE_EVENTS_DIR``: ``{test id: {event: seconds, "n_compiles": n, "wall": s}}``, and
the failed tests, one per line with the last line of their error, beside it (``<worker>.failed``).
"""

from __future__ import annotations

import collections
import json
import os
import time
from pathlib import Path

import jax
import pytest

#: The events kept (the last component of JAX's event name).
EVENTS = (
    "jaxpr_trace_duration",
    "jaxpr_to_mlir_module_duration",
    "backend_compile_duration",
    "compile_time_saved_sec",
)

_current = {"test": "<collection>"}
_stats: dict[str, collections.Counter] = collections.defaultdict(collections.Counter)
_failed: list[str] = []


def _on_duration(event: str, duration: float, **_) -> None:
    name = event.rsplit("/", 1)[-1]
    if name in EVENTS:
        _stats[_current["test"]][name] += duration
        if name == "backend_compile_duration":
            _stats[_current["test"]]["n_compiles"] += 1


jax.monitoring.register_event_duration_secs_listener(_on_duration)


@pytest.hookimpl(hookwrapper=True)
def pytest_runtest_makereport(item, call):
    report = (yield).get_result()
    if report.failed:
        _failed.append(f"{item.nodeid} ({report.when}): {str(report.longrepr).strip().splitlines()[-1]}")


@pytest.hookimpl(hookwrapper=True)
def pytest_runtest_protocol(item, nextitem):
    _current["test"] = item.nodeid
    start = time.perf_counter()
    yield
    _stats[item.nodeid]["wall"] += time.perf_counter() - start


def pytest_sessionfinish(session):
    folder = os.environ.get("VDSBI_COMPILE_EVENTS_DIR")
    if folder:
        worker = os.environ.get("PYTEST_XDIST_WORKER", "main")
        out = {test: dict(c) for test, c in _stats.items()}
        (Path(folder) / f"{worker}.json").write_text(json.dumps(out))
        (Path(folder) / f"{worker}.failed").write_text("\n".join(_failed))
