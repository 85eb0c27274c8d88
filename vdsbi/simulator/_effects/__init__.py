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
