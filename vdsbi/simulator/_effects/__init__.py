"""Physics effects. Adding one: a new module here and one line in EFFECTS."""

from ._aero_drag import AeroDrag as AeroDrag
from ._base import AbstractEffect as AbstractEffect, Context as Context
from ._imu_lever_arm import ImuLeverArm as ImuLeverArm
from ._imu_misalignment import ImuMisalignment as ImuMisalignment
from ._road_bank import RoadBank as RoadBank
from ._road_grade import RoadGrade as RoadGrade
from ._rolling_resistance import RollingResistance as RollingResistance
from ._sensor_bias import SensorBias as SensorBias
from ._steering_lag import SteeringLag as SteeringLag
from ._torque_lag import TorqueLag as TorqueLag
from ._wheel_radius_error import WheelRadiusError as WheelRadiusError

#: Registry: name -> effect class.
EFFECTS: dict[str, type[AbstractEffect]] = {
    cls.name: cls
    for cls in (
        AeroDrag,
        RollingResistance,
        RoadGrade,
        RoadBank,
        SteeringLag,
        TorqueLag,
        ImuLeverArm,
        ImuMisalignment,
        SensorBias,
        WheelRadiusError,
    )
}


def get_effect(name: str) -> AbstractEffect:
    if name not in EFFECTS:
        raise ValueError(f"effects: unknown effect '{name}' (known: {', '.join(EFFECTS)})")
    return EFFECTS[name]()


def register_effect(cls: type[AbstractEffect]) -> type[AbstractEffect]:
    """Add an effect class to `EFFECTS` under `cls.name` (usable as a class decorator).

    The built-in effects are listed in `EFFECTS` above; this is for effects defined outside
    the package (experiments, tests). Raises ValueError on a duplicate or incomplete class.
    """
    needed = ("name", "param_names", "units", "null", "typical", "description")
    missing = [a for a in needed if not hasattr(cls, a)]
    if missing:
        raise ValueError(f"effects: {cls.__name__} lacks class attribute(s) {missing}")
    if not len(cls.param_names) == len(cls.units) == len(cls.null) == len(cls.typical):
        raise ValueError(f"effects: {cls.__name__}: param_names, units, null, typical differ in length")
    if cls.name in EFFECTS and EFFECTS[cls.name] is not cls:
        raise ValueError(f"effects: an effect named '{cls.name}' is already registered")
    EFFECTS[cls.name] = cls
    return cls
