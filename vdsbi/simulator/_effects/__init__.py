"""Physics effects. Adding one: a new module here, holding one `AbstractEffect` subclass with its
metadata; the package finds it (`EFFECTS`), and simulation, identification, discovery and export
take it from there."""

import importlib
import pkgutil

from ._aero_drag import AeroDrag as AeroDrag
from ._base import AbstractEffect as AbstractEffect, Context as Context, Param as Param, promoted as promoted
from ._downforce import Downforce as Downforce
from ._imu_lever_arm import ImuLeverArm as ImuLeverArm
from ._imu_misalignment import ImuMisalignment as ImuMisalignment
from ._missing_terms import (
    TERMS as TERMS,
    Term as Term,
    term_effect as term_effect,
    term_formula as term_formula,
)
from ._road_bank import RoadBank as RoadBank
from ._road_grade import RoadGrade as RoadGrade
from ._rolling_resistance import RollingResistance as RollingResistance
from ._sensor_bias import SensorBias as SensorBias
from ._sensor_scale import SensorScale as SensorScale
from ._signal_delay import SignalDelay as SignalDelay
from ._steer_offset import SteerOffset as SteerOffset
from ._steering_lag import SteeringLag as SteeringLag
from ._torque_gain import TorqueGain as TorqueGain
from ._torque_lag import TorqueLag as TorqueLag
from ._tyre_friction import TyreFriction as TyreFriction
from ._wheel_radius_error import WheelRadiusError as WheelRadiusError
from ._yaw_inertia import YawInertia as YawInertia

#: Registry: name -> effect class, in search order. Filled by `register_effect` below; read
#: at call time by everything that lists effects (simulation, identification, discovery).
EFFECTS: dict[str, type[AbstractEffect]] = {}

_METADATA = ("name", "params", "description")


def get_effect(name: str) -> AbstractEffect:
    if name not in EFFECTS:
        raise ValueError(f"effects: unknown effect '{name}' (known: {', '.join(EFFECTS)})")
    return EFFECTS[name]()


def _check_metadata(cls: type[AbstractEffect]) -> None:
    """What the class definition cannot check: the attributes are there (its `params` records
    were checked when it was defined)."""
    missing = [a for a in _METADATA if not hasattr(cls, a)]
    if missing:
        raise ValueError(f"effects: {cls.__name__} lacks class attribute(s) {missing}")


def register_effect(cls: type[AbstractEffect]) -> type[AbstractEffect]:
    """Add an effect class to `EFFECTS` under `cls.name` (usable as a class decorator).

    An effect registered here is simulated, identified and searched for by discovery like a
    built-in one. Raises ValueError on a duplicate name or missing metadata.
    """
    _check_metadata(cls)
    if cls.name in EFFECTS and EFFECTS[cls.name] is not cls:
        raise ValueError(f"effects: an effect named '{cls.name}' is already registered")
    EFFECTS[cls.name] = cls
    return cls


#: The built-in effects' search order (discovery tries effects in this order and breaks ties by
#: it); an effect module not named here comes after them, by effect name.
SEARCH_ORDER = (
    "aero_drag",
    "rolling_resistance",
    "road_grade",
    "road_bank",
    "steering_lag",
    "torque_lag",
    "imu_lever_arm",
    "imu_misalignment",
    "sensor_bias",
    "wheel_radius_error",
    "tyre_friction",
    "torque_gain",
    "signal_delay",
    "sensor_scale",
    "yaw_inertia",
    "steer_offset",
    "downforce",
)


def _effect_classes() -> list[type[AbstractEffect]]:
    """Every concrete `AbstractEffect` subclass defined in a module of this package."""
    found = []
    for info in pkgutil.iter_modules(__path__):
        if info.name in ("_base", "_missing_terms"):
            continue
        module = importlib.import_module(f"{__name__}.{info.name}")
        for obj in vars(module).values():
            if (
                isinstance(obj, type)
                and issubclass(obj, AbstractEffect)
                and obj.__module__ == module.__name__
                and isinstance(obj.__dict__.get("name"), str)
            ):
                found.append(obj)
    rank = {n: i for i, n in enumerate(SEARCH_ORDER)}
    return sorted(found, key=lambda c: (rank.get(c.name, len(rank)), c.name))


for _cls in _effect_classes():
    register_effect(_cls)
