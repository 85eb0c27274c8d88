"""Excitation design: a differentiable maneuver optimised for Fisher information.

A `Maneuver` holds unconstrained parameters; `Maneuver.inputs(limits)` maps them onto the
sample grid inside the hard limits by construction:

  * steer(t) = max_steer · tanh(Σ_k a_k sin(2π f_k t + φ_k)), f_k ∈ [f_min, f_max] (the
    `vdsbi.problem.Box` `Limits.frequencies`);
  * a pedal level ℓ(t) ∈ [−1, 1]: M segments whose lengths are a softmax share of the
    duration and whose levels are tanh-bounded, joined by sigmoid edges of width
    `edge_time`; ℓ > 0 drives the front axle (ℓ·max_drive; front-wheel drive), ℓ < 0 brakes
    with the vehicle's fixed brake balance (front share ℓ·max_brake·front_share, rear the rest);
  * v0 ∈ [v0_min, v0_max] (`Limits.speeds`).

The limits that depend on the response — |ay| ≤ ay_fraction·μ·g and vx inside the speed
window — are penalised through the simulated readings, and `design_maneuver` returns the best
iterate that satisfies every limit exactly (the initial maneuver must, and is checked).
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

from ..problem import Box
from ..simulator import (
    CHANNELS,
    GRAVITY,
    NOMINAL_THETA,
    PARAM_NAMES,
    RK4,
    SEED_CHANNELS,
    AbstractSolver,
    AbstractVehicleModel,
    Inputs,
    solve,
)
from ._fisher import noise_model, scaled_fisher

_AY = CHANNELS.index("ay")
_VX = CHANNELS.index("vx")


class Limits(eqx.Module):
    """What a test drive may do. Units SI; all static (they fix the design problem).

    Attributes:
        duration: maneuver length, s.
        rate: sample rate, Hz.
        max_steer: |road-wheel angle|, rad.
        max_drive: front-axle drive torque, N·m.
        max_brake: total brake torque, N·m.
        brake_front_share: the vehicle's brake balance (not a design variable).
        ay_fraction: |ay| ≤ ay_fraction·μ·g.
        v_min, v_max: speed window for vx over the whole maneuver, m/s.
        v0_min, v0_max: range of the initial speed, m/s.
        f_min, f_max: steer frequency range, Hz.
        edge_time: pedal transition time (10 % to 90 %), s.
    """

    duration: float = eqx.field(static=True, default=5.0)
    rate: float = eqx.field(static=True, default=200.0)
    max_steer: float = eqx.field(static=True, default=0.1)
    max_drive: float = eqx.field(static=True, default=900.0)
    max_brake: float = eqx.field(static=True, default=1800.0)
    brake_front_share: float = eqx.field(static=True, default=0.65)
    ay_fraction: float = eqx.field(static=True, default=0.6)
    v_min: float = eqx.field(static=True, default=5.0)
    v_max: float = eqx.field(static=True, default=20.0)
    v0_min: float = eqx.field(static=True, default=5.0)
    v0_max: float = eqx.field(static=True, default=20.0)
    f_min: float = eqx.field(static=True, default=0.1)
    f_max: float = eqx.field(static=True, default=2.0)
    edge_time: float = eqx.field(static=True, default=0.1)

    def __check_init__(self):
        if not (0 < self.v_min <= self.v0_min < self.v0_max <= self.v_max):
            raise ValueError("limits: need 0 < v_min <= v0_min < v0_max <= v_max")
        if not (0 < self.f_min < self.f_max):
            raise ValueError("limits: need 0 < f_min < f_max")
        for name in ("duration", "rate", "max_steer", "max_drive", "max_brake", "ay_fraction", "edge_time"):
            if not getattr(self, name) > 0:
                raise ValueError(f"limits: '{name}' must be > 0")
        if not 0 <= self.brake_front_share <= 1:
            raise ValueError("limits: 'brake_front_share' must lie in [0, 1]")

    def frequencies(self, num: int) -> Box:
        """The box of `num` steer frequencies, [f_min, f_max] Hz each."""
        names = tuple(f"frequency_{k}" for k in range(num))
        return Box(np.full(num, float(self.f_min)), np.full(num, float(self.f_max)), names)

    def speeds(self) -> Box:
        """The box of the initial speed, [v0_min, v0_max] m/s."""
        return Box(np.array([float(self.v0_min)]), np.array([float(self.v0_max)]), ("v0",))

    @property
    def num_samples(self) -> int:
        return int(round(self.duration * self.rate)) + 1

    def ay_max(self, friction: float) -> float:
        return self.ay_fraction * friction * GRAVITY


class Maneuver(eqx.Module):
    """Unconstrained maneuver parameters (map them with `inputs` / `initial_speed`).

    Attributes:
        steer_amp: (K,) sine amplitudes before the tanh bound (units of max_steer).
        steer_freq: (K,) unconstrained frequencies (sigmoid into [f_min, f_max]).
        steer_phase: (K,) phases, rad.
        pedal_level: (M,) unconstrained levels (tanh into [−1, 1]).
        pedal_length: (M,) unconstrained segment lengths (softmax share of the duration).
        v0: unconstrained initial speed (sigmoid into [v0_min, v0_max]).
    """

    steer_amp: Float[Array, " K"]
    steer_freq: Float[Array, " K"]
    steer_phase: Float[Array, " K"]
    pedal_level: Float[Array, " M"]
    pedal_length: Float[Array, " M"]
    v0: Float[Array, ""]

    @classmethod
    def seed_like(cls, limits: Limits, num_sines: int = 3, num_segments: int = 4) -> Maneuver:
        """A start close to the seed's maneuver at 10.5 m/s: 0.05 rad steer at 0.25 Hz
        (small extra sines at 0.5 and 1 Hz), drive then brake at the seed's levels."""
        f = np.array([0.25, 0.5, 1.0, 1.5, 0.75, 0.35][:num_sines])
        amp = np.zeros(num_sines)
        amp[0] = math.atanh(min(0.05 / limits.max_steer, 0.99))
        amp[1:] = 0.05
        drive = min(600.0 / limits.max_drive, 0.99)
        brake = min(1200.0 / limits.max_brake, 0.99)
        levels = np.array([drive if i < num_segments // 2 else -brake for i in range(num_segments)])
        return cls(
            steer_amp=jnp.asarray(amp),
            steer_freq=limits.frequencies(num_sines).to_unbounded(f, edge=1e-6),
            steer_phase=jnp.zeros(num_sines),
            pedal_level=jnp.asarray(np.arctanh(levels)),
            pedal_length=jnp.zeros(num_segments),
            v0=limits.speeds().to_unbounded(jnp.array([10.5]), edge=1e-6)[0],
        )

    def initial_speed(self, limits: Limits) -> Float[Array, ""]:
        return limits.speeds().from_unbounded(self.v0[None])[0]

    def pedal(self, limits: Limits) -> Float[Array, " T"]:
        """ℓ(t) ∈ [−1, 1] on the sample grid."""
        t = jnp.arange(limits.num_samples) / limits.rate
        share = jax.nn.softmax(self.pedal_length)
        edges = limits.duration * jnp.concatenate([jnp.zeros(1), jnp.cumsum(share)])
        # Segment m weight: σ((t − e_m)/w) − σ((t − e_{m+1})/w), with the outer edges pushed
        # out so the first and last segments start and end at full weight.
        inner = edges[1:-1]
        w = limits.edge_time / 4.4  # σ rises 10 % → 90 % over 4.4·w = edge_time
        rise = jax.nn.sigmoid((t[None] - inner[:, None]) / w)  # (M−1, T)
        ones, zeros = jnp.ones_like(t)[None], jnp.zeros_like(t)[None]
        up = jnp.concatenate([ones, rise])
        down = jnp.concatenate([rise, zeros])
        return jnp.tanh(self.pedal_level) @ (up - down)

    def inputs(self, limits: Limits) -> Inputs:
        t = jnp.arange(limits.num_samples) / limits.rate
        freq = limits.frequencies(self.steer_freq.shape[0]).from_unbounded(self.steer_freq)
        s = jnp.sum(
            self.steer_amp[:, None] * jnp.sin(2 * jnp.pi * freq[:, None] * t + self.steer_phase[:, None]), 0
        )
        steer = limits.max_steer * jnp.tanh(s)
        lev = self.pedal(limits)
        drive, brake = jax.nn.relu(lev), jax.nn.relu(-lev)
        tf = limits.max_drive * drive - limits.max_brake * limits.brake_front_share * brake
        tr = -limits.max_brake * (1 - limits.brake_front_share) * brake
        return Inputs(0.0, 1.0 / limits.rate, steer, tf, tr)

    def describe(self, limits: Limits) -> dict:
        freq = limits.frequencies(self.steer_freq.shape[0]).from_unbounded(self.steer_freq)
        share = jax.nn.softmax(self.pedal_length)
        return {
            "v0": float(self.initial_speed(limits)),
            "steer_sines": [
                {"amplitude": float(a), "frequency_hz": float(f), "phase_rad": float(p)}
                for a, f, p in zip(self.steer_amp, freq, self.steer_phase)
            ],
            "steer_bound_rad": limits.max_steer,
            "pedal_segments": [
                {"level": float(lv), "length_s": float(s * limits.duration)}
                for lv, s in zip(jnp.tanh(self.pedal_level), share)
            ],
        }


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
            jnp.asarray(self.channels),
            self.relative,
            self.additive,
            self.floor_fraction,
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
    noise: str = "seed",
    noise_std_map=None,
    solver: AbstractSolver = RK4(dt=0.005),
    penalty_weight: float = 1e3,
) -> DesignProblem:
    """Build a `DesignProblem`; `target=None` means D-optimal (log det F)."""
    if target is not None and target not in PARAM_NAMES:
        raise ValueError(f"design: unknown target '{target}' (one of {PARAM_NAMES} or None)")
    rel, add = noise_model(noise, channels, noise_std_map)
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
