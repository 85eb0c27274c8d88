"""The vectorisable tan/arctan match the library functions; their derivatives are exact."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from vdsbi.simulator._fastmath import arctan, tan


def _grid():
    x = np.concatenate(
        [
            np.linspace(-60.0, 60.0, 120_001),
            np.geomspace(1e-9, 1e7, 4000),
            # the range-reduction seams: 1 and tan(π/12)
            1.0 + np.linspace(-1e-5, 1e-5, 201),
            2.0 - 3.0**0.5 + np.linspace(-1e-5, 1e-5, 201),
            [0.0],
        ]
    )
    return np.concatenate([x, -x])


def test_arctan_float32_within_float32_rounding():
    x = _grid().astype(np.float32)
    got = np.asarray(arctan(jnp.asarray(x)))
    exact = np.arctan(x.astype(np.float64))
    assert got.dtype == np.float32
    ulp = np.spacing(np.abs(exact).astype(np.float32)).astype(np.float64)
    assert np.all(np.abs(got - exact) <= 2 * np.maximum(ulp, 1e-45))
    assert np.all(np.sign(got) == np.sign(x))


def test_tan_float32_within_float32_rounding():
    x = np.linspace(-1.4, 1.4, 100_001).astype(np.float32)
    got = np.asarray(tan(jnp.asarray(x)))
    exact = np.tan(x.astype(np.float64))
    assert got.dtype == np.float32
    assert np.max(np.abs(got - exact) / np.maximum(np.abs(exact), 1e-6)) < 4e-7


def test_float64_is_the_library_function(x64):
    x = jnp.asarray(_grid())
    assert x.dtype == jnp.float64
    np.testing.assert_array_equal(np.asarray(arctan(x)), np.asarray(jnp.arctan(x)))
    y = jnp.linspace(-1.4, 1.4, 1001)
    np.testing.assert_array_equal(np.asarray(tan(y)), np.asarray(jnp.tan(y)))


@pytest.mark.parametrize("x0", [-30.0, -1.0, -0.2, 0.0, 0.27, 0.9, 1.0, 4.0])
def test_arctan_derivatives_exact(x0):
    x = jnp.float32(x0)
    g = jax.grad(arctan)(x)
    h = jax.grad(jax.grad(arctan))(x)
    np.testing.assert_allclose(g, 1.0 / (1.0 + x0 * x0), rtol=1e-6)
    np.testing.assert_allclose(h, -2.0 * x0 / (1.0 + x0 * x0) ** 2, rtol=1e-5, atol=1e-7)
    # batched, forward mode
    xs = jnp.linspace(-3.0, 3.0, 7, dtype=jnp.float32)
    np.testing.assert_allclose(jax.vmap(jax.jacfwd(arctan))(xs), 1.0 / (1.0 + xs**2), rtol=1e-6)
