"""`release_compiled_programs`: a long process gives its compiled programs' memory mappings back."""

import sys

import jax
import jax.numpy as jnp
import pytest

from vdsbi.runtime import memory_map_usage, release_compiled_programs

pytestmark = pytest.mark.skipif(not sys.platform.startswith("linux"), reason="reads /proc")


def _compile_many(n: int):
    fns = [jax.jit(lambda x, i=i: jnp.sin(x) * i + jnp.cos(x @ x.T).sum()) for i in range(n)]
    for f in fns:
        f(jnp.ones((8, 8))).block_until_ready()
    return fns


def test_usage_reads_this_process_and_the_kernel_limit():
    used, limit = memory_map_usage()
    assert 0 < used < limit


def test_programs_are_released_only_past_the_fraction():
    fns = _compile_many(40)  # kept alive, as a module-level jitted function would be
    before = fns[3](jnp.ones((8, 8)))
    assert not release_compiled_programs(fraction=1.0)
    crowded, _ = memory_map_usage()
    assert release_compiled_programs(fraction=0.0)
    released, _ = memory_map_usage()
    # each compiled program holds several mappings; dropping 40 programs frees many
    assert released < crowded - 40
    # and a released function still works: it is compiled again on its next call
    assert jnp.array_equal(fns[3](jnp.ones((8, 8))), before)
