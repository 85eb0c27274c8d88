"""Differentiable MAP fit of θ, initial speeds and effect parameters (Levenberg–Marquardt).

One *super-model* with all ten effects enabled is compiled once; a candidate explanation is a
runtime mask saying which effects are active (inactive effects sit exactly at their null
values), so fitting any of the 55 candidates reuses one compiled Jacobian kernel.

The Jacobian is forward-mode (`jax.linearize` + `vmap` over a fixed-width tangent basis).
`vdsbi.simulator.solve` steps with diffrax's RK4, whose step uses a custom-VJP loop and so
cannot be pushed through `jacfwd`; `rk4_readings` below is the same fixed-step classical RK4
on the same vector field and sensor map (it agrees with `solve` to ~1e-12 in float64).

Parameters live in an unbounded space z: θ = lo + (hi − lo)·sigmoid(z) inside the vehicle's
prior box, effect parameters likewise inside `EFFECT_BOUNDS`, initial speeds v0 = v0_meas + z
(m/s). A weak Gaussian N(0, 3²) on z (N(0, 1 m/s) on v0) regularises flat directions.

Noise model: additive white Gaussian sensor noise, independent per channel with std σ_c.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Sequence

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from ..simulator import EFFECTS, PARAM_NAMES, Args, Inputs, Vehicle, VehicleModel, make_model
from ..simulator._vehicle import CHANNELS


def super_model(vehicle: Vehicle) -> VehicleModel:
    """All candidate effects, in registry order. At their null values they vanish exactly
    (the lags' states are frozen and bypassed at τ = 0, so nothing stiff remains and a 5 ms
    RK4 step is stable; τ is bounded below by 5 ms when fitted: |λ|·h ≤ 1.2)."""
    return make_model(vehicle, EFFECT_NAMES)


#: Fitting bounds per effect parameter (wider than the effect's `typical` range so an
#: estimate is not pinned by the bound; physical sign constraints where they exist).
EFFECT_BOUNDS: dict[str, tuple[tuple[float, float], ...]] = {
    "aero_drag": ((0.0, 2.5),),
    "rolling_resistance": ((0.0, 0.08),),
    "road_grade": ((-0.15, 0.15),),
    "road_bank": ((-0.15, 0.15),),
    "steering_lag": ((0.005, 0.8),),
    "torque_lag": ((0.005, 1.2),),
    "imu_lever_arm": ((-2.5, 2.5), (-1.0, 1.0)),
    "imu_misalignment": ((-0.15, 0.15), (-0.15, 0.15)),
    "sensor_bias": ((-2.0, 2.0), (-2.0, 2.0), (-0.08, 0.08)),
    "wheel_radius_error": ((-0.15, 0.15),),
}
#: Starting value of each effect parameter when its effect is switched on (inside the bounds).
EFFECT_START: dict[str, tuple[float, ...]] = {
    "aero_drag": (0.3,),
    "rolling_resistance": (0.004,),
    "road_grade": (0.0,),
    "road_bank": (0.0,),
    "steering_lag": (0.04,),
    "torque_lag": (0.05,),
    "imu_lever_arm": (0.0, 0.0),
    "imu_misalignment": (0.0, 0.0),
    "sensor_bias": (0.0, 0.0, 0.0),
    "wheel_radius_error": (0.0,),
}
#: Candidate effects (registered effects without fitting bounds here are not searched).
EFFECT_NAMES: tuple[str, ...] = tuple(n for n in EFFECTS if n in EFFECT_BOUNDS)
_SIZES = [len(EFFECTS[n].param_names) for n in EFFECT_NAMES]
_OFFSETS = np.concatenate([[0], np.cumsum(_SIZES)]).astype(int)
#: Slice of each effect's parameters in the flat effect-parameter vector.
EFFECT_SLICES: dict[str, slice] = {
    n: slice(int(_OFFSETS[i]), int(_OFFSETS[i + 1])) for i, n in enumerate(EFFECT_NAMES)
}
NUM_EFFECT_PARAMS = int(_OFFSETS[-1])
#: Most effect parameters a candidate may free at once (a pair: sensor_bias + a 2-param effect).
MAX_EFFECT_PARAMS = 5
#: Prior std of z (θ and effect parameters) and of the initial speed, m/s.
Z_PRIOR_STD = 3.0
V0_PRIOR_STD = 1.0


def _effect_arrays():
    lo = np.concatenate([[b[0] for b in EFFECT_BOUNDS[n]] for n in EFFECT_NAMES])
    hi = np.concatenate([[b[1] for b in EFFECT_BOUNDS[n]] for n in EFFECT_NAMES])
    null = np.concatenate([EFFECTS[n].null for n in EFFECT_NAMES]).astype(float)
    start = np.concatenate([EFFECT_START[n] for n in EFFECT_NAMES]).astype(float)
    return lo, hi, null, start


def _logit(x):
    x = np.clip(x, 1e-9, 1 - 1e-9)
    return np.log(x) - np.log1p(-x)


def rk4_readings(model, theta, inputs: Inputs, v0, effect_params, dt: float = 0.0025):
    """Noise-free (T, 6) readings by classical RK4, forward-differentiable (see module doc)."""
    args = Args(theta=theta, effect_params=effect_params, inputs=inputs)
    y0 = model.initial_state(theta, effect_params, inputs, v0)
    sub = max(1, round(inputs.dt / dt))
    h = inputs.dt / sub
    f = lambda t, y: model.vector_field(t, y, args)

    def interval(y, k):
        for j in range(sub):
            t0 = inputs.t0 + k * inputs.dt + j * h
            k1 = f(t0, y)
            k2 = f(t0 + h / 2, y + h / 2 * k1)
            k3 = f(t0 + h / 2, y + h / 2 * k2)
            k4 = f(t0 + h, y + h * k3)
            y = y + h / 6 * (k1 + 2 * k2 + 2 * k3 + k4)
        return y, model.sensors(inputs.t0 + (k + 1) * inputs.dt, y, args)

    _, ys = jax.lax.scan(interval, y0, jnp.arange(inputs.num_samples - 1))
    return jnp.concatenate([model.sensors(inputs.t0, y0, args)[None], ys])


class FitData(eqx.Module):
    """What the fit conditions on: W equal-length windows of a recording.

    Attributes:
        inputs: driver inputs, each leaf stacked over windows (W, T).
        measured: (W, T, C) measured channels.
        sigma: (C,) additive noise std per channel, channel units.
        mask: (W, T) 1 where a sample enters the fit, else 0.
        v0_meas: (W,) measured initial speed per window, m/s.
        channel_index: indices of the measured channels in `CHANNELS` (static).
        channels: their names (static).
    """

    inputs: Inputs
    measured: jax.Array
    sigma: jax.Array
    mask: jax.Array
    v0_meas: jax.Array
    channel_index: tuple[int, ...] = eqx.field(static=True)
    channels: tuple[str, ...] = eqx.field(static=True)

    @property
    def num_windows(self) -> int:
        return int(self.measured.shape[0])


class Space(eqx.Module):
    """Maps the unbounded vector z = [z_θ (6), z_v0 (W), z_effects (16)] to physical values."""

    theta_lo: jax.Array
    theta_hi: jax.Array
    eff_lo: jax.Array
    eff_hi: jax.Array
    eff_null: jax.Array

    def split(self, z, num_windows):
        return z[:6], z[6 : 6 + num_windows], z[6 + num_windows :]

    def theta(self, z_theta):
        return self.theta_lo + (self.theta_hi - self.theta_lo) * jax.nn.sigmoid(z_theta)

    def effects(self, z_eff, active):
        val = self.eff_lo + (self.eff_hi - self.eff_lo) * jax.nn.sigmoid(z_eff)
        return jnp.where(active, val, self.eff_null)


def make_space(vehicle: Vehicle) -> Space:
    prior = vehicle.default_prior()
    lo, hi, null, _ = _effect_arrays()
    return Space(
        theta_lo=jnp.array([prior[n][0] for n in PARAM_NAMES]),
        theta_hi=jnp.array([prior[n][1] for n in PARAM_NAMES]),
        eff_lo=jnp.asarray(lo),
        eff_hi=jnp.asarray(hi),
        eff_null=jnp.asarray(null),
    )


def _split_effects(flat):
    return tuple(flat[EFFECT_SLICES[n]] for n in EFFECT_NAMES)


def _predict(model, space, data: FitData, z, active, dt):
    """(W, T, 6) readings for every window."""
    zt, zv, ze = space.split(z, data.num_windows)
    theta = space.theta(zt)
    ep = _split_effects(space.effects(ze, active))
    v0 = data.v0_meas + zv

    def one(inp, v):
        return rk4_readings(model, theta, inp, v, ep, dt)

    return jax.vmap(one)(data.inputs, v0)


def _whitened(model, space, data, z, active, dt):
    y = _predict(model, space, data, z, active, dt)[:, :, list(data.channel_index)]
    r = (y - data.measured) / data.sigma
    r = jnp.where(data.mask[:, :, None] > 0, r, 0.0)
    return r.reshape(-1)


@eqx.filter_jit
def _residual(model, space, data, z, active, dt):
    return _whitened(model, space, data, z, active, dt)


@eqx.filter_jit
def _residual_and_jacobian(model, space, data, z, active, basis, dt):
    """Whitened residual (N,) and its Jacobian along the columns of `basis` (P, K) -> (N, K)."""
    fn = lambda zz: _whitened(model, space, data, zz, active, dt)
    r, lin = jax.linearize(fn, z)
    jac = jax.vmap(lin, in_axes=1, out_axes=1)(basis)
    return r, jac


@eqx.filter_jit
def _predict_jit(model, space, data, z, active, dt):
    return _predict(model, space, data, z, active, dt)


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
    """

    def __init__(self, vehicle: Vehicle, data: FitData, dt: float = 0.0025):
        self.vehicle = vehicle
        self.model = super_model(vehicle)
        self.space = make_space(vehicle)
        self.data = data
        self.dt = float(dt)
        w = data.num_windows
        self.num_params = 6 + w + NUM_EFFECT_PARAMS
        self.width = 6 + w + MAX_EFFECT_PARAMS
        self.num_residuals = int(np.asarray(data.mask).sum()) * len(data.channels)
        _, _, _, start = _effect_arrays()
        lo, hi = np.asarray(self.space.eff_lo), np.asarray(self.space.eff_hi)
        self._z_eff_start = _logit((start - lo) / (hi - lo))

    def initial_z(self, theta0: np.ndarray | None = None) -> np.ndarray:
        prior = self.vehicle.default_prior()
        if theta0 is None:
            # Middle of the prior box in z (geometric for the stiffnesses).
            theta0 = np.array([np.sqrt(prior[n][0] * prior[n][1]) for n in PARAM_NAMES])
            theta0[0] = 0.5 * (prior["l_f"][0] + prior["l_f"][1])
        lo, hi = np.asarray(self.space.theta_lo), np.asarray(self.space.theta_hi)
        zt = _logit((np.asarray(theta0) - lo) / (hi - lo))
        return np.concatenate([zt, np.zeros(self.data.num_windows), self._z_eff_start])

    def active_mask(self, effects: Sequence[str]) -> np.ndarray:
        act = np.zeros(NUM_EFFECT_PARAMS, dtype=bool)
        for e in effects:
            act[EFFECT_SLICES[e]] = True
        return act

    def free_index(self, effects: Sequence[str], fix_theta: bool = False) -> np.ndarray:
        w = self.data.num_windows
        idx = [] if fix_theta else list(range(6))
        idx += list(range(6, 6 + w))
        for e in effects:
            s = EFFECT_SLICES[e]
            idx += list(range(6 + w + s.start, 6 + w + s.stop))
        return np.asarray(idx, dtype=int)

    def _prior_prec(self) -> np.ndarray:
        w = self.data.num_windows
        prec = np.full(self.num_params, 1.0 / Z_PRIOR_STD**2)
        prec[6 : 6 + w] = 1.0 / V0_PRIOR_STD**2
        return prec

    def residual(self, z, effects: Sequence[str], data: FitData | None = None) -> np.ndarray:
        act = jnp.asarray(self.active_mask(effects))
        d = self.data if data is None else data
        return np.asarray(_residual(self.model, self.space, d, jnp.asarray(z), act, self.dt))

    def predict(self, z, effects: Sequence[str], data: FitData | None = None) -> np.ndarray:
        """(W, T, 6) noise-free readings on `data` (default: the fitted windows)."""
        act = jnp.asarray(self.active_mask(effects))
        d = self.data if data is None else data
        return np.asarray(_predict_jit(self.model, self.space, d, jnp.asarray(z), act, self.dt))

    def linearize(self, z, effects: Sequence[str], free: np.ndarray):
        """Residual (N,) and Jacobian (N, len(free)) at z."""
        if len(free) > self.width:
            raise ValueError(f"fit: {len(free)} free parameters exceed the kernel width {self.width}")
        basis = np.zeros((self.num_params, self.width))
        basis[free, np.arange(len(free))] = 1.0
        act = jnp.asarray(self.active_mask(effects))
        r, jac = _residual_and_jacobian(
            self.model, self.space, self.data, jnp.asarray(z), act, jnp.asarray(basis), self.dt
        )
        return np.asarray(r), np.asarray(jac)[:, : len(free)]

    def fit(
        self,
        effects: Sequence[str] = (),
        z0: np.ndarray | None = None,
        *,
        max_iter: int = 30,
        tol: float = 1e-6,
        fix_theta: bool = False,
    ) -> FitResult:
        """Levenberg–Marquardt on ½|r|² + ½ Σ prec·z² over the free parameters.

        `z0` warm-starts (e.g. from the base fit); entries of newly activated effects are
        reset to their starting values.
        """
        effects = tuple(effects)
        z = self.initial_z() if z0 is None else np.array(z0, dtype=float)
        w = self.data.num_windows
        for e in effects:
            s = EFFECT_SLICES[e]
            if z0 is None or not np.isfinite(z[6 + w + s.start : 6 + w + s.stop]).all():
                z[6 + w + s.start : 6 + w + s.stop] = self._z_eff_start[s]
        free = self.free_index(effects, fix_theta)
        prec = self._prior_prec()[free]
        centre = np.zeros(len(free))

        def cost_of(r, zf):
            if not np.all(np.isfinite(r)):
                return np.inf
            return 0.5 * float(r @ r) + 0.5 * float(np.sum(prec * (zf - centre) ** 2))

        r, jac = self.linearize(z, effects, free)
        cost = cost_of(r, z[free])
        lam = 1e-3
        converged = False
        it = 0
        while it < max_iter:
            it += 1
            g = jac.T @ r + prec * (z[free] - centre)
            h = jac.T @ jac + np.diag(prec)
            improved = False
            for _ in range(8):
                step = -np.linalg.solve(h + lam * np.diag(np.diag(h) + 1e-9), g)
                step = np.clip(step, -2.0, 2.0)
                z_new = z.copy()
                z_new[free] += step
                r_new = self.residual(z_new, effects)
                c_new = cost_of(r_new, z_new[free])
                if c_new < cost:
                    improved = True
                    break
                lam *= 5.0
            if not improved:
                converged = True
                break
            rel = (cost - c_new) / max(cost, 1e-12)
            z, cost = z_new, c_new
            lam = max(lam / 4.0, 1e-7)
            r, jac = self.linearize(z, effects, free)
            if rel < tol:
                converged = True
                break
        return self._result(effects, z, r, jac, free, prec, it, converged)

    def _result(self, effects, z, r, jac, free, prec, iterations, converged) -> FitResult:
        w = self.data.num_windows
        chi2 = float(r @ r)
        k = len(free)
        dof = max(1, self.num_residuals - k)
        # Laplace covariance in z; inflated by χ²/dof when > 1 (noise under-stated or model
        # misspecified: the usual quasi-likelihood correction).
        cov_z = np.linalg.pinv(jac.T @ jac + np.diag(prec)) * max(1.0, chi2 / dof)
        sd_free = np.sqrt(np.clip(np.diag(cov_z), 0, None))
        sd_z = np.zeros(self.num_params)
        sd_z[free] = sd_free
        zt, zv, ze = z[:6], z[6 : 6 + w], z[6 + w :]
        sig = lambda x: 1.0 / (1.0 + np.exp(-x))
        tlo, thi = np.asarray(self.space.theta_lo), np.asarray(self.space.theta_hi)
        theta = tlo + (thi - tlo) * sig(zt)
        theta_std = (thi - tlo) * sig(zt) * (1 - sig(zt)) * sd_z[:6]
        elo, ehi = np.asarray(self.space.eff_lo), np.asarray(self.space.eff_hi)
        eval_ = elo + (ehi - elo) * sig(ze)
        esd = (ehi - elo) * sig(ze) * (1 - sig(ze)) * sd_z[6 + w :]
        params, stds = {}, {}
        for e in effects:
            s = EFFECT_SLICES[e]
            names = EFFECTS[e].param_names
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
        )


def channel_indices(names: Sequence[str]) -> tuple[int, ...]:
    return tuple(CHANNELS.index(n) for n in names)
