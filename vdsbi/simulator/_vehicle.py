"""Vehicle constants, identified-parameter names and the seed's nominal values."""

from __future__ import annotations

import math
from collections.abc import Mapping
from typing import Any

import equinox as eqx
import numpy as np

#: Identified parameters, in this order everywhere (θ vectors, files, reports).
PARAM_NAMES: tuple[str, ...] = ("l_f", "h_cog", "C_kappa_f", "C_kappa_r", "C_alpha_f", "C_alpha_r")
PARAM_UNITS: dict[str, str] = {
    "l_f": "m",
    "h_cog": "m",
    "C_kappa_f": "N",
    "C_kappa_r": "N",
    "C_alpha_f": "N/rad",
    "C_alpha_r": "N/rad",
}
#: Measured channels of the recording contract, in simulator output order.
CHANNELS: tuple[str, ...] = ("ax", "ay", "yaw_rate", "omega_front", "omega_rear", "vx")
#: The seed's five measured channels (it has no vx).
SEED_CHANNELS: tuple[str, ...] = ("ax", "ay", "yaw_rate", "omega_front", "omega_rear")
INPUTS: tuple[str, ...] = ("steer", "torque_front", "torque_rear")

#: The seed's Table I nominal values.
NOMINAL_THETA: dict[str, float] = {
    "l_f": 1.3,
    "h_cog": 0.5,
    "C_kappa_f": 1e5,
    "C_kappa_r": 1e5,
    "C_alpha_f": 6e4,
    "C_alpha_r": 6e4,
}
GRAVITY = 9.81

VEHICLE_KEYS: tuple[str, ...] = (
    "mass",
    "wheelbase",
    "wheel_radius",
    "wheel_inertia",
    "tire_vertical_stiffness",
    "friction",
    "relaxation_length",
)


class Vehicle(eqx.Module):
    """Known constants of one vehicle (the contract's vehicle.json).

    Attributes:
        mass: kg.
        wheelbase: L, m.
        wheel_radius: free tire radius R_f, m.
        wheel_inertia: I_w of one axle's wheels and driveline, kg·m².
        tire_vertical_stiffness: C_vert of one axle's tires, N/m.
        friction: road friction coefficient μ.
        relaxation_length: σ_l, m.
        noise_std: optional additive sensor noise std per channel name.
        prior: optional {param: (low, high)} overriding the default prior.
    """

    mass: float
    wheelbase: float
    wheel_radius: float
    wheel_inertia: float
    tire_vertical_stiffness: float
    friction: float
    relaxation_length: float
    noise_std: dict[str, float] = eqx.field(static=True, default_factory=dict)
    prior: dict[str, tuple[float, float]] = eqx.field(static=True, default_factory=dict)

    def __check_init__(self):
        for key in VEHICLE_KEYS:
            value = getattr(self, key)
            if isinstance(value, (int, float, np.floating, np.integer)):
                if not math.isfinite(value) or value <= 0:
                    raise ValueError(f"vehicle: '{key}' must be a positive finite number, got {value}")

    @classmethod
    def from_dict(cls, data: Mapping[str, Any], source: str = "vehicle") -> Vehicle:
        """Validated construction from a vehicle.json mapping; extra keys are ignored.

        Raises:
            ValueError: naming `source` and the offending key.
        """
        if not isinstance(data, Mapping):
            raise ValueError(f"{source}: expected a mapping of vehicle constants")
        kwargs: dict[str, Any] = {}
        for key in VEHICLE_KEYS:
            if key not in data:
                raise ValueError(f"{source}: missing key '{key}'")
            value = data[key]
            if isinstance(value, bool) or not isinstance(value, (int, float)):
                raise ValueError(
                    f"{source}: key '{key}' must be a number, got {type(value).__name__} {value!r}"
                )
            if not math.isfinite(value) or value <= 0:
                raise ValueError(f"{source}: key '{key}' must be positive and finite, got {value}")
            kwargs[key] = float(value)
        if kwargs["friction"] > 3.0:
            raise ValueError(f"{source}: key 'friction' = {kwargs['friction']} is implausible (> 3)")
        noise = data.get("noise_std") or {}
        if not isinstance(noise, Mapping):
            raise ValueError(f"{source}: key 'noise_std' must be a mapping channel -> std")
        clean_noise: dict[str, float] = {}
        for ch, value in noise.items():
            if ch not in CHANNELS:
                continue  # extra keys are accepted silently, per the contract
            if isinstance(value, bool) or not isinstance(value, (int, float)) or not value >= 0:
                raise ValueError(f"{source}: noise_std['{ch}'] must be a number >= 0, got {value!r}")
            clean_noise[ch] = float(value)
        prior = data.get("prior") or {}
        if not isinstance(prior, Mapping):
            raise ValueError(f"{source}: key 'prior' must be a mapping param -> [low, high]")
        clean_prior: dict[str, tuple[float, float]] = {}
        for name, bounds in prior.items():
            if name not in PARAM_NAMES and not _effect_parameter(name):
                raise ValueError(
                    f"{source}: prior for unknown parameter '{name}' (expected one of {PARAM_NAMES} "
                    "or an effect's EFFECT.PARAM, e.g. sensor_bias.ax)"
                )
            if (
                not isinstance(bounds, (list, tuple))
                or len(bounds) != 2
                or not all(isinstance(b, (int, float)) and not isinstance(b, bool) for b in bounds)
            ):
                raise ValueError(f"{source}: prior['{name}'] must be [low, high], got {bounds!r}")
            lo, hi = float(bounds[0]), float(bounds[1])
            if not (math.isfinite(lo) and math.isfinite(hi) and lo < hi):
                raise ValueError(f"{source}: prior['{name}'] needs finite low < high, got {bounds!r}")
            clean_prior[name] = (lo, hi)
        vehicle = cls(**kwargs, noise_std=clean_noise, prior=clean_prior)
        check_prior(vehicle.default_prior(), vehicle, source)
        return vehicle

    def to_dict(self) -> dict[str, Any]:
        out: dict[str, Any] = {k: float(getattr(self, k)) for k in VEHICLE_KEYS}
        if self.noise_std:
            out["noise_std"] = dict(self.noise_std)
        if self.prior:
            out["prior"] = {k: list(v) for k, v in self.prior.items()}
        return out

    def default_prior(self) -> dict[str, tuple[float, float]]:
        """Uniform prior box: physically valid ranges scaled to this vehicle, then overrides.

        Stiffnesses are expressed per axle relative to the static axle load m·g/2: cornering
        stiffness 3–50 /rad and longitudinal slip stiffness 3–40 times the load cover soft winter
        tyres to race slicks, whose stiffness grows with the load downforce adds.
        """
        L = float(self.wheelbase)
        load = float(self.mass) * GRAVITY / 2
        box = {
            "l_f": (0.25 * L, 0.75 * L),
            "h_cog": (0.2, 1.0),
            "C_kappa_f": (3 * load, 40 * load),
            "C_kappa_r": (3 * load, 40 * load),
            "C_alpha_f": (3 * load, 50 * load),
            "C_alpha_r": (3 * load, 50 * load),
        }
        box.update(self.prior)
        return box


def _effect_parameter(name: str) -> bool:
    """Whether `name` is an effect's parameter, ``effect.param`` (its prior joins θ's box when
    the effect is identified)."""
    from ._effects import EFFECTS  # the registry, read now (effects may register late)

    effect, _, param = str(name).partition(".")
    return effect in EFFECTS and param in EFFECTS[effect].param_names


def check_prior(prior: Mapping[str, tuple[float, float]], vehicle: Vehicle, source: str) -> None:
    """Raise ValueError if a prior box admits unphysical parameters."""
    L = float(vehicle.wheelbase)
    lo, hi = prior["l_f"]
    if lo <= 0 or hi >= L:
        raise ValueError(f"{source}: prior['l_f'] = [{lo}, {hi}] must lie inside (0, wheelbase={L})")
    for name in PARAM_NAMES[1:]:
        lo, hi = prior[name]
        if lo <= 0:
            raise ValueError(f"{source}: prior['{name}'] low bound {lo} must be > 0")


def default_vehicle() -> Vehicle:
    """Built-in mid-size front-driven car for the seed's experiment (the seed gives none).

    1500 kg, L = 2.7 m (so the seed's l_f ∈ [1, 1.5] m leaves l_r ≥ 1.2 m); 205/55 R16 tires
    (R_f = 0.31 m); I_w = 1.8 kg·m² per axle (two wheels ≈ 2 × 0.8 plus brake discs and
    driveline share); C_vert = 4e5 N/m per axle (two tires of 200 kN/m); dry asphalt μ = 0.9;
    σ_l = 0.3 m, about half a tire circumference, typical for passenger tires.
    """
    return Vehicle(
        mass=1500.0,
        wheelbase=2.7,
        wheel_radius=0.31,
        wheel_inertia=1.8,
        tire_vertical_stiffness=4.0e5,
        friction=0.9,
        relaxation_length=0.3,
    )


def theta_to_dict(theta) -> dict[str, float]:
    theta = np.asarray(theta, dtype=float)
    return {name: float(theta[i]) for i, name in enumerate(PARAM_NAMES)}


def theta_from_dict(d: Mapping[str, float], source: str = "theta") -> np.ndarray:
    missing = [n for n in PARAM_NAMES if n not in d]
    if missing:
        raise ValueError(f"{source}: missing parameter(s) {missing}")
    return np.array([float(d[n]) for n in PARAM_NAMES])
