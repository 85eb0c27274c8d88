"""tan and arctan that XLA vectorises on a CPU.

XLA:CPU lowers `tan` and `atan` to per-element library calls, and in the batched vector field
they cost more than the rest of it together. `sin`/`cos` and polynomials vectorise. In
float64 (the discovery's least squares, the precision tests) the library functions are kept.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np

_TAN_PI_12 = 2.0 - 3.0**0.5  # Python floats stay weakly typed: float32 stays float32
_SQRT3 = 3.0**0.5


def _single_precision(x) -> bool:
    return jnp.finfo(jnp.result_type(x)).bits <= 32


def tan(x):
    """tan(x) as sin(x)/cos(x) (within 2 ulp of `jnp.tan`)."""
    if not _single_precision(x):
        return jnp.tan(x)
    return jnp.sin(x) / jnp.cos(x)


def _atan_series(v):
    # Taylor series to v¹¹ on |v| ≤ tan(π/12) = 0.268: the first omitted term is < 4e-9.
    w = v * v
    p = 1.0 / 11.0
    for c in (1.0 / 9.0, 1.0 / 7.0, 1.0 / 5.0, 1.0 / 3.0):
        p = c - w * p
    return v * (1.0 - w * p)


@jax.custom_jvp
def arctan(x):
    """arctan(x) by range reduction to |v| ≤ tan(π/12) and a series (float32: within 1.6e-7
    absolute of the exact value, as `jnp.arctan`); the derivative is the exact 1/(1 + x²)."""
    if not _single_precision(x):
        return jnp.arctan(x)
    t = jnp.abs(x)
    big = t > 1.0
    u = jnp.where(big, 1.0 / jnp.where(big, t, 1.0), t)  # arctan t = π/2 − arctan(1/t)
    mid = u > _TAN_PI_12  # arctan u = π/6 + arctan((√3·u − 1)/(u + √3))
    v = jnp.where(mid, (_SQRT3 * u - 1.0) / (u + _SQRT3), u)
    a = _atan_series(v) + jnp.where(mid, np.pi / 6, 0.0)
    a = jnp.where(big, np.pi / 2 - a, a)
    return jnp.sign(x) * a


@arctan.defjvp
def _arctan_jvp(primals, tangents):
    (x,), (dx,) = primals, tangents
    return arctan(x), dx / (1.0 + x * x)
