"""θ extended by the parameters of enabled effects: names, prior box, and the split back."""

from __future__ import annotations

from collections.abc import Mapping, Sequence

import jax.numpy as jnp

from ..simulator import PARAM_NAMES, PARAM_UNITS, Vehicle
from ..simulator.effects import get_effect


def parameter_name(effect: str, param: str) -> str:
    """The flat name of an effect's parameter, ``signal_delay.delay``: how files, reports and the
    command line name it."""
    return f"{effect}.{param}"


def _effect(effect):
    """An effect's class from its registered name, its class or an instance."""
    if isinstance(effect, str):
        return get_effect(effect)
    return effect if isinstance(effect, type) else type(effect)


def parameter_names(effects: Sequence = ()) -> tuple[str, ...]:
    """PARAM_NAMES, then ``effect.param`` for each parameter of each effect (a registered name,
    an effect class or an instance), in the flat vector's order."""
    classes = [_effect(e) for e in effects]
    return (*PARAM_NAMES, *(parameter_name(c.name, p) for c in classes for p in c.param_names))


def parameter_units(effects: Sequence = ()) -> dict[str, str]:
    out = dict(PARAM_UNITS)
    for c in map(_effect, effects):
        out |= {parameter_name(c.name, p): u for p, u in zip(c.param_names, c.units)}
    return out


def prior_box(
    vehicle: Vehicle,
    effects: Sequence[str] = (),
    overrides: Mapping[str, tuple[float, float]] | None = None,
    grip: float | None = None,
) -> dict[str, tuple[float, float]]:
    """Uniform prior box: the vehicle's θ box, then each effect's prior bounds
    (`AbstractEffect.prior_bounds`: its fit bounds widened to hold its null value, what any car
    could have, unless the grip the drive used rules values out); vehicle.json's `prior`, then
    `overrides` (e.g. the ranges a diagnosis measured), replace any of them by full name
    (``signal_delay.delay``).

    `grip` is the share of vehicle.json's μ·g the drive uses (`grip_used`): an effect whose range
    depends on it moves its bounds unless vehicle.json sets them, told whether another of
    `effects` loads the tyres beyond the car's weight (`AbstractEffect.adds_load`).

    Raises:
        ValueError: an override for an unknown parameter, or with low ≥ high.
    """
    box = dict(vehicle.default_prior())
    effs = {e: get_effect(e) for e in effects}
    for e, eff in effs.items():
        extra_load = any(other.adds_load for name, other in effs.items() if name != e)
        for p, bounds in zip(eff.param_names, eff.prior_bounds(grip, extra_load)):
            name = parameter_name(e, p)
            box[name] = tuple(float(v) for v in vehicle.prior.get(name, bounds))
    for name, (lo, hi) in (overrides or {}).items():
        if name not in box:
            raise ValueError(f"prior for unknown parameter {name!r}; known: {', '.join(box)}")
        if not float(lo) < float(hi):
            raise ValueError(f"prior for {name}: low {lo} must be below high {hi}")
        box[name] = (float(lo), float(hi))
    return box


def split_parameters(theta_ext, effects: Sequence = ()) -> tuple:
    """(…, 6 + P) -> (θ (…, 6), one (…, P_e) array per effect: a registered name, an effect class
    or an instance, in the flat vector's order)."""
    theta_ext = jnp.asarray(theta_ext)
    out, i = [], len(PARAM_NAMES)
    for e in effects:
        n = len(_effect(e).param_names)
        out.append(theta_ext[..., i : i + n])
        i += n
    return theta_ext[..., : len(PARAM_NAMES)], tuple(out)
