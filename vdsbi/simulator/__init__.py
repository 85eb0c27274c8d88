"""Differentiable, batched bicycle-model vehicle simulator (seed eq. 1–13) with physics effects.

The vehicle, θ and the channels; inputs and maneuvers; `simulate` (one checked run), `make_model`
with `solve` / `solve_batch` (one draw, many draws sharded over the devices). Grouped beside them:
`effects` (the effect registry, the base class and the candidate terms), `models` (the torque- and
speed-driven vector fields and the longitudinal modes), `solvers` (the integrators) and
`measurement` (sensor noise, the anti-alias decimator, the stochastic simulator).
"""

from . import effects as effects, measurement as measurement, models as models, solvers as solvers
from ._inputs import Inputs as Inputs
from ._profiles import (
    SeedManeuver as SeedManeuver,
    random_profile as random_profile,
    seed_profile as seed_profile,
)
from ._sharding import ENV_CPU_DEVICES as ENV_CPU_DEVICES, shard_draws as shard_draws
from ._solve import (
    check_theta as check_theta,
    make_model as make_model,
    simulate as simulate,
    solve as solve,
    solve_batch as solve_batch,
)
from ._vehicle import (
    CHANNELS as CHANNELS,
    GRAVITY as GRAVITY,
    INPUTS as INPUTS,
    NOMINAL_THETA as NOMINAL_THETA,
    PARAM_NAMES as PARAM_NAMES,
    PARAM_UNITS as PARAM_UNITS,
    SEED_CHANNELS as SEED_CHANNELS,
    Vehicle as Vehicle,
    default_vehicle as default_vehicle,
    theta_from_dict as theta_from_dict,
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
