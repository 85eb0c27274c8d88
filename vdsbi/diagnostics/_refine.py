"""A point estimate refined by least squares on the whole drive, channels weighted by their misfit.

The APT posterior says how uncertain θ is; its mean is a poor point estimate when the posterior
is wide (a real drive, few simulations). Starting there, Levenberg–Marquardt fits the free
parameters to the training samples of every window through the simulator and the shared filter.

Weights: on a real drive the model misses by far more than the sensor noise (a gyro's 10⁻³
rad/s against a model error of 10⁻² rad/s), so weighting by the noise would let one channel
decide everything. Each channel's scale is instead profiled: the Gaussian likelihood with an
unknown variance per channel, maximised over the variances, is Σ_c N_c/2·log RSS_c, minimised
here by iterated reweighting (scale_c = RMS residual of channel c at the last fit, starting
from the measurement's std). Coordinates are the logits of the prior box, so the estimate
stays inside it; a weak Gaussian prior there (std `PRIOR_STD` logits about the box centre)
keeps a flat direction from running to a bound.
"""

from __future__ import annotations

from collections.abc import Sequence

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from ..problem import Problem, parameter_names, simulate_draws, split_parameters, windowed_model
from ..simulator import Solver
from ._least_squares import levenberg_marquardt, logit

#: Std of the weak prior on each free logit coordinate.
PRIOR_STD = 3.0


class Refinement(eqx.Module):
    """A refined point estimate.

    Attributes:
        names: parameter names (θ, then each effect's).
        theta: (6 + P,) the estimate; fixed parameters keep their start values.
        free: names of the parameters fitted.
        scale: {channel: RMS residual on the training samples at the estimate}.
        converged: the last fit stopped by its tolerance, not its iteration cap.
        steps: iterations of each reweighted fit.
    """

    names: tuple[str, ...]
    theta: np.ndarray
    free: tuple[str, ...]
    scale: dict
    converged: bool
    steps: tuple[int, ...]


def refine(
    problem: Problem,
    start,
    prior_box,
    *,
    effects: Sequence[str] = (),
    free: Sequence[str] | None = None,
    reweights: int = 2,
    max_steps: int = 40,
    solver: Solver = Solver(),
) -> Refinement:
    """Least-squares refinement of `start` on `problem`'s training samples.

    Args:
        problem: the drive.
        start: (6 + P,) values in `parameter_names(effects)` order (e.g. the posterior mean),
            or (M, 6 + P) candidates (e.g. the mean and posterior draws): the fit starts from
            the one that fits the training samples best (a wide posterior has poor corners).
        prior_box: {name: (low, high)}; the estimate stays inside.
        effects: enabled effects (their parameters follow θ in `start`).
        free: names fitted (default all); the others stay at `start` (not identified).
        reweights: profiling passes after the first fit.
        max_steps: Levenberg–Marquardt iterations per pass.
    """
    # float64 throughout: in float32 the Jacobian of a long drive is too coarse and a step
    # into a spinning window goes unnoticed (measured on vw_gti_high_speed_2).
    with jax.enable_x64(True):
        return _refine(problem, start, prior_box, effects, free, reweights, max_steps, solver)


def _refine(problem, start, prior_box, effects, free, reweights, max_steps, solver) -> Refinement:
    names = parameter_names(effects)
    free = tuple(names if free is None else [n for n in names if n in free])
    train = problem.select("train")
    lo = np.array([prior_box[n][0] for n in names])
    hi = np.array([prior_box[n][1] for n in names])
    mask = np.asarray(train.train)
    scale = np.array([np.std(train.y[..., c][mask]) for c in range(len(train.channels))])
    wm = windowed_model(train, effects, solver)
    start = _best_start(wm, train, np.atleast_2d(np.asarray(start, float)), effects, scale)
    z0 = jnp.asarray(logit((start - lo) / (hi - lo), eps=1e-4))
    idx = jnp.asarray([names.index(n) for n in free], dtype=int)
    fit = _fitter(wm, train, effects, lo, hi, z0, idx, max_steps)
    z, steps, converged = z0[idx], [], False
    for _ in range(reweights + 1):
        res = fit(z, jnp.asarray(scale))
        z, converged = res.z, bool(res.converged)
        steps.append(int(res.num_steps))
        r = np.asarray(res.residual).reshape(*mask.shape, len(scale))[mask] * scale
        scale = np.sqrt(np.mean(r**2, axis=0))
    theta = np.asarray(_to_theta(z0.at[idx].set(z), lo, hi))
    return Refinement(
        names=names,
        theta=theta,
        free=free,
        scale={c: float(s) for c, s in zip(train.channels, scale)},
        converged=converged,
        steps=tuple(steps),
    )


def _best_start(wm, train: Problem, starts: np.ndarray, effects, scale: np.ndarray) -> np.ndarray:
    """The candidate with the least scaled squared misfit on the training samples (a failed
    simulation counts as infinitely bad)."""
    if len(starts) == 1:
        return starts[0]
    theta, effect_params = split_parameters(jnp.asarray(starts), effects)
    pred, ok = simulate_draws(None, wm, theta, effect_params=effect_params)
    err = np.where(np.asarray(train.train)[..., None], (np.asarray(pred) - train.y) / scale, 0.0)
    cost = np.where(np.asarray(ok), np.sum(err**2, axis=(1, 2, 3)), np.inf)
    return starts[int(np.argmin(np.nan_to_num(cost, nan=np.inf)))]


def _to_theta(z, lo, hi):
    return lo + (hi - lo) * jax.nn.sigmoid(z)


def _fitter(wm, train: Problem, effects, lo, hi, z0, idx, max_steps):
    """The jitted fit of the free coordinates for given channel scales (compiled once)."""
    y, mask = jnp.asarray(train.y), jnp.asarray(train.train)
    prec = jnp.full(idx.shape, 1.0 / PRIOR_STD**2)

    def residual(z_free, scale):
        theta, effect_params = split_parameters(_to_theta(z0.at[idx].set(z_free), lo, hi), effects)
        pred, _ = wm(theta, effect_params)
        return jnp.where(mask[..., None], (pred - y) / scale, 0.0).ravel()

    @jax.jit
    def fit(z_free, scale):
        return levenberg_marquardt(
            lambda z: residual(z, scale), z_free, prior_precision=prec, max_steps=max_steps
        )

    return fit
