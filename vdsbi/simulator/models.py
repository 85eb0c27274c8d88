"""The vehicle models: `TorqueDriven` (wheels driven by the applied torques) and `SpeedDriven`
(Vx follows the measured speed), their base `AbstractVehicleModel`, the longitudinal modes by
name (`LONGITUDINAL_MODES`, `LongitudinalMode`, a user's `LongitudinalChoice`, `model_class`),
`VehicleModel` (the model for effect modules and a mode) and `steady_lateral_state`."""

from ._dynamics import (
    LONGITUDINAL_MODES as LONGITUDINAL_MODES,
    LongitudinalChoice as LongitudinalChoice,
    LongitudinalMode as LongitudinalMode,
    SpeedDriven as SpeedDriven,
    TorqueDriven as TorqueDriven,
    VehicleModel as VehicleModel,
    model_class as model_class,
    steady_lateral_state as steady_lateral_state,
)
from ._model import AbstractVehicleModel as AbstractVehicleModel
