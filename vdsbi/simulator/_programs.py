"""Keep a long-lived process under the kernel's limit on memory mappings.

XLA:CPU maps each compiled program's code into memory in several pieces, and JAX keeps every
program it compiled for as long as the function it was compiled for lives (module-level jitted
functions: for the life of the process). A process that compiles many programs — the test
suite in one pytest worker, a benchmark grid, a diagnosis that identifies one candidate model
after another — runs into Linux's ``vm.max_map_count`` (65 530 by default), and the next
compilation dies with a segmentation fault or an abort, which nothing in Python can catch.
`release_compiled_programs` drops JAX's compiled programs when the process has used more than
a fraction of the limit; they are recompiled when next needed.
"""

from __future__ import annotations

import gc
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
