"""Differentiable, batched bicycle-model vehicle simulator (seed eq. 1–13) with physics effects."""

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
from ._effects import (
    EFFECTS as EFFECTS,
    TERMS as TERMS,
    AbstractEffect as AbstractEffect,
    Context as Context,
    Term as Term,
    get_effect as get_effect,
    register_effect as register_effect,
    term_effect as term_effect,
    term_formula as term_formula,
)
from ._filter import Decimator as Decimator
from ._inputs import Inputs as Inputs
from ._model import AbstractVehicleModel as AbstractVehicleModel, Args as Args
from ._profiles import (
    constant_profile as constant_profile,
    random_profile as random_profile,
    seed_profile as seed_profile,
)
from ._sensors import (
    SEED_RELATIVE_NOISE as SEED_RELATIVE_NOISE,
    SensorNoise as SensorNoise,
    StiffnessMixtureNoise as StiffnessMixtureNoise,
)
from ._sharding import shard_draws as shard_draws
from ._solve import (
    TRACE_COUNT as TRACE_COUNT,
    check_inputs as check_inputs,
    check_theta as check_theta,
    effect_params_from as effect_params_from,
    make_model as make_model,
    simulate as simulate,
    solve as solve,
    solve_batch as solve_batch,
    theta_valid as theta_valid,
)
from ._solver import (
    RK4 as RK4,
    AbstractSolver as AbstractSolver,
    AdaptiveTsit5 as AdaptiveTsit5,
    Solver as Solver,
)
from ._stochastic import StochasticSimulator as StochasticSimulator
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

#: The seed's Table II true values (stiffness = Table I nominal + Δ·1e5).
SEED_TRUE_THETA: dict[str, float] = {
    "l_f": 1.5,
    "h_cog": 0.415,
    "C_kappa_f": 1e5 + 0.446e5,
    "C_kappa_r": 1e5 + 0.407e5,
    "C_alpha_f": 6e4 + 0.12e5,
    "C_alpha_r": 6e4 + 0.051e5,
}
