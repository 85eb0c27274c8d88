import itertools
import os

# The suite is compile-bound: most of its CPU time is XLA compiling. LLVM at -O0 compiles
# faster and runs slower, a net gain here; results move only by float32 rounding (a process
# stays deterministic), which no test may rely on since another CPU rounds differently too.
# Users, benchmarks and experiments keep XLA's default level. The tests also compile as the
# `vdsbi` command does, with XLA's older loop emitters (less compile again). Subprocesses
# inherit the flags; name one in XLA_FLAGS yourself to test with another value.
from vdsbi.cli._main import CLI_XLA_FLAGS, xla_flags  # noqa: E402  (no backend started yet)

os.environ["XLA_FLAGS"] = xla_flags(os.environ, {**CLI_XLA_FLAGS, "xla_backend_optimization_level": "0"})

import jax  # noqa: E402
import jax.numpy as jnp  # noqa: E402
import numpy as np  # noqa: E402
import pytest  # noqa: E402

# `vdsbi` processes the tests start keep no compiled programs in the user's cache folder
# (test_cli_identify checks the cache with a folder of its own).
os.environ.setdefault("VDSBI_COMPILATION_CACHE", "off")


@pytest.fixture
def getkey():
    """Fresh PRNG keys from a fixed seed, so each test is reproducible."""
    counter = itertools.count()
    base = jax.random.key(0)
    return lambda: jax.random.fold_in(base, next(counter))


@pytest.fixture
def x64():
    """float64 inside the test, where precision matters."""
    with jax.enable_x64(True):
        yield


@pytest.fixture(scope="session")
def once_per_run(tmp_path_factory):
    """`once_per_run(name, make)`: the folder `make(folder)` filled, made once per test run. Under
    xdist a module fixture runs on every worker that gets one of the file's tests; with this the
    first worker makes the folder and the others wait for it and read it."""
    import fcntl
    import os

    root = tmp_path_factory.getbasetemp()
    if os.environ.get("PYTEST_XDIST_WORKER"):
        root = root.parent  # shared by the workers of this run

    def get(name: str, make):
        folder = root / name
        with open(root / f"{name}.lock", "w") as lock:
            fcntl.flock(lock, fcntl.LOCK_EX)
            if not (folder / ".done").exists():
                folder.mkdir(exist_ok=True)
                make(folder)
                (folder / ".done").touch()
        return folder

    return get


def tree_allclose(a, b, rtol=1e-5, atol=1e-8) -> bool:
    la, lb = jax.tree.leaves(a), jax.tree.leaves(b)
    return len(la) == len(lb) and all(
        np.allclose(np.asarray(x), np.asarray(y), rtol=rtol, atol=atol) for x, y in zip(la, lb)
    )


__all__ = ["tree_allclose", "jnp"]


# No persistent XLA compilation cache: a worker can segfault inside JAX's cache write
# (`executable.serialize()`), a native crash no test can catch; a clean CI checkout starts
# with an empty cache anyway, so it buys little there.


@pytest.fixture(autouse=True)
def _under_the_memory_map_limit():
    """One pytest worker compiles hundreds of programs; without this it reached Linux's
    `vm.max_map_count` after ~275 tests and died in XLA's compiler (see
    `vdsbi.runtime.release_compiled_programs`)."""
    yield
    from vdsbi.runtime import release_compiled_programs

    release_compiled_programs()
