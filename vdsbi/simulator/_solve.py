"""Solving the model: one draw, and many draws vmapped and sharded."""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Mapping, Sequence

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Bool, Float

from ._dynamics import AbstractVehicleModel, Args, LongitudinalMode, SpeedDriven, model_class
from ._effects import EFFECTS, get_effect
from ._inputs import Inputs
from ._sharding import shard_draws
from ._solver import RK4, AbstractSolver
from ._vehicle import PARAM_NAMES, Vehicle


@dataclasses.dataclass(frozen=True, kw_only=True)
class EffectSettings:
    """The effects a simulation enables, and their parameter values.

    Attributes:
        enabled: names of the effects, applied in this order (see `make_model`).
        params: {effect: {param: value}} or {effect: vector in the effect's parameter order}
            for any of the enabled effects; missing parameters take the effect's null values.
    """

    enabled: Sequence[str] = ()
    params: Mapping[str, object] = dataclasses.field(default_factory=dict)

    def __post_init__(self):
        enabled = (self.enabled,) if isinstance(self.enabled, str) else tuple(self.enabled)
        object.__setattr__(self, "enabled", enabled)


def effect_params_from(
    effects: Sequence[str], values: Mapping[str, object] | None = None
) -> tuple[tuple, tuple]:
    """Build (effect modules, parameter vectors) from names and {effect: {param: value}}.

    Missing parameters take the effect's null value. Raises ValueError on unknown names.
    """
    values = dict(values or {})
    unknown = [k for k in values if k not in effects]
    if unknown:
        raise ValueError(f"effects: parameters given for effect(s) not enabled: {unknown}")
    mods, params = [], []
    for name in effects:
        eff = get_effect(name)
        given = values.get(name, {})
        if isinstance(given, Mapping):
            bad = [k for k in given if k not in eff.param_names]
            if bad:
                raise ValueError(f"effects: '{name}' has no parameter(s) {bad} (has {list(eff.param_names)})")
            vec = [float(given.get(k, d)) for k, d in zip(eff.param_names, eff.null)]
        else:
            vec = np.asarray(given, dtype=float).reshape(-1).tolist()
            if len(vec) != len(eff.param_names):
                raise ValueError(f"effects: '{name}' needs {len(eff.param_names)} values")
        if not all(math.isfinite(v) for v in vec):
            raise ValueError(f"effects: '{name}' parameters must be finite, got {vec}")
        mods.append(eff)
        params.append(jnp.asarray(vec, dtype=float))
    return tuple(mods), tuple(params)


def check_theta(theta, vehicle: Vehicle) -> None:
    """Raise ValueError naming the parameter if θ is unphysical (for use outside jit)."""
    theta = np.asarray(theta, dtype=float)
    if theta.shape != (len(PARAM_NAMES),):
        raise ValueError(f"theta: expected shape ({len(PARAM_NAMES)},), got {theta.shape}")
    for name, v in zip(PARAM_NAMES, theta):
        if not math.isfinite(v):
            raise ValueError(f"theta: '{name}' is not finite ({v})")
    if not 0 < theta[0] < vehicle.wheelbase:
        raise ValueError(f"theta: 'l_f' = {theta[0]} must lie in (0, wheelbase={vehicle.wheelbase})")
    for name, v in zip(PARAM_NAMES[1:], theta[1:]):
        if v <= 0:
            raise ValueError(f"theta: '{name}' = {v} must be > 0")


def theta_valid(theta, vehicle: Vehicle) -> Bool[Array, ""]:
    """Traceable version of check_theta, for masking inside a batch."""
    return (theta[0] > 0) & (theta[0] < vehicle.wheelbase) & jnp.all(theta[1:] > 0)


def check_inputs(
    inputs: Inputs, longitudinal: LongitudinalMode | type[AbstractVehicleModel] = "torque"
) -> None:
    """Raise ValueError naming the series if an input the model uses is missing or non-finite.

    Args:
        inputs: driver inputs.
        longitudinal: the model class or its mode's name; `SpeedDriven` ("speed") also needs
            `inputs.speed` and `inputs.accel`.
    """
    cls = model_class(longitudinal)
    _require_measured(cls, inputs)
    for name in ("steer", "torque_front", "torque_rear", *cls.measured_inputs):
        arr = np.asarray(getattr(inputs, name))
        if not np.all(np.isfinite(arr)):
            idx = int(np.argmin(np.isfinite(arr)))
            raise ValueError(f"inputs: '{name}' is not finite at sample {idx}")


def _require_measured(cls: type[AbstractVehicleModel], inputs: Inputs) -> None:
    missing = [n for n in cls.measured_inputs if getattr(inputs, n) is None]
    if missing:
        raise ValueError(
            f"inputs: longitudinal={cls.longitudinal!r} needs the measured series {missing} "
            "(Inputs(..., speed=vx m/s, accel=ax m/s²))"
        )


def solve(
    model: AbstractVehicleModel,
    theta: Float[Array, "6"],
    inputs: Inputs,
    v0: Float[Array, ""],
    effect_params: tuple = (),
    solver: AbstractSolver = RK4(),
    lateral0: Float[Array, "2"] | None = None,
) -> tuple[Float[Array, "T 6"], Bool[Array, ""]]:
    """Noise-free sensor readings at the input samples, and a success flag (one draw).

    Args:
        model: vehicle model (`TorqueDriven` or `SpeedDriven`: what drives Vx).
        theta: (6,) identified parameters.
        inputs: driver inputs; `SpeedDriven` needs `speed` and `accel`.
        v0: initial speed, m/s (ignored by `SpeedDriven`: the measured speed at t0).
        effect_params: one parameter vector per enabled effect.
        solver: the integrator.
        lateral0: optional (2,) initial (Vy m/s, r rad/s); None starts straight (Vy = r = 0).

    Returns:
        readings: (T, 6) in CHANNELS order (ax, ay, yaw_rate, omega_front, omega_rear, vx).
        ok: False if the solve failed, θ is unphysical or any value is non-finite.

    Raises:
        ValueError: (at trace time) `SpeedDriven` without `inputs.speed`/`inputs.accel`.
    """
    _require_measured(type(model), inputs)
    args = Args(theta=theta, effect_params=effect_params, inputs=inputs)
    y0 = model.initial_state(theta, effect_params, inputs, v0, lateral0)
    ys, solved = solver.integrate(model, y0, args)
    ok = (
        solved
        & jnp.all(jnp.isfinite(ys))
        & theta_valid(theta, model.vehicle)
        # A wheel spinning backwards or a vehicle reversing is outside the model's domain.
        & jnp.all(ys[:, 5] > -1.0)
    )
    return ys, ok


#: Number of times the batched kernel has been traced (tests assert one per shape).
TRACE_COUNT = {"batch": 0}


@eqx.filter_jit
def _solve_batch(model, theta, inputs, v0, effect_params, solver, lateral0=None):
    TRACE_COUNT["batch"] += 1
    fn = lambda th, v, ep, lat: solve(model, th, inputs, v, ep, solver, lat)
    return jax.vmap(fn)(theta, v0, effect_params, lateral0)


def solve_batch(
    model: AbstractVehicleModel,
    theta: Float[Array, "N 6"],
    inputs: Inputs,
    v0: Float[Array, " N"],
    effect_params: tuple = (),
    solver: AbstractSolver = RK4(),
    lateral0: Float[Array, "N 2"] | None = None,
) -> tuple[Float[Array, "N T 6"], Bool[Array, " N"]]:
    """Many draws at once: vmapped over draws and sharded over all jax.devices() along N.

    `effect_params` holds one (N, P_e) array per enabled effect. `lateral0`, if given, is the
    initial (Vy m/s, r rad/s) per draw, (N, 2) or broadcastable to it (e.g. (2,)). A failed
    draw is flagged in the returned mask; it never raises and never spoils the others.
    Integrates with `solver.batched()`, the layout made for many draws.
    """
    _require_measured(type(model), inputs)
    theta = jnp.asarray(theta)
    n = theta.shape[0]
    v0 = jnp.broadcast_to(jnp.asarray(v0, dtype=theta.dtype), (n,))
    effect_params = tuple(
        jnp.broadcast_to(jnp.asarray(p, dtype=theta.dtype), (n, len(e.param_names)))
        for e, p in zip(model.effects, effect_params)
    )
    if lateral0 is not None:
        lateral0 = jnp.broadcast_to(jnp.asarray(lateral0, dtype=theta.dtype), (n, 2))
    theta, v0, effect_params, lateral0 = shard_draws((theta, v0, effect_params, lateral0), n)
    ys, ok = _solve_batch(model, theta, inputs, v0, effect_params, solver.batched(), lateral0)
    return ys[:n], ok[:n]


def make_model(
    vehicle: Vehicle,
    effects: Sequence[str] = (),
    longitudinal: LongitudinalMode | type[AbstractVehicleModel] = "torque",
) -> AbstractVehicleModel:
    """Model with the named effects enabled.

    Args:
        vehicle: vehicle constants.
        effects: names of effects, applied in this order.
        longitudinal: the model class, or its mode's name: "torque" (`TorqueDriven`, wheels
            driven by the applied torques) or "speed" (`SpeedDriven`, Vx follows the measured
            speed; the inputs must then carry `speed` and `accel`).

    Raises:
        ValueError: unknown or duplicate effect names, unknown mode.
    """
    cls = model_class(longitudinal)
    if isinstance(effects, str):
        effects = (effects,)
    for name in effects:
        if name not in EFFECTS:
            get_effect(name)  # raises the clear error
    if len(set(effects)) != len(effects):
        raise ValueError(f"effects: duplicate effect names in {list(effects)}")
    return cls(vehicle=vehicle, effects=tuple(get_effect(n) for n in effects))


def simulate(
    theta,
    inputs: Inputs,
    vehicle: Vehicle,
    *,
    v0: float | None = None,
    effects: EffectSettings = EffectSettings(),
    solver: AbstractSolver = RK4(),
    longitudinal: LongitudinalMode | type[AbstractVehicleModel] = "torque",
    lateral0=None,
) -> tuple[np.ndarray, bool]:
    """One noise-free simulation with every input checked first (the user-facing call).

    Args:
        theta: (6,) in PARAM_NAMES order.
        inputs: driver inputs.
        vehicle: vehicle constants.
        v0: initial speed, m/s (required by `TorqueDriven`; ignored by `SpeedDriven`).
        effects: the effects to enable and their parameter values (`EffectSettings`).
        solver: the integrator.
        longitudinal: the model class or its mode's name, "torque" or "speed" (see
            `make_model`); `SpeedDriven` needs `inputs.speed` and `inputs.accel`.
        lateral0: optional initial (Vy m/s, r rad/s); default starts straight.

    Returns:
        readings (T, 6) in CHANNELS order, and whether the solve succeeded.

    Raises:
        ValueError: naming the offending field.
    """
    check_theta(theta, vehicle)
    cls = model_class(longitudinal)
    check_inputs(inputs, cls)
    if issubclass(cls, SpeedDriven):
        v0 = 0.0  # unused: the measured speed at t0 sets the initial state
    elif not (isinstance(v0, (int, float)) and math.isfinite(v0) and v0 > 0):
        raise ValueError(f"v0: initial speed must be a positive number, got {v0!r}")
    if lateral0 is not None:
        lateral0 = np.asarray(lateral0, dtype=float)
        if lateral0.shape != (2,) or not np.all(np.isfinite(lateral0)):
            raise ValueError(f"lateral0: expected 2 finite values (Vy m/s, r rad/s), got {lateral0!r}")
        lateral0 = jnp.asarray(lateral0, dtype=float)
    model = make_model(vehicle, effects.enabled, cls)
    _, params = effect_params_from(effects.enabled, effects.params)
    ys, ok = _solve_one(
        model, jnp.asarray(theta, dtype=float), inputs, jnp.asarray(v0), params, solver, lateral0
    )
    return np.asarray(ys), bool(ok)


@eqx.filter_jit
def _solve_one(model, theta, inputs, v0, params, solver, lateral0=None):
    return solve(model, theta, inputs, v0, params, solver, lateral0)
