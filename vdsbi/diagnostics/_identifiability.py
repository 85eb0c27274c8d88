"""What a drive can and cannot tell: per-parameter identifiability from the Fisher information,
and the prior box's own say (`held_by_box`).

The Fisher information of θ over a problem's fitted samples (Jacobian by forward-mode autodiff
through the simulator and the shared filter) plus the prior's own precision gives a Laplace
posterior covariance. A parameter whose posterior std so estimated is still more than
`MAX_STD_RATIO` of its prior std is *not identified* by this drive: the data cannot move it
far from the prior, so reports must not print its posterior as an estimate. A parameter the
model output does not depend on at all (C_κ without torques) has exactly zero information.

Misspecification: where the model misses the data by more than the noise (a real drive), the
information is measured against each channel's residual scale at θ (χ²/dof inflation), not the
sensor noise alone.

Correlated noise: the compared samples are low-passed, so neighbouring residuals are
correlated; the information is scaled by the effective-sample factor (1 − ρ)/(1 + ρ) of the
filtered noise's lag-1 autocorrelation ρ (computed from the filter taps), so it is not
overstated.

The box: an estimate the information calls determined is still not the drive's when its 90 %
interval spans (nearly) the whole prior box, or when it sits on a bound of the box (the bound,
not the data, holds it; e.g. an inertia standing in for a lag the model lacks).
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from ..problem import Problem, dof_factor, windowed_model
from ..simulator import PARAM_NAMES
from ..simulator.solvers import RK4, AbstractSolver
from ._fisher import fisher_from_jacobian

#: Posterior std over prior std above which a parameter is reported as not identified.
MAX_STD_RATIO = 0.5
#: A 90 % interval spanning at least this share of the prior box excludes little of it (a
#: uniform prior's own spans 0.9).
SPAN_SHARE = 0.8
#: An estimate within this share of the box's width from a bound sits on it: the logit
#: coordinates' prior pulls a bound-held MAP a few per cent inside.
BOUND_SHARE = 0.05


def held_by_box(estimate: float, q05: float, q95: float, low: float, high: float) -> list[str]:
    """Why the prior box rather than the drive holds a parameter (empty when it does not): its
    90 % interval [q05, q95] spans at least `SPAN_SHARE` of [low, high], or its estimate lies
    within `BOUND_SHARE` of the width from a bound."""
    width = high - low
    reasons = []
    if q95 - q05 >= SPAN_SHARE * width:
        reasons.append(f"its 90 % interval spans {(q95 - q05) / width:.0%} of its prior box")
    for side, bound in (("lower", low), ("upper", high)):
        if abs(estimate - bound) <= BOUND_SHARE * width:
            reasons.append(
                f"its estimate {estimate:.4g} sits on the {side} bound of its prior box "
                f"[{low:.4g}, {high:.4g}]: the bound holds it"
            )
    return reasons


def filtered_noise_rho(problem: Problem) -> float:
    """Lag-1 autocorrelation (at the compared rate) of white noise after the problem's filter."""
    if problem.decimator is None:
        return 0.0
    h = np.asarray(problem.decimator.taps)
    d = problem.decimator.factor
    return float(np.dot(h[d:], h[:-d]) / np.dot(h, h)) if d < len(h) else 0.0


@eqx.filter_jit
def _readings_and_jacobian(wm, theta, scale, effect_params):
    """Compared readings at θ and their Jacobian (W, K, C, P) in prior-width units: one compiled
    forward-mode pass (run op by op, the simulation was compiled twice per call)."""

    def compared(u):
        ys, _ = wm(theta + u * scale, effect_params)
        return ys, ys

    jac, ys = jax.jacfwd(compared, has_aux=True)(jnp.zeros_like(theta))
    return ys, jac


def identifiability(
    problem: Problem,
    theta,
    prior_box: Mapping[str, tuple[float, float]],
    *,
    effects: Sequence[str] = (),
    effect_params: tuple = (),
    solver: AbstractSolver = RK4(),
) -> dict[str, dict]:
    """Per parameter: prior std, Laplace posterior std at θ, their ratio, and a verdict.

    Args:
        problem: the drive (its training samples are used).
        theta: (6,) where to evaluate (e.g. the posterior mean or the prior centre).
        prior_box: {name: (low, high)} uniform prior.
        effects, effect_params: enabled effects at fixed values (their own parameters are
            not assessed here).

    Returns:
        {name: {"prior_std", "posterior_std", "ratio", "identified", "reason"}}.
    """
    train = problem.select("train")
    wm = windowed_model(train, effects, solver)
    effect_params = tuple(jnp.asarray(p) for p in effect_params)
    lo = np.array([prior_box[n][0] for n in PARAM_NAMES])
    hi = np.array([prior_box[n][1] for n in PARAM_NAMES])
    scale = hi - lo  # work in prior-width units so the matrix is well conditioned
    theta = np.asarray(theta, dtype=float)

    ys, jac = _readings_and_jacobian(wm, jnp.asarray(theta), jnp.asarray(scale), effect_params)
    mask = np.asarray(train.train)
    resid = (np.asarray(ys) - train.y)[mask] / train.sigma  # (N, C)
    # Quasi-likelihood: where the model misses by more than the noise at θ, the residual's
    # own scale is the noise the information is measured against.
    inflation = np.maximum(1.0, np.mean(resid**2, axis=0))
    jac = jnp.where(mask[..., None, None], jac, 0.0).reshape(-1, len(train.channels), len(PARAM_NAMES))
    std = jnp.broadcast_to(jnp.asarray(train.sigma * np.sqrt(inflation)), jac.shape[:2])
    fim = np.asarray(fisher_from_jacobian(jac, std)) * float(dof_factor(filtered_noise_rho(train)))
    prior_var = np.full(len(PARAM_NAMES), 1.0 / 12.0)  # uniform on a unit width
    cov = np.linalg.inv(fim + np.diag(1.0 / prior_var))
    post_std = np.sqrt(np.clip(np.diag(cov), 0.0, None))
    no_info = np.all(np.abs(np.asarray(jac)) == 0.0, axis=(0, 1))
    out = {}
    for i, name in enumerate(PARAM_NAMES):
        ratio = float(post_std[i] / np.sqrt(prior_var[i]))
        identified = bool(ratio <= MAX_STD_RATIO and not no_info[i])
        if no_info[i]:
            reason = "the channels do not depend on it in this mode (zero information)"
        elif not identified:
            reason = f"the drive leaves {ratio:.0%} of its prior std (Cramér–Rao, at the estimate)"
        else:
            reason = ""
        out[name] = {
            "prior_std": float(scale[i] * np.sqrt(prior_var[i])),
            "posterior_std": float(scale[i] * post_std[i]),
            "ratio": ratio,
            "identified": identified,
            "reason": reason,
        }
    return out
