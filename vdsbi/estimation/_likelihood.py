"""The likelihood posterior of a problem: the best fit through the simulator, a noise model that
includes the model's own error, and the Laplace approximation there.

Coordinates: z = `Box.to_unbounded(θ)`, so every estimate stays inside the prior box. The
uniform prior on θ is logistic in z; it is approximated by N(0, π²/3) per coordinate (the
logistic's variance), which keeps a direction the drive does not inform at the prior.

Noise model (`vdsbi.estimation._noise`): with `ModelError` (the default) each channel c gets a
scale s_c and an autocorrelation time τ_c of its residual, so its N_c samples count as N_c/τ_c
independent ones; with `SensorNoise`, the sensor's σ_c, white. The fit minimises
Σ_c Σ_k r_ck²/(s_c²·τ_c) + the prior term, by iterated reweighting (fit, re-estimate s and τ,
refit), with `levenberg_marquardt`; the Laplace covariance (JᵀJ + prior precision)⁻¹ is
taken with the final weights. On a simulated drive with the right model s_c → σ_c and τ_c → the
filter's own correlation; on a real one the intervals widen by the model error, which is what
makes them hold. This is a quasi-likelihood (Heagerty & Lumley 2000 for the block view of
dependent residuals; Ribatet et al. 2012 for curvature-adjusted composite likelihoods).

Start speeds: each torque-driven window's start speed is corrected with θ and marginalised
(`vdsbi.estimation._start_speed`).
"""

from __future__ import annotations

import dataclasses
from collections.abc import Sequence
from typing import Any, NamedTuple

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array

from ..problem import Box, Part, Problem, parameter_names, windowed_model
from ..problem.points import Point, Space, mask_of, padded, positions, scatter
from ..simulator import PARAM_NAMES
from ..simulator.models import AbstractVehicleModel
from ..simulator.solvers import Solver
from ._laplace_posterior import LikelihoodPosterior
from ._least_squares import GaussianPrior, StepControl, laplace_covariance, levenberg_marquardt
from ._noise import ModelError, NoiseModel, SensorNoise, measure_noise
from ._start import best_start, informed_parameters, prior_mean
from ._start_speed import V0_STD, corrected_windows, own_columns, profiled, residual_and_jacobian
from ._widening import BLOCK_TAUS, consistent_covariance, data_splits, robust_covariance

#: Std of the Gaussian standing in for the uniform prior in each logit coordinate (the logistic
#: distribution's: a uniform θ is logistic in z).
PRIOR_Z_STD = float(np.pi / np.sqrt(3.0))
#: Largest step of one logit coordinate per iteration (a sigmoid saturates past |z| ≈ 5).
MAX_Z_STEP = 2.0


@dataclasses.dataclass(frozen=True, kw_only=True)
class FitRequest:
    """What a likelihood fit fits, on which samples, and how hard it tries (`fit_likelihood`).

    Attributes:
        free: names fitted (default: every parameter the channels depend on); the others stay
            at their start and keep their prior variance.
        part: "train" (the fit that is validated on the held-out part) or "valid" (everything).
        noise: `ModelError` (default; re-measured after each pass) or `SensorNoise`.
        max_steps: Levenberg–Marquardt iterations per pass.
        width: coordinates fitted, the free ones padded to it (default: as many as are free):
            fits with fewer free parameters then share one compilation.
    """

    free: Sequence[str] | None = None
    part: Part = "train"
    noise: SensorNoise | ModelError = ModelError()
    max_steps: int = 40
    width: int | None = None


def fit_likelihood(
    problem: Problem,
    start,
    box: Box,
    request: FitRequest = FitRequest(),
    *,
    effects: Sequence[str] = (),
    model: AbstractVehicleModel | None = None,
    solver: Solver = Solver(),
) -> LikelihoodPosterior:
    """The likelihood posterior of `problem`'s `request.part` samples.

    Args:
        problem: the drive.
        start: (P,) values in the box's order, or (M, P) candidates (the mean and draws of a
            neural posterior, the prior centre, a previous fit): the fit starts from the one that
            fits best.
        box: the prior box over `parameter_names(effects)` (with `model`: over θ and its effects'
            parameters, in its effects' order).
        request: the parameters fitted, the samples, the noise model and the iterations
            (`FitRequest`).
        effects: enabled effects (their parameters follow θ).
        model: the model to fit (default: the one with `effects`): e.g. one holding every
            candidate effect, so that one compiled fit serves every candidate; its parameters
            not `request.free` stay exactly at `start` (an effect's null values: it vanishes).
        solver: the simulator's solver.
    """
    if model is None and tuple(box.names) != parameter_names(effects):
        raise ValueError(f"box over {box.names}, parameters {parameter_names(effects)}")
    # float64: in float32 the Jacobian of a long drive is too coarse and a step into a spinning
    # window goes unnoticed.
    with jax.enable_x64(True):
        wm = windowed_model(problem, effects, solver, model=model)
        effects = tuple(type(e) for e in wm.model.effects)
        size = sum(len(e.param_names) for e in effects)
        if len(box.names) != len(PARAM_NAMES) + size:
            raise ValueError(f"box over {len(box.names)} parameters, the model has {size} beside θ")
        return _fit(problem, wm, effects, start, box, request)


def _first_noise(data: Problem, mask, noise: SensorNoise | ModelError) -> tuple[np.ndarray, np.ndarray, int]:
    """(scale, τ, re-measurements) of the first pass."""
    sensor = np.asarray(data.sigma, float)
    if isinstance(noise, SensorNoise):
        return sensor, np.ones_like(sensor), 0
    first = noise.start
    if first is None:
        return np.maximum(np.std(data.y[mask], axis=0), sensor), np.ones_like(sensor), noise.passes
    if tuple(first.channels) != tuple(data.channels):
        raise ValueError(f"noise model of {first.channels}, problem channels {data.channels}")
    return np.asarray(first.scale, float), np.asarray(first.tau, float), noise.passes


def _fit(data: Problem, wm, effects, start, box: Box, request: FitRequest) -> LikelihoodPosterior:
    """The fit's stages: the best start, the coordinates it moves, the reweighted fit, and the
    posterior at its end."""
    # Every window, the others masked: the validation fit and the refit on all the driving then
    # share one problem shape, and so one compilation.
    mask = np.asarray(data.part(request.part))
    box64 = Box(jnp.asarray(box.low, jnp.float64), jnp.asarray(box.high, jnp.float64), box.names)
    scale, tau, passes = _first_noise(data, mask, request.noise)
    starts = np.atleast_2d(np.asarray(start, float))
    start = best_start(wm, data, mask, starts, effects, scale)
    z0 = np.asarray(box64.to_unbounded(start, edge=1e-4))
    layout = _layout(wm, data, box64, z0, effects, request, batch=len(starts))
    mean = prior_mean(box, wm.model.effects)
    coords = _coordinates(box64, effects, z0, start, layout)
    fit = _fitter(wm, data, mask, coords, layout.extended(mean[layout.idx]), request.max_steps)
    first = _Noise(scale, tau, steps=())
    sensor_only = isinstance(request.noise, SensorNoise)
    res, noise = _reweighted(fit, layout.extended(z0[layout.idx]), data, mask, first, passes, sensor_only)
    if res is None:
        # The start itself does not simulate: an infinitely bad fit, said as such.
        return _failed(data, box, z0, layout.free, request.part, noise.model(data, mask), mean, noise.steps)
    return _posterior(data, box, z0, layout, res, noise, mean, request.part)


class _Layout(NamedTuple):
    """The fitted coordinates: the `free` names at box indices `idx`, padded to `width`, then one
    start-speed correction per corrected window (`windows`)."""

    free: tuple[str, ...]
    idx: np.ndarray
    width: int
    windows: int

    def extended(self, values: np.ndarray) -> np.ndarray:
        """`values` of the free coordinates, zeros in the padding and the start speeds."""
        return np.concatenate([values, np.zeros(self.width - len(self.idx) + self.windows)])


def _layout(wm, data: Problem, box: Box, z0: np.ndarray, effects, request: FitRequest, batch: int) -> _Layout:
    """The coordinates the fit moves: `request.free` (default: those the channels depend on at
    z0) in the box's order, padded to `request.width`, and the corrected windows' start speeds."""
    free = request.free
    if free is None:
        free = informed_parameters(wm, data, box, z0, effects, batch=batch)
    names = box.names
    free = tuple(n for n in names if n in free)
    idx = np.asarray([names.index(n) for n in free], dtype=int)
    width = len(idx) if request.width is None else max(int(request.width), len(idx))
    return _Layout(free, idx, width, corrected_windows(data))


class _Noise(NamedTuple):
    """The noise model as it stands (scale and τ are re-measured after each pass), and the
    iterations each pass took."""

    scale: np.ndarray
    tau: np.ndarray
    steps: tuple[int, ...]

    def model(self, data: Problem, mask) -> NoiseModel:
        sensor = np.asarray(data.sigma, float)
        return NoiseModel(data.channels, self.scale, self.tau, sensor, mask.sum() * np.ones_like(self.scale))


def _reweighted(fit, p, data: Problem, mask, noise: _Noise, passes: int, sensor_only: bool):
    """`passes + 1` fits from `p`, each weighted by the noise the previous one left (with
    `SensorNoise`, the sensor's, unchanged). Returns the last fit's result (None if a fit cost
    is not finite: its start does not simulate) and the noise model it ends with."""
    sensor = np.asarray(data.sigma, float)
    scale, tau, steps = noise
    p = jnp.asarray(p)
    for _ in range(passes + 1):
        std = scale * np.sqrt(tau)
        res = fit(p, jnp.asarray(std))
        p = res.z
        steps = (*steps, int(res.num_steps))
        if not np.isfinite(float(res.cost)):
            return None, _Noise(scale, tau, steps)
        resid = np.asarray(res.residual).reshape(*mask.shape, len(scale)) * std
        if not sensor_only:
            measured = measure_noise(resid, mask, sensor, data.channels)
            scale, tau = measured.scale, measured.tau
    return _Pass(res, std, resid), _Noise(scale, tau, steps)


class _Pass(NamedTuple):
    """The last pass: its solver result, the per-channel stds it was weighted by, and its
    residual in channel units."""

    result: Any
    std: np.ndarray
    residual: np.ndarray


def _posterior(
    data: Problem, box: Box, z0, layout: _Layout, last: _Pass, noise: _Noise, mean, part: Part
) -> LikelihoodPosterior:
    """The posterior at the last pass's fit: its covariances with the final noise model, the
    parameters not fitted at their start and prior variance."""
    mask = np.asarray(data.part(part))
    res, std, resid = last
    scale, tau = noise.scale, noise.tau
    idx, k, kw, n_v = layout.idx, len(layout.idx), layout.width, layout.windows
    p = np.asarray(res.z)
    z, v0_offset = p[:k], p[kw:] if n_v else np.zeros(len(data.v0))
    raw = np.asarray(res.jacobian).reshape(*mask.shape, len(scale), kw + n_v)
    raw = np.concatenate([raw[..., :k], raw[..., kw:]], axis=-1)
    jac = raw * (std / scale)[:, None]
    cov_free, informed, shifts, joint, curvature = _covariances(
        data, mask, jac, resid / scale, z - mean[idx], tau
    )
    names = box.names
    cov, cov_info = (np.diag(np.full(len(names), PRIOR_Z_STD**2)) for _ in range(2))
    cov[np.ix_(idx, idx)] = cov_free
    cov_info[np.ix_(idx, idx)] = informed
    z_all = z0.copy()
    z_all[idx] = z
    disagree = {layout.free[i]: v for i, v in shifts.items()}
    return LikelihoodPosterior(
        box,
        z_all,
        cov,
        cov_info,
        layout.free,
        noise.model(data, mask),
        bool(res.converged),
        noise.steps,
        disagree,
        joint,
        v0_offset,
        curvature,
        part,
        resid,
        raw * std[:, None],
        mean,
    )


def _failed(data: Problem, box: Box, z0, free, part: Part, noise: NoiseModel, mean, steps):
    """The posterior of a fit whose start does not simulate: the prior, an infinite residual on
    the fitted samples (its χ² and evidence infinitely bad), not converged."""
    prior = np.diag(np.full(len(box.names), PRIOR_Z_STD**2))
    c, columns = len(data.channels), len(free) + corrected_windows(data)
    mask = np.asarray(data.part(part))
    return LikelihoodPosterior(
        box,
        z0,
        prior,
        prior.copy(),
        free,
        noise,
        False,
        tuple(steps),
        residual=np.where(mask[..., None], np.inf, 0.0) * np.ones(c),
        jacobian=np.zeros((*mask.shape, c, columns)),
        part=part,
        prior_mean=mean,
        v0_offset=np.zeros(len(data.v0)),
        curvature=np.diag(np.full(columns - corrected_windows(data), PRIOR_Z_STD**-2)),
    )


def _covariances(data: Problem, mask, jac, r, z, tau):
    """The Laplace covariance of the free coordinates with the final noise model, the start
    speeds marginalised, then widened by the model error (`robust_covariance`, then
    `consistent_covariance`); `jac` (W, K, C, k + start speeds) and `r` (W, K, C) whitened by the
    residual's scale. Returns (widened, information-only, shifts, joint disagreement, the
    curvature with the start speeds held)."""
    k = len(z)
    jac, jac_v = jac[..., :k], own_columns(jac[..., k:])
    root_tau = np.sqrt(tau)
    held = (jac / root_tau[:, None]).reshape(-1, k)
    curvature = held.T @ held + np.diag(np.full(k, PRIOR_Z_STD**-2))
    jac_tau = profiled(jac / root_tau[:, None], jac_v / root_tau)
    jac = profiled(jac, jac_v)
    prec = np.full(k, PRIOR_Z_STD**-2)
    cov = np.asarray(laplace_covariance(jnp.asarray(jac_tau.reshape(-1, k)), prec))
    informed = robust_covariance(cov, jac, r, mask, prec, BLOCK_TAUS * float(tau.max()))
    splits = data_splits(data, mask)
    widened, shifts, joint = consistent_covariance(informed, jac_tau, r / root_tau, z, prec, splits)
    return widened, informed, shifts, joint, curvature


class _Coordinates(eqx.Module):
    """Where a fit moves: the flattened entries `index` of the point `z0` (the free parameters'
    unbounded coordinates, padded to a common width, then the corrected windows' start speeds),
    `free` as a mask; the other parameters held exactly at `held`'s values."""

    space: Space
    z0: Point
    held: Point
    index: Array
    free: Point
    width: int = eqx.field(static=True)

    def values(self, p):
        """(θ, effect parameters, start-speed offsets) at the fitted entries `p`."""
        z = scatter(self.z0, self.index, p)
        theta, effect_params = self.space.values(z, self.held, self.free)
        return theta, effect_params, z.v0


def _coordinates(box: Box, effects, z0: np.ndarray, start: np.ndarray, layout: _Layout) -> _Coordinates:
    """The fit's coordinates: `layout`'s free parameters (box indices) and start speeds, as
    entries of a point."""
    nt, n_v = len(PARAM_NAMES), layout.windows
    at = positions(Point(z0[:nt], np.zeros(n_v), z0[nt:]))
    in_box = np.concatenate([at.theta, at.effects])[layout.idx]
    size = len(z0) + n_v
    index = np.concatenate([padded(in_box, layout.width, size), at.v0]).astype(int)
    start = jnp.asarray(start, jnp.float64)
    z = Point(jnp.asarray(z0[:nt]), jnp.zeros(n_v), jnp.asarray(z0[nt:]))
    return _Coordinates(
        Space.of(box, effects),
        z,
        Point(start[:nt], jnp.zeros(n_v), start[nt:]),
        jnp.asarray(index),
        mask_of(z, jnp.asarray(index)),
        layout.width,
    )


def _residual(wm, y, mask, coords: _Coordinates, p, std):
    """Whitened residual at p = [free logit coordinates (padded), start-speed corrections (W or
    none)]."""
    theta, effect_params, v0 = coords.values(p)
    pred, _ = wm(theta, effect_params, v0=wm.v0 + v0 if v0.shape[0] else None)
    return jnp.where(mask[..., None], (pred - y) / std, 0.0).ravel()


@eqx.filter_jit
def _lm(wm, y, mask, coords: _Coordinates, p, mean, std, max_steps):
    """One Levenberg–Marquardt fit of the free coordinates and start-speed corrections for given
    per-channel stds; a module-level jit, so every fit of the same shapes (the reweighting passes,
    the refit, every candidate of a search) compiles once."""
    k = coords.width
    prec = jnp.concatenate([jnp.full(k, PRIOR_Z_STD**-2), jnp.full(p.shape[0] - k, V0_STD**-2)])
    fn = lambda q: _residual(wm, y, mask, coords, q, std)
    return levenberg_marquardt(
        fn,
        p,
        prior=GaussianPrior(prec.astype(p.dtype), mean.astype(p.dtype)),
        max_steps=max_steps,
        control=StepControl(max_step=MAX_Z_STEP),
        # Without start speeds to correct, the plain forward-mode Jacobian.
        jacobian=(lambda q: residual_and_jacobian(fn, k, q)) if p.shape[0] > k else None,
    )


def _fitter(wm, data: Problem, mask, coords: _Coordinates, mean, max_steps):
    """The fit of the free coordinates as a function of (start, per-channel stds)."""
    y, m, steps = jnp.asarray(data.y), jnp.asarray(mask), jnp.asarray(max_steps)
    mean = jnp.asarray(mean, jnp.float64)
    return lambda p, std: _lm(wm, y, m, coords, p, mean, std, steps)
