"""Candidate explanations fitted with the one estimator (`vdsbi.estimation.fit_likelihood`).

One *super-model* with every candidate effect enabled is built once per `Fitter`; a candidate
explanation is which effects are active: the others' parameters sit exactly at their null values,
where they vanish, so every candidate's fit runs one compiled program (the free coordinates padded
to one width). The effects, their fit bounds and starting values are read from the registry
(`vdsbi.simulator.effects.EFFECTS`, each effect's `bounds` and `start`) when a `Fitter` is built, so an
effect added with `register_effect` is searched like a built-in one.

A `DiscoveryFit` is the estimator's posterior seen in the search's layout: the unbounded vector
z = [z_θ (6), z_v0 (W), z_effects (E)], the residual whitened by the sensor noise (what the
misspecification test holds against noise), and the per-channel residual and noise model the
evidence is computed with (`vdsbi.discovery._rank`).
"""

from __future__ import annotations

import dataclasses
from collections.abc import Sequence

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float

from ..estimation import ModelError, SensorNoise, fit_likelihood
from ..problem import Box, Problem, WindowedModel, parameter_names, windowed_model
from ..simulator import PARAM_NAMES, Vehicle, make_model
from ..simulator.effects import EFFECTS
from ..simulator.models import AbstractVehicleModel, LongitudinalMode, model_class
from ..simulator.solvers import Solver
from ._candidates import EffectSpace, effect_space
from ._results import DiscoveryFit

#: Prior std of the initial speed of a window the fit did not see, m/s.
V0_PRIOR_STD = 1.0
#: Unit-box coordinates of starting values are clipped to [EDGE, 1 − EDGE] before the logit.
EDGE = 1e-9


def super_model(
    vehicle: Vehicle, effects: EffectSpace, longitudinal: LongitudinalMode = "torque"
) -> AbstractVehicleModel:
    """All candidate effects, in registry order. At their null values they vanish exactly
    (the lags' states are frozen and bypassed at τ = 0, so nothing stiff remains and a 5 ms
    RK4 step is stable; τ is bounded below by 5 ms when fitted: |λ|·h ≤ 1.2)."""
    if all(n in EFFECTS for n in effects.names):
        return make_model(vehicle, effects.names, longitudinal=longitudinal)
    # unregistered effects (a discovered-term effect) are built from their classes
    mods = tuple(effects.classes[n]() for n in effects.names)
    return model_class(longitudinal)(vehicle=vehicle, effects=mods)


class Space(eqx.Module):
    """Maps the unbounded vector z = [z_θ (6), z_v0 (W), z_effects (E)] to physical values.

    Attributes:
        theta: the prior box of θ.
        effects: the fit box of every effect parameter, flat.
        null: (E,) values at which each effect vanishes.
        slices: each effect's (start, stop) in the flat effect vector.
    """

    theta: Box
    effects: Box
    null: Float[Array, " E"]
    slices: tuple[tuple[int, int], ...] = eqx.field(static=True)

    def split(self, z, num_windows: int):
        return z[:6], z[6 : 6 + num_windows], z[6 + num_windows :]

    def effect_params(self, z_eff, active) -> tuple[jax.Array, ...]:
        """One parameter vector per effect; inactive ones at their null values."""
        flat = jnp.where(active, self.effects.from_unbounded(z_eff), self.null)
        return tuple(flat[a:b] for a, b in self.slices)


def make_space(vehicle: Vehicle, effects: EffectSpace) -> Space:
    names = parameter_names([effects.classes[e] for e in effects.names])[len(PARAM_NAMES) :]
    return Space(
        theta=Box.from_dict(vehicle.default_prior(), PARAM_NAMES),
        effects=Box(jnp.asarray(effects.lo), jnp.asarray(effects.hi), names),
        null=jnp.asarray(effects.null),
        slices=tuple((s.start, s.stop) for s in effects.slices.values()),
    )


class _Target(eqx.Module):
    """The fitted samples: the windowed super-model and what it is compared with."""

    wm: WindowedModel
    measured: Float[Array, "W K C"]
    sigma: Float[Array, " C"]
    mask: Float[Array, "W K"]


def _readings(wm: WindowedModel, space: Space, z, active) -> Float[Array, "W K C"]:
    """The compared samples of every window at z; each window starts from its measured speed
    plus its fitted offset."""
    zt, zv, ze = space.split(z, wm.v0.shape[0])
    ys, _ = wm(space.theta.from_unbounded(zt), space.effect_params(ze, active), v0=wm.v0 + zv)
    return ys


def whitened(space: Space, target: _Target, z, active):
    r = (_readings(target.wm, space, z, active) - target.measured) / target.sigma
    r = jnp.where(target.mask[:, :, None] > 0, r, 0.0)
    return r.reshape(-1)


def _padded(free, width: int, size: int) -> np.ndarray:
    """`free` indices padded to `width` with the out-of-range index `size`: every number of free
    parameters then shares one compilation (the padding's slots are read as 0 and dropped)."""
    index = np.full(max(len(free), width), size)
    index[: len(free)] = free
    return index


def _take(z, free):
    """z[free] with the padding's slots at 0."""
    return jnp.where(free < z.size, z[jnp.minimum(free, z.size - 1)], 0.0)


@eqx.filter_jit
def _linearised(wm, space, z, active, free):
    """The readings at z and ∂readings/∂z[free] for padded `free` (`_padded`: its slots give zero
    columns); one program serves predictions and their variances."""
    fn = lambda y: (r := _readings(wm, space, z.at[free].set(y, mode="drop"), active), r)
    jac, readings = jax.jacfwd(fn, has_aux=True)(_take(z, free))
    return readings, jac


class Fitter:
    """Fits candidates on the training part of a problem with one compiled kernel.

    Args:
        problem: the problem; its windows holding training samples are fitted
            (`Problem.select("train")`).
        dt: RK4 step, s (5 ms for the search, the simulator's default 2.5 ms for the test
            and the final fit).
        effects: the candidate effects (default: every registered effect, read now).
        free_effects: most effect parameters one fit may free (default: the three largest
            effects', as the forward search adds up to three; all of them for a term refit).
    """

    def __init__(
        self,
        problem: Problem,
        dt: float = 0.0025,
        effects: EffectSpace | None = None,
        free_effects: int | None = None,
    ):
        self.problem = problem.select("train")
        self.vehicle = problem.vehicle
        self.effects = effect_space() if effects is None else effects
        self.model = super_model(self.vehicle, self.effects, problem.longitudinal)
        self.space = make_space(self.vehicle, self.effects)
        self.dt = float(dt)
        self.solver = Solver(dt=self.dt)
        train = self.problem
        self.target = _Target(
            wm=self.windowed(train),
            measured=jnp.asarray(train.y),
            sigma=jnp.asarray(train.sigma),
            mask=jnp.asarray(train.train.astype(float)),
        )
        w = train.num_windows
        self.num_windows = w
        self.num_params = 6 + w + self.effects.num_params
        most = self.effects.max_pair_params if free_effects is None else int(free_effects)
        self.width = 6 + w + most
        self.num_residuals = int(train.train.sum()) * len(train.channels)
        e = self.effects
        self._z_eff_start = np.asarray(self.space.effects.to_unbounded(e.start, edge=EDGE))
        self.box = Box(
            jnp.concatenate([self.space.theta.low, self.space.effects.low]),
            jnp.concatenate([self.space.theta.high, self.space.effects.high]),
            (*PARAM_NAMES, *self.space.effects.names),
        )

    def windowed(self, problem: Problem) -> WindowedModel:
        """The super-model over the windows of `problem`."""
        return windowed_model(problem, solver=self.solver, model=self.model)

    def initial_z(self, theta0: np.ndarray | None = None) -> np.ndarray:
        prior = self.vehicle.default_prior()
        if theta0 is None:
            # Middle of the prior box in z (geometric for the stiffnesses).
            theta0 = np.array([np.sqrt(prior[n][0] * prior[n][1]) for n in PARAM_NAMES])
            theta0[0] = 0.5 * (prior["l_f"][0] + prior["l_f"][1])
        zt = np.asarray(self.space.theta.to_unbounded(np.asarray(theta0, float), edge=EDGE))
        return np.concatenate([zt, np.zeros(self.num_windows), self._z_eff_start])

    def _effect_index(self, effect: str) -> np.ndarray:
        """Indices in z of an effect's parameters."""
        s = self.effects.slices[effect]
        return 6 + self.num_windows + np.arange(s.start, s.stop)

    def active_mask(self, effects: Sequence[str]) -> np.ndarray:
        act = np.zeros(self.effects.num_params, dtype=bool)
        for e in effects:
            act[self.effects.slices[e]] = True
        return act

    def free_index(self, effects: Sequence[str], fix_theta: bool = False) -> np.ndarray:
        w = self.num_windows
        idx = [] if fix_theta else list(range(6))
        idx += list(range(6, 6 + w))
        for e in effects:
            idx += self._effect_index(e).tolist()
        return np.asarray(idx, dtype=int)

    def _on(self, problem: Problem | None):
        """(z layout map, windows not fitted) for predictions on `problem`'s windows: each
        index of the fitted z and where it sits in that problem's z; and the indices there
        of the initial-speed offsets of windows the fit did not see (at 0)."""
        if problem is None:
            return None, np.zeros(0, int)
        w, wt = self.num_windows, problem.num_windows
        where = {win: j for j, win in enumerate(problem.windows)}
        missing = [win for win in self.problem.windows if win not in where]
        if missing:
            raise ValueError(f"predict: fitted windows {missing} are not windows of the problem")
        to = np.concatenate(
            [
                np.arange(6),
                6 + np.array([where[win] for win in self.problem.windows], dtype=int),
                6 + wt + np.arange(self.effects.num_params),
            ]
        )
        fitted = set(to[6 : 6 + w].tolist())
        unseen = np.array([6 + j for j in range(wt) if 6 + j not in fitted], dtype=int)
        return to, unseen

    def _z_on(self, z, problem: Problem | None) -> np.ndarray:
        to, _ = self._on(problem)
        if to is None:
            return np.asarray(z)
        out = np.zeros(6 + problem.num_windows + self.effects.num_params)
        out[to] = z
        return out

    def predict(self, z, effects: Sequence[str], problem: Problem | None = None) -> np.ndarray:
        """(W, K, C) noise-free compared samples of the windows of `problem` (default: the
        fitted ones, truncated after the last training sample); windows the fit did not see
        start from their measured speed."""
        return self._linearised(z, effects, problem)[0]

    def _linearised(self, z, effects: Sequence[str], problem: Problem | None, free=()):
        """(readings, ∂readings/∂z[free]) on the windows of `problem` (`_linearised`), z on the
        fitted windows; `free` indexes z on `problem`'s windows."""
        act = jnp.asarray(self.active_mask(effects))
        wm = self.target.wm if problem is None else self.windowed(problem)
        z = jnp.asarray(self._z_on(z, problem))
        width = self.width + (0 if problem is None else problem.num_windows - self.num_windows)
        index = jnp.asarray(_padded(np.asarray(free, int), width, z.size))
        readings, jac = _linearised(wm, self.space, z, act, index)
        return np.asarray(readings), np.asarray(jac)[..., : len(free)]

    def prediction_variance(self, fit: DiscoveryFit, problem: Problem | None = None) -> np.ndarray:
        """(W, K, C) variance of `predict`'s samples that the fit's parameter uncertainty (its
        Laplace covariance, linearised) carries; the initial speeds of windows the fit did not
        see keep their prior std `V0_PRIOR_STD` (inflated like the fit's covariance)."""
        to, unseen = self._on(problem)
        free, cov = (fit.free, fit.cov) if to is None else (to[fit.free], fit.cov)
        if unseen.size:
            k = len(free)
            grown = np.zeros((k + unseen.size,) * 2)
            grown[:k, :k] = cov
            grown[k:, k:] = np.eye(unseen.size) * V0_PRIOR_STD**2 * max(1.0, fit.chi2_dof)
            free, cov = np.concatenate([free, unseen]), grown
        jac = self._linearised(fit.z, fit.effects, problem, free)[1]
        return np.einsum("...k,kl,...l->...", jac, cov, jac)

    def fit(
        self,
        effects: Sequence[str] = (),
        z0: np.ndarray | None = None,
        *,
        max_iter: int = 30,
        fix_theta: bool = False,
        noise: SensorNoise | ModelError = ModelError(),
    ) -> DiscoveryFit:
        """The estimator's fit (`fit_likelihood`) of θ and the `effects`' parameters on the
        training part, the other effects at their null values.

        `z0` warm-starts (e.g. from the base fit), its start speeds included; entries of newly
        activated effects are reset to their starting values. `noise`: re-measured after each
        pass (`ModelError`, as identify fits) or held (`ModelError(passes=0, start=...)`, a
        search's candidates weighed alike).
        """
        effects = tuple(effects)
        z = self.initial_z() if z0 is None else np.array(z0, dtype=float)
        for e in effects:
            i = self._effect_index(e)
            if z0 is None or not np.isfinite(z[i]).all():
                z[i] = self._z_eff_start[self.effects.slices[e]]
        w = self.num_windows
        zt, zv, ze = z[:6], z[6 : 6 + w], z[6 + w :]
        act = self.active_mask(effects)
        eff = np.where(act, np.asarray(self.space.effects.from_unbounded(ze)), self.effects.null)
        start = np.concatenate([np.asarray(self.space.theta.from_unbounded(zt)), eff])
        names = self.box.names
        free = ([] if fix_theta else list(PARAM_NAMES)) + [names[6 + i] for i in np.flatnonzero(act)]
        problem = dataclasses.replace(self.problem, v0=np.asarray(self.problem.v0) + zv)
        post = fit_likelihood(
            problem,
            start,
            self.box,
            model=self.model,
            free=free,
            noise=noise,
            max_steps=max_iter,
            solver=self.solver,
            width=self.width - w,
        )
        return self._result(effects, z, post, act)

    def _result(self, effects, z, post, act) -> DiscoveryFit:
        """`post` in the search's layout (see the module docstring)."""
        w, z = self.num_windows, z.copy()
        idx = np.asarray([post.names.index(n) for n in post.free], dtype=int)
        n_t = int(np.sum(idx < 6))
        corrected = post.jacobian.shape[-1] > len(idx)
        z[idx[:n_t]] = post.z[idx[:n_t]]
        z[6 + w + idx[n_t:] - 6] = post.z[idx[n_t:]]
        if corrected:
            z[6 : 6 + w] += post.v0_offset
        sigma = np.asarray(self.problem.sigma, float)
        jac_t, jac_e = post.jacobian[..., :n_t], post.jacobian[..., n_t : len(idx)]
        jac_v = post.jacobian[..., len(idx) :]
        free = np.concatenate([idx[:n_t], 6 + np.arange(w if corrected else 0), 6 + w + idx[n_t:] - 6])
        jac = np.concatenate([jac_t, jac_v, jac_e], axis=-1) / sigma[:, None]
        # The start speeds' variances from their own information (each moves its own window).
        std = post.noise.std
        var_v = 1.0 / (np.sum((jac_v / std[:, None]) ** 2, axis=(1, 2)).diagonal() + V0_PRIOR_STD**-2)
        cov_te = post.cov_z[np.ix_(idx, idx)]
        cov = np.zeros((len(free),) * 2)
        order = np.r_[np.arange(n_t), len(idx) + np.arange(jac_v.shape[-1]), n_t + np.arange(len(idx) - n_t)]
        inv = np.argsort(order)
        cov[np.ix_(inv[: len(idx)], inv[: len(idx)])] = cov_te
        if corrected:
            cov[inv[len(idx) :], inv[len(idx) :]] = np.atleast_1d(var_v)
        sd = np.sqrt(np.clip(np.diag(post.cov_z), 0, None))
        theta_box, eff_box = self.space.theta, self.space.effects
        theta = np.asarray(post.theta[:6])
        theta_std = np.asarray(theta_box.dtheta_dz(post.z[:6])) * sd[:6]
        ze = post.z[6:]
        values, stds = np.asarray(eff_box.from_unbounded(ze)), np.asarray(eff_box.dtheta_dz(ze)) * sd[6:]
        params, spread = {}, {}
        for e in effects:
            s = self.effects.slices[e]
            names = self.effects.classes[e].param_names
            params[e] = {n: float(v) for n, v in zip(names, values[s])}
            spread[e] = {n: float(v) for n, v in zip(names, stds[s])}
        r = post.residual / sigma
        return DiscoveryFit(
            effects=tuple(effects),
            z=z,
            theta=theta,
            theta_std=theta_std,
            v0=np.asarray(self.problem.v0) + z[6 : 6 + w],
            effect_params=params,
            effect_std=spread,
            chi2=float(np.sum(r**2)),
            num_samples=self.num_residuals,
            num_params=len(free),
            residual=r.reshape(-1),
            jacobian=jac.reshape(-1, len(free)),
            free=free,
            iterations=int(sum(post.steps)),
            converged=bool(post.converged),
            cov=cov,
            rss=np.sum(post.residual**2, axis=(0, 1)),
            noise=post.noise,
            theta_interval=post.interval(0.9)[:6],
        )
