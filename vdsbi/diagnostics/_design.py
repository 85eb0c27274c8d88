"""Excitation design: a differentiable maneuver optimised for Fisher information.

The maneuver is a `Maneuver` within `Limits` (see `_maneuver`), inside the hard limits on
steer, torques and initial speed by construction. The limits that depend on the response —
|ay| ≤ ay_fraction·μ·g and vx inside the speed window — are penalised through the simulated
readings, and `design_maneuver` returns the best iterate that satisfies every limit exactly
(the initial maneuver must, and is checked); `check_limits` checks every limit on a simulated
maneuver.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import optax
from jaxtyping import Array, Float

from ..simulator import CHANNELS, NOMINAL_THETA, PARAM_NAMES, SEED_CHANNELS, Inputs, solve
from ..simulator.measurement import SensorNoise
from ..simulator.models import AbstractVehicleModel
from ..simulator.solvers import RK4, AbstractSolver
from ._fisher import MeasuredNoise, channel_noise, scaled_fisher
from ._maneuver import Limits, Maneuver

_AY = CHANNELS.index("ay")
_VX = CHANNELS.index("vx")


class Objective(NamedTuple):
    """Value of a design (larger is better) and what it is made of."""

    value: Float[Array, ""]
    information: Float[Array, ""]
    penalty: Float[Array, ""]
    ay_excess: Float[Array, ""]
    speed_excess: Float[Array, ""]
    ok: Float[Array, ""]


class DesignProblem(eqx.Module):
    """Everything fixed while a maneuver is optimised.

    Attributes:
        model: vehicle model.
        theta: (6,) where the information is evaluated (physical units).
        limits: what the maneuver may do.
        channels: measured channels (indices into CHANNELS), static.
        relative, additive: noise model per used channel.
        target: index into PARAM_NAMES of the parameter whose bound is minimised, or −1 for
            D-optimal (maximise log det F).
        penalty_weight: weight of the squared limit violations (relative to their limit).
        margin: the penalty acts on ay and speed limits tightened by this fraction; feasibility
            is judged on the true limits.
        floor_fraction: relative-noise floor.
        solver: integration settings used while optimising.
    """

    model: AbstractVehicleModel
    theta: Float[Array, "6"]
    limits: Limits
    channels: tuple[int, ...] = eqx.field(static=True)
    relative: Float[Array, " C"]
    additive: Float[Array, " C"]
    target: int = eqx.field(static=True, default=-1)
    penalty_weight: float = eqx.field(static=True, default=1e3)
    margin: float = eqx.field(static=True, default=0.02)
    floor_fraction: float = eqx.field(static=True, default=0.1)
    solver: AbstractSolver = RK4(dt=0.005)

    @property
    def scale(self):
        return jnp.asarray([NOMINAL_THETA[n] for n in PARAM_NAMES], dtype=self.theta.dtype)

    def fisher_scaled(self, inputs: Inputs, v0) -> tuple[Float[Array, "6 6"], Float[Array, "T 6"], Array]:
        """Scaled F (θ/nominal), full readings, success flag."""
        f = scaled_fisher(
            self.model,
            self.theta / self.scale,
            self.scale,
            inputs,
            v0,
            MeasuredNoise(jnp.asarray(self.channels), self.relative, self.additive, self.floor_fraction),
            self.solver,
        )
        return f.fim, f.readings, f.ok

    def information(self, fz):
        if self.target < 0:
            return jnp.linalg.slogdet(fz)[1]
        e = jnp.zeros(fz.shape[0], fz.dtype).at[self.target].set(1.0)
        return -jnp.log(jnp.linalg.solve(fz, e)[self.target])

    def __call__(self, maneuver: Maneuver) -> Objective:
        lim = self.limits
        inputs = maneuver.inputs(lim)
        fz, ys, ok = self.fisher_scaled(inputs, maneuver.initial_speed(lim))
        info = self.information(fz)
        ay_max = lim.ay_max(self.model.vehicle.friction)
        ay_ex = jnp.max(jnp.abs(ys[:, _AY])) / ay_max - 1.0
        vx = ys[:, _VX]
        sp_ex = jnp.maximum(jnp.max(vx) / lim.v_max - 1.0, 1.0 - jnp.min(vx) / lim.v_min)
        # Soft violation measure: mean squared relative excess over the samples, against limits
        # tightened by `margin` so that iterates hovering at the penalty's edge stay feasible.
        m = self.margin
        pen = jnp.mean(jax.nn.relu(jnp.abs(ys[:, _AY]) / (ay_max * (1 - m)) - 1.0) ** 2)
        pen = pen + jnp.mean(
            jax.nn.relu(vx / (lim.v_max * (1 - m)) - 1.0) ** 2
            + jax.nn.relu(1.0 - vx / (lim.v_min * (1 + m))) ** 2
        )
        value = info - self.penalty_weight * pen
        value = jnp.where(ok & jnp.isfinite(value), value, -jnp.inf)
        return Objective(value, info, pen, ay_ex, sp_ex, ok)


def design_problem(
    model: AbstractVehicleModel,
    theta,
    limits: Limits = Limits(),
    *,
    target: str | None = "C_kappa_r",
    channels=SEED_CHANNELS,
    noise: SensorNoise | None = None,
    solver: AbstractSolver = RK4(dt=0.005),
    penalty_weight: float = 1e3,
) -> DesignProblem:
    """Build a `DesignProblem`; `target=None` means D-optimal (log det F)."""
    if target is not None and target not in PARAM_NAMES:
        raise ValueError(f"design: unknown target '{target}' (one of {PARAM_NAMES} or None)")
    rel, add = channel_noise(noise, channels)
    return DesignProblem(
        model=model,
        theta=jnp.asarray(theta, dtype=float),
        limits=limits,
        channels=tuple(CHANNELS.index(c) for c in channels),
        relative=jnp.asarray(rel),
        additive=jnp.asarray(add),
        target=-1 if target is None else PARAM_NAMES.index(target),
        penalty_weight=penalty_weight,
        solver=solver,
    )


class DesignResult(NamedTuple):
    """Outcome of `design`.

    Attributes:
        maneuver: best feasible maneuver found.
        initial: the start.
        history: per step (objective value, information, penalty, feasible) as numpy arrays.
        best_step: number of optimiser updates behind `maneuver` (0: the start itself).
    """

    maneuver: Maneuver
    initial: Maneuver
    history: dict
    best_step: int


def feasible(obj: Objective, tol: float = 0.0) -> bool:
    return bool(obj.ok) and float(obj.ay_excess) <= tol and float(obj.speed_excess) <= tol


def design_maneuver(
    problem: DesignProblem,
    initial: Maneuver,
    *,
    num_steps: int = 100,
    learning_rate: float = 0.05,
    callback=None,
) -> DesignResult:
    """Gradient ascent (Adam, cosine-decayed step size) on the penalised information objective.

    One jitted step (value, gradient and update inside). Returns the best iterate that meets
    every limit exactly; raises ValueError if the initial maneuver does not.

    Args:
        problem: the design problem.
        initial: starting maneuver.
        num_steps: optimiser steps.
        learning_rate: initial Adam step size (the parameters are O(1)); decays to a tenth.
        callback: optional f(step, Objective) called after every evaluation.
    """
    # Strong-typed float leaves: a weak-typed start would make the second step recompile.
    dtype = jnp.result_type(float)
    initial = jax.tree.map(lambda x: jnp.array(x, dtype=dtype), initial)
    man, state = initial, _OPT.init(eqx.filter(initial, eqx.is_inexact_array))
    lr = jnp.array(learning_rate, dtype=dtype)
    best, best_val, best_step = initial, -math.inf, -1
    hist = {"value": [], "information": [], "penalty": [], "feasible": []}
    for i in range(num_steps + 1):
        prev = man
        # Cosine decay to a tenth of the step size: settles the iterate against the limits.
        decay = 0.1 + 0.9 * 0.5 * (1 + math.cos(math.pi * min(i, num_steps) / max(num_steps, 1)))
        man, state, obj = _step(problem, man, state, lr * decay)
        # `obj` was evaluated at `prev`.
        feas = feasible(obj)
        if i == 0 and not feas:
            raise ValueError(
                f"design: the initial maneuver violates the limits (ay excess {float(obj.ay_excess):+.3f}, "
                f"speed excess {float(obj.speed_excess):+.3f}, solve ok {bool(obj.ok)})"
            )
        hist["value"].append(float(obj.value))
        hist["information"].append(float(obj.information))
        hist["penalty"].append(float(obj.penalty))
        hist["feasible"].append(feas)
        if feas and float(obj.information) > best_val:
            best, best_val, best_step = prev, float(obj.information), i
        if callback is not None:
            callback(i, obj)
    return DesignResult(best, initial, {k: np.asarray(v) for k, v in hist.items()}, best_step)


def _neg(obj: Objective):
    return -obj.value, obj


#: Adam without its step size (applied in `_step`, so the jitted step is shared by all calls).
_OPT = optax.chain(optax.clip_by_global_norm(10.0), optax.scale_by_adam())


@eqx.filter_jit
def _step(problem: DesignProblem, man: Maneuver, state, lr):
    """One ascent step; returns the new maneuver, optimiser state and the Objective at `man`."""
    (_, obj), grad = eqx.filter_value_and_grad(lambda m: _neg(problem(m)), has_aux=True)(man)
    grad = jax.tree.map(lambda g: jnp.where(jnp.isfinite(g), g, 0.0), grad)
    updates, state = _OPT.update(grad, state, man)
    updates = jax.tree.map(lambda u: -lr * u, updates)
    return eqx.apply_updates(man, updates), state, obj


def check_limits(
    model: AbstractVehicleModel,
    theta,
    inputs: Inputs,
    v0: float,
    limits: Limits,
    solver: AbstractSolver = RK4(),
) -> dict:
    """Every limit checked on the simulated maneuver (default solver): values and verdicts."""
    ys, ok = solve(model, jnp.asarray(theta, dtype=float), inputs, jnp.asarray(v0, dtype=float), (), solver)
    ys = np.asarray(ys)
    ay_max = limits.ay_max(model.vehicle.friction)
    tf, tr = np.asarray(inputs.torque_front), np.asarray(inputs.torque_rear)
    brake_total = np.maximum(-np.minimum(tf, 0), 0) + np.maximum(-np.minimum(tr, 0), 0)
    rep = {
        "solve_ok": bool(ok),
        "max_abs_ay": float(np.abs(ys[:, _AY]).max()),
        "ay_limit": ay_max,
        "vx_range": [float(ys[:, _VX].min()), float(ys[:, _VX].max())],
        "speed_window": [limits.v_min, limits.v_max],
        "max_abs_steer": float(np.abs(np.asarray(inputs.steer)).max()),
        "steer_limit": limits.max_steer,
        "max_drive_torque": float(max(tf.max(), 0.0)),
        "drive_limit": limits.max_drive,
        "max_brake_torque": float(brake_total.max()),
        "brake_limit": limits.max_brake,
        "max_rear_drive_torque": float(max(tr.max(), 0.0)),
    }
    eps = 1e-9
    rep["respected"] = bool(
        rep["solve_ok"]
        and rep["max_abs_ay"] <= ay_max * (1 + eps)
        and limits.v_min * (1 - eps) <= rep["vx_range"][0]
        and rep["vx_range"][1] <= limits.v_max * (1 + eps)
        and rep["max_abs_steer"] <= limits.max_steer * (1 + eps)
        and rep["max_drive_torque"] <= limits.max_drive * (1 + eps)
        and rep["max_brake_torque"] <= limits.max_brake * (1 + eps)
        and rep["max_rear_drive_torque"] <= eps
    )
    return rep
