import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import pytest

from vdsbi.inference import BoxPrior, IdentityEmbedding, SplineFlowSettings
from vdsbi.inference._flow import ConditionalFlow
from vdsbi.inference._spline import num_spline_params, rq_spline_forward, rq_spline_inverse

BOUND = 3.0


def _params(key, num_bins=8, scale=2.0):
    return scale * jax.random.normal(key, (num_spline_params(num_bins),), jnp.float64)


def _points(params):
    from vdsbi.inference._spline import _spline_parts

    xk = np.asarray(_spline_parts(params, BOUND)[0])
    interior = np.linspace(-BOUND + 1e-3, BOUND - 1e-3, 41)
    return jnp.asarray(np.concatenate([[-BOUND, BOUND, -BOUND - 1.5, BOUND + 2.0], xk[1:-1], interior]))


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_spline_inverse_and_logdet(x64, seed):
    params = _params(jax.random.key(seed))
    xs = _points(params)
    fwd = jax.vmap(rq_spline_forward, in_axes=(0, None, None))
    inv = jax.vmap(rq_spline_inverse, in_axes=(0, None, None))
    y, ld = fwd(xs, params, BOUND)
    x_back, ld_inv = inv(y, params, BOUND)
    np.testing.assert_allclose(x_back, xs, atol=1e-9, rtol=0)
    np.testing.assert_allclose(ld_inv, -ld, atol=1e-9)
    # log-det against autodiff of the forward map, at edges, knots, interior and in the tails.
    dydx = jax.vmap(jax.grad(lambda x: rq_spline_forward(x, params, BOUND)[0]))(xs)
    np.testing.assert_allclose(ld, np.log(np.abs(dydx)), atol=1e-5, rtol=0)
    dxdy = jax.vmap(jax.grad(lambda v: rq_spline_inverse(v, params, BOUND)[0]))(y)
    np.testing.assert_allclose(ld_inv, np.log(np.abs(dxdy)), atol=1e-5, rtol=0)
    # identity tails and monotonicity
    assert float(y[2]) == float(xs[2]) and float(y[3]) == float(xs[3]) and float(ld[2]) == 0.0
    order = np.argsort(np.asarray(xs))
    assert np.all(np.diff(np.asarray(y)[order]) > 0)
    # edges map to edges
    np.testing.assert_allclose(y[:2], [-BOUND, BOUND], atol=1e-12)


def test_spline_vector_jacobian(x64):
    key = jax.random.key(3)
    params = jax.random.normal(key, (4, num_spline_params(6)), jnp.float64)
    x = jnp.asarray([-BOUND, -0.3, 1.7, BOUND], jnp.float64)
    f = lambda v: jax.vmap(rq_spline_forward, in_axes=(0, 0, None))(v, params, BOUND)[0]
    _, ld = jax.vmap(rq_spline_forward, in_axes=(0, 0, None))(x, params, BOUND)
    sign, logdet = jnp.linalg.slogdet(jax.jacobian(f)(x))
    assert sign > 0
    np.testing.assert_allclose(jnp.sum(ld), logdet, atol=1e-5)


def _random_flow(key, dim=3, context=2):
    prior = BoxPrior(-2.0 * jnp.ones(dim), 3.0 * jnp.ones(dim))
    flow = ConditionalFlow(
        key,
        prior,
        IdentityEmbedding(context),
        (context,),
        SplineFlowSettings(num_layers=3, num_bins=5, hidden=16),
    )
    # Perturb every float leaf so the flow is far from the identity.
    leaves, tree = jax.tree.flatten(flow)
    keys = jax.random.split(jax.random.fold_in(key, 1), len(leaves))
    leaves = [
        leaf + 0.1 * jax.random.normal(k, leaf.shape, leaf.dtype)
        if (hasattr(leaf, "dtype") and jnp.issubdtype(leaf.dtype, jnp.floating) and i > 0)
        else leaf
        for i, (leaf, k) in enumerate(zip(leaves, keys))
    ]
    return jax.tree.unflatten(tree, leaves)


def test_flow_logdet_matches_jacobian_and_inverts(x64, getkey):
    flow = _random_flow(getkey())
    ctx = jnp.asarray([0.4, -1.1])
    z = jnp.asarray([0.3, -2.5, 3.5])  # includes a coordinate in the tails

    @eqx.filter_jit
    def run(flow, z, ctx):
        eps, logdet = flow._to_noise(z, ctx)
        jac = jax.jacobian(lambda v: flow._to_noise(v, ctx)[0])(z)
        return eps, logdet, jac, flow._from_noise(eps, ctx)

    eps, logdet, jac, (z_back, logdet_inv) = run(flow, z, ctx)
    sign, ref = jnp.linalg.slogdet(jac)
    assert sign != 0 and abs(float(ref)) > 0.01  # a genuinely non-trivial map
    np.testing.assert_allclose(logdet, ref, atol=1e-5)
    np.testing.assert_allclose(z_back, z, atol=1e-8)
    np.testing.assert_allclose(logdet_inv, -logdet, atol=1e-8)


@pytest.mark.parametrize("dim", [1, 2, 3, 4])
def test_coupling_splines_exactly_the_transformed_coordinates(x64, getkey, dim):
    """Each layer equals the textbook coupling (a spline on EVERY coordinate from the full
    conditioner output, the conditioning ones then put back), though it only evaluates the
    transformed coordinates' share."""
    flow = _random_flow(getkey(), dim=dim)
    ctx = jnp.asarray([0.4, -1.1])
    z = jnp.asarray([0.3, -2.5, 3.5, 1.2])[:dim]  # includes a coordinate in the tails
    for i in range(flow.num_layers):
        layer = jax.tree.map(lambda a, i=i: a[i] if eqx.is_array(a) else a, flow.layers)
        h = jnp.concatenate([jnp.where(layer.mask, z, 0.0), ctx])
        params = layer.conditioner(h).reshape(dim, num_spline_params(flow.num_bins))
        y, ld = jax.vmap(rq_spline_forward, in_axes=(0, 0, None))(z, params, flow.tail_bound)
        ref_y, ref_ld = jnp.where(layer.mask, z, y), jnp.sum(jnp.where(layer.mask, 0.0, ld))
        out, out_ld = layer._couple(rq_spline_forward, z, ctx)
        assert not np.allclose(out, z)  # the layer does transform something
        np.testing.assert_allclose(out, ref_y, atol=1e-12)
        np.testing.assert_allclose(out_ld, ref_ld, atol=1e-12)
