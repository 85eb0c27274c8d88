"""The box bijection: invertible, inside the box, log-det against autodiff."""

import jax
import jax.numpy as jnp
import numpy as np

from vdsbi.problem import Box


def test_round_trip_and_log_det_match_autodiff():
    box = Box(jnp.array([0.5, -2.0, 1e4]), jnp.array([2.0, 3.0, 3e5]), ("a", "b", "c"))
    z = jnp.array([0.3, -1.7, 2.2])
    theta = box.from_unbounded(z)
    assert bool(box.contains(theta))
    np.testing.assert_allclose(box.to_unbounded(theta), z, rtol=1e-4, atol=1e-4)
    jac = jax.jacobian(box.from_unbounded)(z)
    np.testing.assert_allclose(np.diag(jac), box.dtheta_dz(z), rtol=1e-5)
    np.testing.assert_allclose(np.log(np.abs(np.linalg.det(jac))), box.log_det_from_unbounded(z), rtol=1e-5)


def test_from_dict_orders_by_names_and_rejects_an_empty_side():
    box = Box.from_dict({"x": (0.0, 1.0), "y": (2.0, 4.0)}, ["y", "x"])
    assert box.names == ("y", "x")
    np.testing.assert_allclose(box.low, [2.0, 0.0])
    try:
        Box.from_dict({"x": (1.0, 1.0)})
    except ValueError as err:
        assert "high > low" in str(err)
    else:
        raise AssertionError("a zero-width box was accepted")
