"""`in_background` and `thread_map`: work on other threads under the caller's float64 setting."""

import jax
import jax.numpy as jnp
import numpy as np

from vdsbi.runtime import in_background, thread_map


def test_thread_map_is_the_loop_in_its_order_with_the_callers_float64():
    fn = lambda x: (x, jnp.asarray(float(x)).dtype)
    with jax.enable_x64(True):
        out = thread_map(fn, range(7), workers=3)
    assert [x for x, _ in out] == list(range(7))
    assert {d for _, d in out} == {jnp.dtype("float64")}
    assert {d for _, d in thread_map(fn, range(3), workers=2)} == {jnp.dtype("float32")}
    assert thread_map(fn, [], workers=2) == []


def test_thread_map_raises_what_a_call_raises():
    def fn(x):
        if x == 2:
            raise ValueError("two")
        return x

    try:
        thread_map(fn, range(4), workers=2)
    except ValueError as err:
        assert str(err) == "two"
    else:
        raise AssertionError("thread_map swallowed the error")


def test_a_program_compiled_in_the_background_is_not_traced_again():
    traces = []

    @jax.jit
    def f(x):
        traces.append(x.dtype)
        return jnp.sin(x).sum()

    with jax.enable_x64(True):
        x = jnp.ones(5)
        in_background(f, x).result()
        assert traces == [jnp.dtype("float64")]  # compiled in float64, as its caller runs
        assert np.isclose(float(f(x)), 5 * np.sin(1.0))
    assert len(traces) == 1


def test_a_failing_call_in_the_background_keeps_its_error_for_who_asks():
    def fails():
        raise RuntimeError("the stage's own call will raise this")

    future = in_background(fails)  # raises nothing here
    assert isinstance(future.exception(timeout=30), RuntimeError)
