"""Dugoff tire model (seed eq. 8–10), per axle."""

from __future__ import annotations

import jax.numpy as jnp
from jaxtyping import Array, Float

from ._fastmath import tan

Scalar = Float[Array, ""]


def dugoff_demand(c_kappa: Scalar, c_alpha: Scalar, kappa: Scalar, alpha: Scalar) -> tuple:
    """The load-independent part of Dugoff: linear forces and the friction demand.

    Split out because the load-transfer loop only needs to re-evaluate λ.
    """
    # 1 + κ > 0 always holds for eq. 3's slip (κ ≥ −1); the floor only keeps
    # pathological draws finite so that they can be masked instead of NaN-ing.
    one_k = jnp.maximum(1.0 + kappa, 0.05)
    tan_a = tan(alpha)
    demand2 = (c_kappa * kappa) ** 2 + (c_alpha * tan_a) ** 2
    # Double-where: f = 1 when both slips are zero (seed convention, λ → ∞), and a
    # NaN-free gradient of sqrt at 0.
    positive = demand2 > 1e-12
    demand = jnp.sqrt(jnp.where(positive, demand2, 1.0))
    inv_demand = jnp.where(positive, one_k / (2.0 * demand), 1e6)
    return c_kappa * kappa / one_k, c_alpha * tan_a / one_k, inv_demand


def dugoff_with_load(demand: tuple, fz: Scalar, mu: Scalar) -> tuple[Scalar, Scalar]:
    fx_lin, fy_lin, inv_demand = demand
    lam = mu * jnp.maximum(fz, 0.0) * inv_demand
    f = jnp.where(lam < 1.0, (2.0 - lam) * lam, 1.0)
    return fx_lin * f, fy_lin * f
