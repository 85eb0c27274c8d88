"""Differentiable MAP fit of θ, initial speeds and effect parameters.

One *super-model* with every registered effect enabled is compiled once per `Fitter`; a
candidate explanation is a runtime mask saying which effects are active (inactive effects sit
exactly at their null values), so fitting any candidate reuses one compiled kernel. The
effects, their fit bounds and starting values are read from the registry
(`vdsbi.simulator.EFFECTS`, each effect's `bounds` and `start`) when a `Fitter` is built, so
an effect added with `register_effect` is searched like a built-in one.

The readings are `vdsbi.simulator.solve`'s fixed-step RK4 (plain jnp in `lax.scan`, so
forward-mode differentiable); the fit is `vdsbi.diagnostics.levenberg_marquardt` with a
forward-mode Jacobian over a fixed-width vector of free parameters (the candidate's free
entries of z, padded), one compilation for all candidates.

Parameters live in an unbounded space z: θ = lo + (hi − lo)·sigmoid(z) inside the vehicle's
prior box, effect parameters likewise inside their effect's `bounds`, initial speeds
v0 = v0_meas + z (m/s). A weak Gaussian N(0, 3²) on z (N(0, 1 m/s) on v0) regularises flat
directions.

Noise model: additive white Gaussian sensor noise, independent per channel with std σ_c.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Sequence

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from ..diagnostics import laplace_covariance, levenberg_marquardt, logit
from ..simulator import (
    CHANNELS,
    EFFECTS,
    PARAM_NAMES,
    Decimator,
    Inputs,
    Solver,
    Vehicle,
    VehicleModel,
    make_model,
    solve,
    steady_lateral_state,
)
from ._candidates import EffectSpace, effect_space

#: Prior std of z (θ and effect parameters) and of the initial speed, m/s.
Z_PRIOR_STD = 3.0
V0_PRIOR_STD = 1.0
#: Largest step of one z coordinate in one iteration (a sigmoid saturates past |z| ≈ 5).
MAX_Z_STEP = 2.0


def super_model(vehicle: Vehicle, effects: EffectSpace, longitudinal: str = "torque") -> VehicleModel:
    """All candidate effects, in registry order. At their null values they vanish exactly
    (the lags' states are frozen and bypassed at τ = 0, so nothing stiff remains and a 5 ms
    RK4 step is stable; τ is bounded below by 5 ms when fitted: |λ|·h ≤ 1.2)."""
    if all(n in EFFECTS for n in effects.names):
        return make_model(vehicle, effects.names, longitudinal=longitudinal)
    # unregistered effects (a discovered-term effect) are built from their classes
    mods = tuple(effects.classes[n]() for n in effects.names)
    return VehicleModel(vehicle=vehicle, effects=mods, longitudinal=longitudinal)


class FitData(eqx.Module):
    """What the fit conditions on: W equal-length windows of a problem (`vdsbi.problem`).

    Attributes:
        inputs: driver inputs, each leaf stacked over windows (W, T) at the model rate.
        measured: (W, K, C) measured channels at the compared samples.
        sigma: (C,) noise std of the compared samples, channel units.
        mask: (W, K) 1 where a sample enters the fit, else 0.
        v0_meas: (W,) measured initial speed per window, m/s.
        r0: (W,) measured initial yaw rate per window (with θ: the initial lateral state).
        decimator: the filter shared with the measurement, or None (compared = model rate).
        channel_index: indices of the measured channels in `CHANNELS` (static).
        channels: their names (static).
        longitudinal: "torque" or "speed" (static).
    """

    inputs: Inputs
    measured: jax.Array
    sigma: jax.Array
    mask: jax.Array
    v0_meas: jax.Array
    r0: jax.Array
    decimator: Decimator | None
    channel_index: tuple[int, ...] = eqx.field(static=True)
    channels: tuple[str, ...] = eqx.field(static=True)
    longitudinal: str = eqx.field(static=True, default="torque")

    @property
    def num_windows(self) -> int:
        return int(self.measured.shape[0])


class Space(eqx.Module):
    """Maps the unbounded vector z = [z_θ (6), z_v0 (W), z_effects (E)] to physical values."""

    theta_lo: jax.Array
    theta_hi: jax.Array
    eff_lo: jax.Array
    eff_hi: jax.Array
    eff_null: jax.Array
    eff_bounds: tuple[tuple[int, int], ...] = eqx.field(static=True)

    def split(self, z, num_windows):
        return z[:6], z[6 : 6 + num_windows], z[6 + num_windows :]

    def theta(self, z_theta):
        return self.theta_lo + (self.theta_hi - self.theta_lo) * jax.nn.sigmoid(z_theta)

    def effects(self, z_eff, active) -> tuple[jax.Array, ...]:
        """One parameter vector per effect; inactive ones at their null values."""
        val = self.eff_lo + (self.eff_hi - self.eff_lo) * jax.nn.sigmoid(z_eff)
        flat = jnp.where(active, val, self.eff_null)
        return tuple(flat[a:b] for a, b in self.eff_bounds)


def make_space(vehicle: Vehicle, effects: EffectSpace) -> Space:
    prior = vehicle.default_prior()
    return Space(
        theta_lo=jnp.array([prior[n][0] for n in PARAM_NAMES]),
        theta_hi=jnp.array([prior[n][1] for n in PARAM_NAMES]),
        eff_lo=jnp.asarray(effects.lo),
        eff_hi=jnp.asarray(effects.hi),
        eff_null=jnp.asarray(effects.null),
        eff_bounds=tuple((s.start, s.stop) for s in effects.slices.values()),
    )


def _predict(model, space, data: FitData, z, active, solver):
    """(W, K, 6) readings of every window at the compared samples; each window starts from its
    measured speed and yaw rate with the steady-state side speed under θ."""
    zt, zv, ze = space.split(z, data.num_windows)
    theta = space.theta(zt)
    ep = space.effects(ze, active)

    def one(inputs, v0, r0):
        lateral0 = jnp.stack(steady_lateral_state(theta, model.vehicle, v0, r0))
        ys = solve(model, theta, inputs, v0, ep, solver, lateral0=lateral0)[0]
        return ys if data.decimator is None else data.decimator(ys)

    return jax.vmap(one)(data.inputs, data.v0_meas + zv, data.r0)


def _whitened(model, space, data, z, active, solver):
    y = _predict(model, space, data, z, active, solver)[:, :, list(data.channel_index)]
    r = (y - data.measured) / data.sigma
    r = jnp.where(data.mask[:, :, None] > 0, r, 0.0)
    return r.reshape(-1)


@eqx.filter_jit
def _residual(model, space, data, z, active, solver):
    return _whitened(model, space, data, z, active, solver)


@eqx.filter_jit
def _predict_jit(model, space, data, z, active, solver):
    return _predict(model, space, data, z, active, solver)


@eqx.filter_jit
def _predict_jacobian(model, space, data, z, active, free, solver):
    fn = lambda y: _predict(model, space, data, z.at[free].set(y), active, solver)
    return jax.jacfwd(fn)(z[free])


@eqx.filter_jit
def _fit_free(model, space, data, z, active, free, prec, max_iter, tol, solver):
    """Levenberg–Marquardt over the entries `free` of z (padded with an out-of-range index,
    whose slots nothing reads: their prior keeps them at 0)."""
    fn = lambda y: _whitened(model, space, data, z.at[free].set(y, mode="drop"), active, solver)
    y0 = jnp.where(free < z.size, z[jnp.minimum(free, z.size - 1)], 0.0)
    return levenberg_marquardt(
        fn, y0, prior_precision=prec, max_steps=max_iter, rtol=tol, max_step=MAX_Z_STEP
    )


@dataclasses.dataclass
class FitResult:
    """A converged (or best-found) MAP fit of one candidate.

    Attributes:
        effects: names of the active effects.
        z: (P,) full unbounded parameter vector.
        theta: (6,) θ in PARAM_NAMES order.
        theta_std: (6,) Laplace std of θ.
        v0: (W,) fitted initial speeds, m/s.
        effect_params: {effect: {param: value}}.
        effect_std: {effect: {param: Laplace std}}.
        chi2: Σ r² over the fitted samples (whitened residual).
        num_samples: number of fitted residual entries N.
        num_params: number of free parameters (θ, v0s, effect parameters).
        residual: (N,) whitened residual at the optimum (masked entries are 0).
        jacobian: (N, K) Jacobian at the optimum along the free columns.
        free: indices of the free entries of z (K,).
        iterations: LM iterations used.
        converged: whether the relative cost change fell below tolerance.
        cov: (K, K) Laplace covariance of the free entries of z (inflated by χ²/dof > 1).
    """

    effects: tuple[str, ...]
    z: np.ndarray
    theta: np.ndarray
    theta_std: np.ndarray
    v0: np.ndarray
    effect_params: dict
    effect_std: dict
    chi2: float
    num_samples: int
    num_params: int
    residual: np.ndarray
    jacobian: np.ndarray
    free: np.ndarray
    iterations: int
    converged: bool
    cov: np.ndarray | None = None

    @property
    def chi2_dof(self) -> float:
        return self.chi2 / max(1, self.num_samples - self.num_params)


class Fitter:
    """Fits candidates on one `FitData` with one compiled kernel.

    Args:
        vehicle: vehicle constants.
        data: the windows to fit.
        dt: RK4 step, s (5 ms for the search, the simulator's default 2.5 ms for the test
            and the final fit).
        effects: the candidate effects (default: every registered effect, read now).
        free_effects: most effect parameters one fit may free (default: the three largest
            effects', as the forward search adds up to three; all of them for a term refit).
    """

    def __init__(
        self,
        vehicle: Vehicle,
        data: FitData,
        dt: float = 0.0025,
        effects: EffectSpace | None = None,
        free_effects: int | None = None,
    ):
        self.vehicle = vehicle
        self.effects = effect_space() if effects is None else effects
        self.model = super_model(vehicle, self.effects, data.longitudinal)
        self.space = make_space(vehicle, self.effects)
        self.data = data
        self.dt = float(dt)
        self.solver = Solver(dt=self.dt)
        w = data.num_windows
        self.num_params = 6 + w + self.effects.num_params
        most = self.effects.max_pair_params if free_effects is None else int(free_effects)
        self.width = 6 + w + most
        self.num_residuals = int(np.asarray(data.mask).sum()) * len(data.channels)
        e = self.effects
        self._z_eff_start = logit((e.start - e.lo) / (e.hi - e.lo))

    def initial_z(self, theta0: np.ndarray | None = None) -> np.ndarray:
        prior = self.vehicle.default_prior()
        if theta0 is None:
            # Middle of the prior box in z (geometric for the stiffnesses).
            theta0 = np.array([np.sqrt(prior[n][0] * prior[n][1]) for n in PARAM_NAMES])
            theta0[0] = 0.5 * (prior["l_f"][0] + prior["l_f"][1])
        lo, hi = np.asarray(self.space.theta_lo), np.asarray(self.space.theta_hi)
        zt = logit((np.asarray(theta0) - lo) / (hi - lo))
        return np.concatenate([zt, np.zeros(self.data.num_windows), self._z_eff_start])

    def _effect_index(self, effect: str) -> np.ndarray:
        """Indices in z of an effect's parameters."""
        s = self.effects.slices[effect]
        return 6 + self.data.num_windows + np.arange(s.start, s.stop)

    def active_mask(self, effects: Sequence[str]) -> np.ndarray:
        act = np.zeros(self.effects.num_params, dtype=bool)
        for e in effects:
            act[self.effects.slices[e]] = True
        return act

    def free_index(self, effects: Sequence[str], fix_theta: bool = False) -> np.ndarray:
        w = self.data.num_windows
        idx = [] if fix_theta else list(range(6))
        idx += list(range(6, 6 + w))
        for e in effects:
            idx += self._effect_index(e).tolist()
        return np.asarray(idx, dtype=int)

    def _prior_prec(self) -> np.ndarray:
        w = self.data.num_windows
        prec = np.full(self.num_params, 1.0 / Z_PRIOR_STD**2)
        prec[6 : 6 + w] = 1.0 / V0_PRIOR_STD**2
        return prec

    def residual(self, z, effects: Sequence[str], data: FitData | None = None) -> np.ndarray:
        act = jnp.asarray(self.active_mask(effects))
        d = self.data if data is None else data
        return np.asarray(_residual(self.model, self.space, d, jnp.asarray(z), act, self.solver))

    def predict(self, z, effects: Sequence[str], data: FitData | None = None) -> np.ndarray:
        """(W, T, 6) noise-free readings on `data` (default: the fitted windows)."""
        act = jnp.asarray(self.active_mask(effects))
        d = self.data if data is None else data
        return np.asarray(_predict_jit(self.model, self.space, d, jnp.asarray(z), act, self.solver))

    def prediction_variance(self, fit: FitResult, data: FitData | None = None) -> np.ndarray:
        """(W, T, 6) variance of the predicted readings on `data` that the fit's parameter
        uncertainty (its Laplace covariance, linearised) carries."""
        act = jnp.asarray(self.active_mask(fit.effects))
        d = self.data if data is None else data
        jac = _predict_jacobian(
            self.model, self.space, d, jnp.asarray(fit.z), act, jnp.asarray(fit.free), self.solver
        )
        jac = np.asarray(jac)
        return np.einsum("...k,kl,...l->...", jac, fit.cov, jac)

    def fit(
        self,
        effects: Sequence[str] = (),
        z0: np.ndarray | None = None,
        *,
        max_iter: int = 30,
        tol: float = 1e-6,
        fix_theta: bool = False,
    ) -> FitResult:
        """MAP fit: `levenberg_marquardt` on ½|r|² + ½ Σ prec·z² over the free parameters.

        `z0` warm-starts (e.g. from the base fit); entries of newly activated effects are
        reset to their starting values.
        """
        effects = tuple(effects)
        z = self.initial_z() if z0 is None else np.array(z0, dtype=float)
        for e in effects:
            i = self._effect_index(e)
            if z0 is None or not np.isfinite(z[i]).all():
                z[i] = self._z_eff_start[self.effects.slices[e]]
        free = self.free_index(effects, fix_theta)
        k = len(free)
        if k > self.width:
            raise ValueError(f"fit: {k} free parameters exceed the kernel width {self.width}")
        # Fixed width (padding indices point past z and are dropped): one compiled kernel.
        index = np.full(self.width, self.num_params)
        index[:k] = free
        prec = np.ones(self.width)
        prec[:k] = self._prior_prec()[free]
        act = jnp.asarray(self.active_mask(effects))
        sol = _fit_free(
            self.model,
            self.space,
            self.data,
            jnp.asarray(z),
            act,
            jnp.asarray(index),
            jnp.asarray(prec),
            jnp.asarray(max_iter),
            jnp.asarray(tol, dtype=z.dtype),
            self.solver,
        )
        z[free] = np.asarray(sol.z)[:k]
        r, jac = np.asarray(sol.residual), np.asarray(sol.jacobian)[:, :k]
        return self._result(effects, z, r, jac, free, prec[:k], int(sol.num_steps), bool(sol.converged))

    def _result(self, effects, z, r, jac, free, prec, iterations, converged) -> FitResult:
        w = self.data.num_windows
        chi2 = float(r @ r)
        k = len(free)
        dof = max(1, self.num_residuals - k)
        # Laplace covariance in z; inflated by χ²/dof when > 1 (noise under-stated or model
        # misspecified: the usual quasi-likelihood correction).
        cov_z = np.asarray(laplace_covariance(jnp.asarray(jac), jnp.asarray(prec))) * max(1.0, chi2 / dof)
        sd_free = np.sqrt(np.clip(np.diag(cov_z), 0, None))
        sd_z = np.zeros(self.num_params)
        sd_z[free] = sd_free
        zt, zv, ze = z[:6], z[6 : 6 + w], z[6 + w :]
        sig = lambda x: 1.0 / (1.0 + np.exp(-x))
        tlo, thi = np.asarray(self.space.theta_lo), np.asarray(self.space.theta_hi)
        theta = tlo + (thi - tlo) * sig(zt)
        theta_std = (thi - tlo) * sig(zt) * (1 - sig(zt)) * sd_z[:6]
        elo, ehi = self.effects.lo, self.effects.hi
        eval_ = elo + (ehi - elo) * sig(ze)
        esd = (ehi - elo) * sig(ze) * (1 - sig(ze)) * sd_z[6 + w :]
        params, stds = {}, {}
        for e in effects:
            s = self.effects.slices[e]
            names = self.effects.classes[e].param_names
            params[e] = {n: float(v) for n, v in zip(names, eval_[s])}
            stds[e] = {n: float(v) for n, v in zip(names, esd[s])}
        return FitResult(
            effects=tuple(effects),
            z=z.copy(),
            theta=theta,
            theta_std=theta_std,
            v0=np.asarray(self.data.v0_meas) + zv,
            effect_params=params,
            effect_std=stds,
            chi2=chi2,
            num_samples=self.num_residuals,
            num_params=k,
            residual=r,
            jacobian=jac,
            free=free,
            iterations=iterations,
            converged=converged,
            cov=cov_z,
        )


def channel_indices(names: Sequence[str]) -> tuple[int, ...]:
    return tuple(CHANNELS.index(n) for n in names)
