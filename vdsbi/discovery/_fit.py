"""Candidate explanations fitted with the one estimator (`vdsbi.estimation.fit_likelihood`).

One *super-model* with every candidate effect enabled is built once per `Fitter`; a candidate
explanation is which effects are active: the others' parameters sit exactly at their null values,
where they vanish, so every candidate's fit runs one compiled program (the free coordinates padded
to one width). The effects, their fit bounds and starting values are read from the registry
(`vdsbi.simulator.effects.EFFECTS`, each effect's `bounds` and `start`) when a `Fitter` is built, so an
effect added with `register_effect` is searched like a built-in one.

A `DiscoveryFit` is the estimator's posterior seen in the search's coordinates: a `Point` (θ,
the start-speed offsets and every effect's parameters, unbounded), the residual whitened by the
sensor noise (what the misspecification test holds against noise), and the per-channel residual
and noise model the evidence is computed with (`vdsbi.discovery._rank`).
"""

from __future__ import annotations

import dataclasses
from collections.abc import Sequence

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Bool, Float

from ..estimation import V0_STD, FitRequest, ModelError, SensorNoise, fit_likelihood
from ..problem import Box, Problem, WindowedModel, parameter_names, windowed_model
from ..problem.points import Point, Space, free_positions, gather, padded, positions, scatter
from ..simulator import PARAM_NAMES, Vehicle, make_model
from ..simulator.effects import EFFECTS
from ..simulator.models import AbstractVehicleModel, LongitudinalMode, model_class
from ..simulator.solvers import Solver
from ._candidates import EffectSpace, effect_space
from ._results import DiscoveryFit

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


def make_space(vehicle: Vehicle, effects: EffectSpace) -> Space:
    names = parameter_names([effects.classes[e] for e in effects.names])[len(PARAM_NAMES) :]
    return Space(
        theta=Box.from_dict(vehicle.default_prior(), PARAM_NAMES),
        effects=Box(jnp.asarray(effects.lo), jnp.asarray(effects.hi), names),
        slices=tuple((s.start, s.stop) for s in effects.slices.values()),
    )


class _Target(eqx.Module):
    """The fitted samples: the windowed super-model and what it is compared with; `null`, the
    values at which every effect vanishes (where inactive effects are held)."""

    wm: WindowedModel
    measured: Float[Array, "W K C"]
    sigma: Float[Array, " C"]
    mask: Float[Array, "W K"]
    null: Float[Array, " E"]


def _readings(wm: WindowedModel, space: Space, z: Point, null, active: Bool[Array, " E"]):
    """The compared samples of every window at z, the effects not `active` held at their `null`
    values; each window starts from its measured speed plus its fitted offset."""
    free = Point(jnp.ones(jnp.shape(z.theta), bool), jnp.ones(jnp.shape(z.v0), bool), active)
    theta, effect_params = space.values(z, Point(z.theta, z.v0, null), free)
    ys, _ = wm(theta, effect_params, v0=wm.v0 + z.v0)
    return ys


def whitened(space: Space, target: _Target, z: Point, active):
    r = (_readings(target.wm, space, z, target.null, active) - target.measured) / target.sigma
    r = jnp.where(target.mask[:, :, None] > 0, r, 0.0)
    return r.reshape(-1)


@eqx.filter_jit
def _linearised(wm, space, z: Point, null, active, free):
    """The readings at z and their derivative by z's flattened entries `free` (padded:
    `padded`, its slots give zero columns); one program serves predictions and their variances."""
    fn = lambda y: (r := _readings(wm, space, scatter(z, free, y), null, active), r)
    jac, readings = jax.jacfwd(fn, has_aux=True)(gather(z, free))
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
            null=jnp.asarray(self.effects.null),
        )
        w = train.num_windows
        self.num_windows = w
        self.num_params = len(PARAM_NAMES) + w + self.effects.num_params
        most = self.effects.max_pair_params if free_effects is None else int(free_effects)
        self.width = len(PARAM_NAMES) + w + most
        self.num_residuals = int(train.train.sum()) * len(train.channels)
        e = self.effects
        self._z_eff_start = np.asarray(self.space.effects.to_unbounded(e.start, edge=EDGE))
        self.box = self.space.box

    def windowed(self, problem: Problem) -> WindowedModel:
        """The super-model over the windows of `problem`."""
        return windowed_model(problem, solver=self.solver, model=self.model)

    def initial_z(self, theta0: np.ndarray | None = None) -> Point:
        prior = self.vehicle.default_prior()
        if theta0 is None:
            # Middle of the prior box in z (geometric for the stiffnesses).
            theta0 = np.array([np.sqrt(prior[n][0] * prior[n][1]) for n in PARAM_NAMES])
            theta0[PARAM_NAMES.index("l_f")] = 0.5 * (prior["l_f"][0] + prior["l_f"][1])
        zt = np.asarray(self.space.theta.to_unbounded(np.asarray(theta0, float), edge=EDGE))
        return Point(zt, np.zeros(self.num_windows), self._z_eff_start.copy()).numpy()

    def active_mask(self, effects: Sequence[str]) -> np.ndarray:
        act = np.zeros(self.effects.num_params, dtype=bool)
        for e in effects:
            act[self.effects.slices[e]] = True
        return act

    def free_mask(self, effects: Sequence[str], fix_theta: bool = False, v0: bool = True) -> Point:
        """The entries a fit of `effects` frees: θ (unless `fix_theta`), the start speeds (if
        `v0`) and the effects' parameters."""
        return Point(
            np.full(len(PARAM_NAMES), not fix_theta),
            np.full(self.num_windows, v0),
            self.active_mask(effects),
        )

    def free_index(self, effects: Sequence[str], fix_theta: bool = False) -> np.ndarray:
        """`free_mask`'s entries as indices in the flattened point."""
        return free_positions(self.free_mask(effects, fix_theta))

    def effect_positions(self, effect: str) -> np.ndarray:
        """Indices in the flattened point of an effect's parameters."""
        return positions(self._shape(self.num_windows)).effects[self.effects.slices[effect]]

    def _on(self, problem: Problem | None):
        """(where the fitted point's entries sit in the flattened point on `problem`'s windows,
        the indices there of the start-speed offsets of windows the fit did not see (at 0))."""
        if problem is None:
            return None, np.zeros(0, int)
        where = self._windows_on(problem)
        target = positions(self._shape(problem.num_windows))
        to = Point(target.theta, target.v0[where], target.effects)
        unseen = np.setdiff1d(target.v0, target.v0[where])
        return np.concatenate(jax.tree.leaves(to)), unseen

    def _shape(self, num_windows: int) -> Point:
        """A point of zeros over `num_windows` windows: where each entry sits, nothing more."""
        return Point(np.zeros(len(PARAM_NAMES)), np.zeros(num_windows), np.zeros(self.effects.num_params))

    def _windows_on(self, problem: Problem) -> np.ndarray:
        """Where each fitted window sits among `problem`'s windows."""
        where = {win: j for j, win in enumerate(problem.windows)}
        missing = [win for win in self.problem.windows if win not in where]
        if missing:
            raise ValueError(f"predict: fitted windows {missing} are not windows of the problem")
        return np.array([where[win] for win in self.problem.windows], dtype=int)

    def _z_on(self, z: Point, problem: Problem | None) -> Point:
        """z on `problem`'s windows: windows the fit did not see start from their measured speed."""
        if problem is None:
            return z
        v0 = np.zeros(problem.num_windows)
        v0[self._windows_on(problem)] = z.v0
        return Point(z.theta, v0, z.effects)

    def predict(self, z: Point, effects: Sequence[str], problem: Problem | None = None) -> np.ndarray:
        """(W, K, C) noise-free compared samples of the windows of `problem` (default: the
        fitted ones, truncated after the last training sample); windows the fit did not see
        start from their measured speed."""
        return self._linearised(z, effects, problem)[0]

    def _linearised(self, z, effects: Sequence[str], problem: Problem | None, free=()):
        """(readings, ∂readings/∂z[free]) on the windows of `problem` (`_linearised`), z on the
        fitted windows; `free` indexes z on `problem`'s windows."""
        act = jnp.asarray(self.active_mask(effects))
        wm = self.target.wm if problem is None else self.windowed(problem)
        z = self._z_on(z, problem).jax()
        width = self.width + (0 if problem is None else problem.num_windows - self.num_windows)
        size = sum(leaf.size for leaf in jax.tree.leaves(z))
        index = jnp.asarray(padded(np.asarray(free, int), width, size))
        readings, jac = _linearised(wm, self.space, z, self.target.null, act, index)
        return np.asarray(readings), np.asarray(jac)[..., : len(free)]

    def prediction_variance(self, fit: DiscoveryFit, problem: Problem | None = None) -> np.ndarray:
        """(W, K, C) variance of `predict`'s samples that the fit's parameter uncertainty (its
        Laplace covariance, linearised) carries; the initial speeds of windows the fit did not
        see keep their prior std `V0_STD` (inflated like the fit's covariance)."""
        to, unseen = self._on(problem)
        free, cov = (fit.free, fit.cov) if to is None else (to[fit.free], fit.cov)
        if unseen.size:
            k = len(free)
            grown = np.zeros((k + unseen.size,) * 2)
            grown[:k, :k] = cov
            grown[k:, k:] = np.eye(unseen.size) * V0_STD**2 * max(1.0, fit.chi2_dof)
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
        z = self.initial_z() if z0 is None else z0.numpy()
        for e in effects:
            i = self.effects.slices[e]
            if z0 is None or not np.isfinite(z.effects[i]).all():
                z.effects[i] = self._z_eff_start[i]
        act = self.active_mask(effects)
        eff = np.where(act, np.asarray(self.space.effects.from_unbounded(z.effects)), self.effects.null)
        start = np.concatenate([np.asarray(self.space.theta.from_unbounded(z.theta)), eff])
        free = ([] if fix_theta else list(PARAM_NAMES)) + [
            self.space.effects.names[i] for i in np.flatnonzero(act)
        ]
        problem = dataclasses.replace(self.problem, v0=np.asarray(self.problem.v0) + z.v0)
        post = fit_likelihood(
            problem,
            start,
            self.box,
            FitRequest(free=free, noise=noise, max_steps=max_iter, width=self.width - self.num_windows),
            model=self.model,
            solver=self.solver,
        )
        return self._result(effects, z, post)

    def _result(self, effects, z: Point, post) -> DiscoveryFit:
        """`post` (in the estimator's box: θ, then the effects' parameters) as a `DiscoveryFit`."""
        nt = len(PARAM_NAMES)
        fitted = [post.names.index(n) for n in post.free]
        it = np.array([i for i in fitted if i < nt], dtype=int)  # free θ, in the box
        ie = np.array([i - nt for i in fitted if i >= nt], dtype=int)  # free effect entries
        corrected = post.jacobian.shape[-1] > len(fitted)
        z.theta[it] = post.z[it]
        z.effects[ie] = post.z[nt + ie]
        if corrected:
            z.v0[:] += post.v0_offset
        mask = Point(
            np.isin(np.arange(nt), it),
            np.full(self.num_windows, corrected),
            np.isin(np.arange(z.effects.size), ie),
        )
        free = free_positions(mask)
        # The estimator's columns are (free θ, free effects, start speeds); the point's order is
        # (θ, start speeds, effects).
        k_t, k_e = it.size, ie.size
        k_v = post.jacobian.shape[-1] - k_t - k_e
        jac_t, jac_e, jac_v = np.split(post.jacobian, [k_t, k_t + k_e], axis=-1)
        sigma = np.asarray(self.problem.sigma, float)
        jac = np.concatenate([jac_t, jac_v, jac_e], axis=-1) / sigma[:, None]
        # The start speeds' variances from their own information (each moves its own window).
        std = post.noise.std
        var_v = 1.0 / (np.sum((jac_v / std[:, None]) ** 2, axis=(1, 2)).diagonal() + V0_STD**-2)
        te = np.r_[np.arange(k_t), k_t + k_v + np.arange(k_e)]
        cov = np.zeros((len(free),) * 2)
        cov[np.ix_(te, te)] = post.cov_z[np.ix_(fitted, fitted)]
        if corrected:
            v = k_t + np.arange(k_v)
            cov[v, v] = np.atleast_1d(var_v)
        sd = np.sqrt(np.clip(np.diag(post.cov_z), 0, None))
        theta_box, eff_box = self.space.theta, self.space.effects
        theta = np.asarray(post.theta[:nt])
        theta_std = np.asarray(theta_box.dtheta_dz(post.z[:nt])) * sd[:nt]
        ze = post.z[nt:]
        values, stds = np.asarray(eff_box.from_unbounded(ze)), np.asarray(eff_box.dtheta_dz(ze)) * sd[nt:]
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
            v0=np.asarray(self.problem.v0) + z.v0,
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
            theta_interval=post.interval(0.9)[:nt],
        )
