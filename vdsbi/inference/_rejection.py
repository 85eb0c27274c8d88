"""Rejection into the prior box: the one way both estimators on θ (the spline flow and the
flow-matching estimator, with an `IdentityMap`) turn their draws into posterior draws."""

import warnings
from collections.abc import Callable

import jax
import jax.numpy as jnp
from jaxtyping import Array, Float, PRNGKeyArray

from ._prior import BoxPrior

_MAX_REJECTION_ROUNDS = 100


def box_rejection(draw: Callable, prior: BoxPrior, key: PRNGKeyArray, n: int) -> Float[Array, "n d"]:
    """``n`` draws of ``draw(key) -> (n, d)`` inside the box, in at most 100 rounds of ``n``.

    Slots still empty after that (under 1 % of the mass inside the box) repeat the accepted
    draws in turn: repeated draws of the right density, where clipping new ones to the box
    would pile them on its faces. Only if none was accepted are they clipped, so the result
    always lies in the box.
    """
    low, high = prior.low, prior.high

    def body(carry):
        i, count, out = carry
        cand = draw(jax.random.fold_in(key, i))
        ok = jnp.all((cand >= low) & (cand <= high), axis=1)
        pos = count + jnp.cumsum(ok) - 1
        slot = jnp.where(ok & (pos < n), pos, n)  # n: out of range, dropped
        out = out.at[slot].set(cand, mode="drop")
        return i + 1, jnp.minimum(count + jnp.sum(ok, dtype=count.dtype), n), out

    def cond(carry):
        i, count, _ = carry
        return (count < n) & (i < _MAX_REJECTION_ROUNDS)

    init = (jnp.zeros((), jnp.int32), jnp.zeros((), jnp.int32), jnp.zeros((n, prior.dim), low.dtype))
    _, count, out = jax.lax.while_loop(cond, body, init)
    jax.debug.callback(lambda c: _warn_if_short(c, n), count)
    slots = jnp.arange(n)

    def repeat():
        return out[slots % jnp.maximum(count, 1)]

    def clipped():  # a cond, so the usual case does not pay for one more draw
        return jnp.clip(draw(jax.random.fold_in(key, _MAX_REJECTION_ROUNDS)), low, high)

    fill = jax.lax.cond(count > 0, repeat, clipped)
    return jnp.where((slots < count)[:, None], out, fill)


def _warn_if_short(count, n) -> None:
    """Host side of `box_rejection`: say so when draws had to be repeated (a posterior that left
    the box goes unnoticed otherwise: its draws look like any others)."""
    short = int(count.min())  # a host array; vmapped over observations: the worst of them
    if short < n:
        warnings.warn(
            f"only {short} of {n} posterior draws fell inside the prior box in "
            f"{_MAX_REJECTION_ROUNDS} rounds of rejection (under 1 % of the flow's mass lies in "
            "the box); the rest repeat them. The estimator has leaked out of the box: consider "
            "theta_map=LogitMap() or a SequentialSettings.leak penalty.",
            RuntimeWarning,
            stacklevel=2,
        )
