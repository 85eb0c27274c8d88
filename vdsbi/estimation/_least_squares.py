"""The one least-squares fitter: Levenberg–Marquardt with a Gaussian prior, and its Laplace
covariance.

Minimises

    C(z) = ½·|r(z)|² + ½·Σ_i prec_i·(z_i − mean_i)²

for a whitened residual r (residual / noise std, so ½|r|² is the negative log-likelihood of
independent Gaussian noise up to a constant). The Jacobian is forward-mode (`jax.jacfwd`: P
tangents through one primal pass), right for our problems' few parameters (P ≲ 20) and long
residuals (N ≈ 10⁴ simulated readings). A step solves

    (H + λ·(diag H + 10⁻⁹))·δ = −g,    H = JᵀJ + diag(prec),  g = Jᵀr + prec·(z − mean),

(Marquardt's scaling of the damping: every parameter is damped in its own units), clipped to
|δ_i| ≤ `max_step`. A step is kept only if it lowers C; otherwise λ grows ×5 and the step is
retried (at most `max_tries` times, each costing one residual evaluation, no Jacobian); after
a kept step λ shrinks ×1/4. The start is the loop's first trial, so the compiled program holds
the Jacobian once: for a residual that is a simulation, compiling its Jacobian is most of a
short fit's cost. It stops when a kept step lowers C by less than `rtol` relative, when no
step is found (a minimum to within the damping), or after `max_steps` kept-or-failed
iterations. Written with `lax.while_loop`, so it runs under `jit` and `vmap` (one data set per
call; under `vmap` every data set iterates until the last one stops, harmlessly).

A loop of our own rather than `optimistix.LevenbergMarquardt`, because that damps with λ·I and
re-linearises (a new Jacobian and QR solve) at every rejected trial, where this loop retries a
rejected step for one residual evaluation and compiles once for every candidate effect.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable
from typing import NamedTuple

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, ArrayLike, Bool, Float, Int


class LeastSquaresResult(eqx.Module):
    """The fit, and the linearisation there.

    Attributes:
        z: (P,) minimiser (best point found).
        residual: (N,) whitened residual at `z`.
        jacobian: (N, P) ∂residual/∂z at `z`.
        cost: C(z) including the prior term.
        num_steps: iterations used (each one Jacobian, plus up to `max_tries` residuals).
        converged: stopped by `rtol` or for want of a better step, not by `max_steps`.
    """

    z: Float[Array, " P"]
    residual: Float[Array, " N"]
    jacobian: Float[Array, "N P"]
    cost: Float[Array, ""]
    num_steps: Int[Array, ""]
    converged: Bool[Array, ""]


class GaussianPrior(eqx.Module):
    """The Gaussian prior ½Σ precision·(z − mean)² added to the cost.

    Attributes:
        precision: (P,) prior precision per coordinate.
        mean: (P,) its mean.
    """

    precision: Float[ArrayLike, " P"]
    mean: Float[ArrayLike, " P"]


@dataclasses.dataclass(frozen=True)
class StepControl:
    """How Levenberg–Marquardt damps and bounds its steps (see the module docstring).

    Attributes:
        damping: initial λ.
        max_step: bound on each coordinate of a step.
        max_tries: damping increases tried per iteration before giving up.
    """

    damping: float = 1e-3
    max_step: float = np.inf
    max_tries: int = 8

    def __post_init__(self):
        if not self.damping > 0:
            raise ValueError(f"StepControl.damping must be > 0, got {self.damping}")
        if not self.max_step > 0:
            raise ValueError(f"StepControl.max_step must be > 0, got {self.max_step}")
        if self.max_tries < 1:
            raise ValueError(f"StepControl.max_tries must be >= 1, got {self.max_tries}")


class _State(NamedTuple):
    z: Array
    r: Array
    jac: Array
    cost: Array
    lam: Array
    steps: Array  # -1 until the start is evaluated (the loop's first trial)
    done: Array  # converged: by `rtol`, or no better step found


def _residual_and_jacobian(fn, z):
    def both(z_):
        r = fn(z_)
        return r, r

    jac, r = jax.jacfwd(both, has_aux=True)(z)
    return r, jac


def levenberg_marquardt(
    fn: Callable[[Float[Array, " P"]], Float[Array, " N"]],
    z0: Float[Array, " P"],
    *,
    prior: GaussianPrior | None = None,
    max_steps: int | Int[Array, ""] = 30,
    rtol: float | Float[Array, ""] = 1e-6,
    control: StepControl = StepControl(),
    jacobian: Callable[[Float[Array, " P"]], tuple[Float[Array, " N"], Float[Array, "N P"]]] | None = None,
) -> LeastSquaresResult:
    """Minimise ½|fn(z)|² + ½Σ precision·(z − mean)² of ``prior`` (see the module docstring).

    Args:
        fn: whitened residual of one data set, (P,) -> (N,); a non-finite entry makes a
            trial point infinitely bad.
        z0: (P,) start.
        prior: the Gaussian prior (default: none).
        max_steps: iteration cap (may be traced: one compilation serves all caps).
        rtol: stop once a kept step lowers the cost by less than this fraction (0: never).
        control: the damping and the bounds on the steps.
        jacobian: z -> (fn(z), ∂fn/∂z), for a residual whose Jacobian has a structure cheaper to
            evaluate than P forward tangents (default: `jax.jacfwd` of `fn`).
    """
    z0 = jnp.asarray(z0)
    dtype = z0.dtype
    # One jitted residual: its shape, the trials and the Jacobian then share one trace of it
    # (for a simulation, tracing is a large part of compiling the fit).
    fn = jax.jit(fn)
    prec = jnp.zeros_like(z0) if prior is None else jnp.asarray(prior.precision, dtype)
    mean = jnp.zeros_like(z0) if prior is None else jnp.asarray(prior.mean, dtype)
    both = (lambda z: _residual_and_jacobian(fn, z)) if jacobian is None else jacobian
    # The start is evaluated and linearised by the loop's own first trial (a step of zero), so
    # the compiled program holds the residual's Jacobian once.
    r_shape = jax.eval_shape(fn, z0)
    init = _State(
        z=z0,
        r=jnp.zeros(r_shape.shape, r_shape.dtype),
        jac=jnp.zeros((*r_shape.shape, *z0.shape), r_shape.dtype),
        cost=jnp.asarray(jnp.inf, dtype),
        lam=jnp.asarray(control.damping, dtype),
        steps=jnp.asarray(-1),
        done=jnp.asarray(False),
    )
    iteration = lambda s: _iteration(fn, both, s, prec, mean, rtol, control.max_step, control.max_tries)
    s = jax.lax.while_loop(lambda s: ~s.done & (s.steps < max_steps), iteration, init)
    return LeastSquaresResult(
        z=s.z, residual=s.r, jacobian=s.jac, cost=s.cost, num_steps=s.steps, converged=s.done
    )


def _cost(r, z, prec, mean):
    """C(z); a non-finite residual makes the point infinitely bad."""
    c = 0.5 * r @ r + 0.5 * jnp.sum(prec * (z - mean) ** 2)
    return jnp.where(jnp.all(jnp.isfinite(r)), c, jnp.inf)


def _iteration(fn, both, s: _State, prec, mean, rtol, max_step: float, max_tries: int) -> _State:
    """One iteration: from the linearisation at `s.z`, look for a damped step that lowers C and
    keep it (linearised there, λ shrunk), or stop. Before the start is linearised, the one trial
    is the start itself, which is not counted as an iteration."""
    started = s.steps >= 0
    g = s.jac.T @ s.r + prec * (s.z - mean)
    h = s.jac.T @ s.jac + jnp.diag(prec)
    tries = jnp.where(started, max_tries, 1)
    lam, z_new, c_new, better = _damped_step(fn, s, g, h, prec, mean, max_step, tries)
    rel = (s.cost - c_new) / jnp.maximum(s.cost, 1e-12)
    keep = better | ~started  # a start that cannot be evaluated is returned as it evaluated
    # The Jacobian is needed only where a step was kept.
    r, jac = jax.lax.cond(keep, lambda: both(z_new), lambda: (s.r, s.jac))
    return _State(
        z=jnp.where(keep, z_new, s.z),
        r=r,
        jac=jac,
        cost=jnp.where(keep, c_new, s.cost),
        lam=jnp.where(better & started, jnp.maximum(lam / 4.0, 1e-7), lam),
        steps=s.steps + 1,
        done=~better | (started & (rel < rtol)),
    )


def _damped_step(fn, s: _State, g, h, prec, mean, max_step: float, max_tries):
    """Solve ``(h + λ·damp)·δ = −g``, growing λ ×5 until the step lowers C or `max_tries`
    trials are spent (one residual each); returns ``(λ, z_new, C(z_new), lowered)``."""
    damp = jnp.diag(jnp.diag(h) + 1e-9)

    def trial(t):
        lam, tries, *_ = t
        step = jnp.clip(-jnp.linalg.solve(h + lam * damp, g), -max_step, max_step)
        z_new = s.z + jnp.where(s.steps >= 0, step, 0.0)
        c_new = _cost(fn(z_new), z_new, prec, mean)
        better = c_new < s.cost
        return jnp.where(better, lam, 5.0 * lam), tries + 1, z_new, c_new, better

    lam, _, z_new, c_new, better = jax.lax.while_loop(
        lambda t: ~t[-1] & (t[1] < max_tries),
        trial,
        (s.lam, jnp.asarray(0), s.z, s.cost, jnp.asarray(False)),
    )
    return lam, z_new, c_new, better


def laplace_covariance(
    jacobian: Float[Array, "N P"], prior_precision: Float[ArrayLike, " P"] | None = None
) -> Float[Array, "P P"]:
    """(JᵀJ + diag(prior_precision))⁺: the Laplace (Gauss–Newton) posterior covariance of a
    whitened least-squares fit; a pseudo-inverse, so unidentified directions do not blow up."""
    a = jacobian.T @ jacobian
    if prior_precision is not None:
        a = a + jnp.diag(jnp.asarray(prior_precision, a.dtype))
    return jnp.linalg.pinv(a)
