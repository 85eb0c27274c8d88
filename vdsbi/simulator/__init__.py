"""Differentiable, batched bicycle-model vehicle simulator (seed eq. 1–13) with physics effects."""

from ._inputs import Inputs as Inputs
from ._vehicle import (
    CHANNELS as CHANNELS,
    GRAVITY as GRAVITY,
    INPUTS as INPUTS,
    NOMINAL_THETA as NOMINAL_THETA,
    PARAM_NAMES as PARAM_NAMES,
    PARAM_UNITS as PARAM_UNITS,
    SEED_CHANNELS as SEED_CHANNELS,
    VEHICLE_KEYS as VEHICLE_KEYS,
    Vehicle as Vehicle,
    check_prior as check_prior,
    default_vehicle as default_vehicle,
    theta_from_dict as theta_from_dict,
    theta_to_dict as theta_to_dict,
)
