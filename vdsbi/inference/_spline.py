"""Monotonic rational-quadratic spline (Durkan et al. 2019, "Neural Spline Flows").

Written for ONE scalar input and its unnormalised parameters; vmap outside.
Inside ``[-bound, bound]`` the map is a monotonic rational-quadratic spline with
``num_bins`` bins; outside it is the identity ("linear tails"), and the boundary
derivatives are fixed to one so the map is C¹ at the edges.
"""

import math

import jax
import jax.numpy as jnp
from jaxtyping import Array, Float

MIN_BIN_WIDTH = 1e-3
MIN_BIN_HEIGHT = 1e-3
MIN_DERIVATIVE = 1e-3
# softplus(_DERIV_SHIFT) + MIN_DERIVATIVE == 1, so zero parameters give derivative one.
_DERIV_SHIFT = math.log(math.expm1(1.0 - MIN_DERIVATIVE))


def num_spline_params(num_bins: int) -> int:
    """Number of unnormalised parameters per scalar: K widths, K heights, K-1 derivatives."""
    return 3 * num_bins - 1


def _knots(unnormalised: Float[Array, " k"], bound: float, min_size: float):
    num_bins = unnormalised.shape[-1]
    sizes = jax.nn.softmax(unnormalised)
    sizes = min_size + (1.0 - min_size * num_bins) * sizes
    sizes = 2.0 * bound * sizes
    knots = jnp.concatenate([jnp.zeros((1,), sizes.dtype), jnp.cumsum(sizes)]) - bound
    knots = knots.at[-1].set(bound)  # exact right edge despite rounding
    return knots, knots[1:] - knots[:-1]


def _spline_parts(params: Float[Array, " p"], bound: float):
    num_bins = (params.shape[-1] + 1) // 3
    xk, widths = _knots(params[:num_bins], bound, MIN_BIN_WIDTH)
    yk, heights = _knots(params[num_bins : 2 * num_bins], bound, MIN_BIN_HEIGHT)
    inner = MIN_DERIVATIVE + jax.nn.softplus(params[2 * num_bins :] + _DERIV_SHIFT)
    one = jnp.ones((1,), inner.dtype)
    derivs = jnp.concatenate([one, inner, one])
    return xk, widths, yk, heights, derivs


def rq_spline_forward(
    x: Float[Array, ""], params: Float[Array, " p"], bound: float
) -> tuple[Float[Array, ""], Float[Array, ""]]:
    """Forward map of one scalar.

    Args:
        x: scalar input.
        params: ``3 * num_bins - 1`` unnormalised parameters.
        bound: the spline acts on ``[-bound, bound]``; identity outside.

    Returns:
        ``(y, log|dy/dx|)``.
    """
    xk, widths, yk, heights, derivs = _spline_parts(params, bound)
    inside = (x >= -bound) & (x <= bound)
    xs = jnp.where(inside, x, 0.0)  # double-where: no NaN gradients from the unused branch
    k = jnp.sum(xs >= xk[1:-1])
    w, h, d0, d1 = widths[k], heights[k], derivs[k], derivs[k + 1]
    s = h / w
    xi = (xs - xk[k]) / w
    om = xi * (1.0 - xi)
    den = s + (d1 + d0 - 2.0 * s) * om
    y = yk[k] + h * (s * xi**2 + d0 * om) / den
    dydx = s**2 * (d1 * xi**2 + 2.0 * s * om + d0 * (1.0 - xi) ** 2) / den**2
    return jnp.where(inside, y, x), jnp.where(inside, jnp.log(dydx), 0.0)


def rq_spline_inverse(
    y: Float[Array, ""], params: Float[Array, " p"], bound: float
) -> tuple[Float[Array, ""], Float[Array, ""]]:
    """Inverse map of one scalar; returns ``(x, log|dx/dy|)``."""
    xk, widths, yk, heights, derivs = _spline_parts(params, bound)
    inside = (y >= -bound) & (y <= bound)
    ys = jnp.where(inside, y, 0.0)
    k = jnp.sum(ys >= yk[1:-1])
    w, h, d0, d1 = widths[k], heights[k], derivs[k], derivs[k + 1]
    s = h / w
    dy = ys - yk[k]
    c2 = d1 + d0 - 2.0 * s
    a = h * (s - d0) + dy * c2
    b = h * d0 - dy * c2
    c = -s * dy
    disc = jnp.maximum(b**2 - 4.0 * a * c, 0.0)
    xi = (2.0 * c) / (-b - jnp.sqrt(disc))
    x = xk[k] + xi * w
    om = xi * (1.0 - xi)
    den = s + c2 * om
    dydx = s**2 * (d1 * xi**2 + 2.0 * s * om + d0 * (1.0 - xi) ** 2) / den**2
    return jnp.where(inside, x, y), jnp.where(inside, -jnp.log(dydx), 0.0)
