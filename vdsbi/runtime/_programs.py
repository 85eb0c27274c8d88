"""Compiled programs: keep a long-lived process under the kernel's limit on memory mappings, and
compile a later stage's programs while this one runs.

XLA:CPU maps each compiled program's code into memory in several pieces, and JAX keeps every
program it compiled for as long as the function it was compiled for lives (module-level jitted
functions: for the life of the process). A process that compiles many programs — the test
suite in one pytest worker, a benchmark grid, a diagnosis that identifies one candidate model
after another — runs into Linux's ``vm.max_map_count`` (65 530 by default), and the next
compilation dies with a segmentation fault or an abort, which nothing in Python can catch.
`release_compiled_programs` drops JAX's compiled programs when the process has used more than
a fraction of the limit; they are recompiled when next needed.

XLA compiles one program on one core, and a stage that simulates one trajectory at a time keeps
about one core busy: `in_background` runs a small call of a later stage in a second thread, so
the programs that stage needs are compiled (and cached by their functions) by the time it runs,
and `thread_map` runs independent calls of such a stage side by side.
"""

from __future__ import annotations

import gc
from collections.abc import Callable, Iterable
from concurrent.futures import Future, ThreadPoolExecutor
from pathlib import Path

import jax

_MAPS = Path("/proc/self/maps")
_LIMIT = Path("/proc/sys/vm/max_map_count")


def memory_map_usage() -> tuple[int, int] | None:
    """``(mappings in use, the kernel's limit)`` for this process; None where the system does not
    say (not Linux)."""
    try:
        with _MAPS.open("rb") as maps:
            used = sum(1 for _ in maps)
        return used, int(_LIMIT.read_text())
    except (OSError, ValueError):
        return None


def release_compiled_programs(fraction: float = 0.5) -> bool:
    """Clear JAX's caches of compiled programs if this process uses more than ``fraction`` of its
    memory mappings; True if it did. Call it between stages of long work, never inside a loop
    whose programs are about to be reused: everything is recompiled on its next call."""
    usage = memory_map_usage()
    if usage is None or usage[0] <= fraction * usage[1]:
        return False
    jax.clear_caches()
    gc.collect()  # the executables' mappings go when their last Python reference does
    return True


def _under_callers_x64(fn: Callable) -> Callable:
    """`fn` to be called on another thread under this thread's float64 setting (it is per thread)."""
    x64 = bool(jax.config.jax_enable_x64)

    def run(*args, **kwargs):
        with jax.enable_x64(x64):
            return fn(*args, **kwargs)

    return run


def in_background(fn: Callable, /, *args, **kwargs) -> Future:
    """``fn(*args, **kwargs)`` on a short-lived worker thread under the caller's float64 setting.

    Run for its compilations, it makes the jitted functions it calls compile their programs for
    these shapes, which a later call of the same shapes in any thread then finds; make such a
    call cheap (one iteration, one draw). Or run a whole stage that does not need this thread's
    result: while one thread compiles on one core, the other's work takes the other.
    ``result()`` waits for it (and raises what it raised); a future nobody asks keeps its error.
    """
    pool = ThreadPoolExecutor(1)
    future = pool.submit(_under_callers_x64(fn), *args, **kwargs)
    pool.shutdown(wait=False)
    return future


def thread_map(fn: Callable, items: Iterable, workers: int = 2) -> list:
    """``[fn(x) for x in items]``, on ``workers`` threads under the caller's float64 setting (1:
    in this thread). JAX releases the interpreter while a program runs, so fits that each keep
    one core busy run side by side; the results are those of the loop, in its order."""
    items = list(items)
    if workers <= 1 or len(items) <= 1:
        return [fn(x) for x in items]
    with ThreadPoolExecutor(min(workers, len(items))) as pool:
        return list(pool.map(_under_callers_x64(fn), items))
