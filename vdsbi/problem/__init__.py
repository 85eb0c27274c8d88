"""A recording plus a vehicle as one problem: windows, channels, noise, inputs, initial states, held-out.

`make_problem` builds a `Problem`; `windowed_model` / `simulate_draws` simulate its windows; `points`
holds its parameters as one pytree and the map to the simulator's values;
`validation` scores a parameter set on a problem's windows (channel scores, predictions, the
predictive band and its coverage) and gives the driving envelope a fit saw and the windows beyond it.
"""

from . import points as points, validation as validation
from ._box import Box as Box
from ._concat import concat_problems as concat_problems
from ._default_effects import default_effects as default_effects
from ._lag import measured_steer_lag as measured_steer_lag, steer_lag_index as steer_lag_index
from ._make import longitudinal_mode as longitudinal_mode, make_problem as make_problem
from ._measured import (
    measured_longitudinal as measured_longitudinal,
    smoothed_yaw_rate as smoothed_yaw_rate,
)
from ._noise import (
    dof_factor as dof_factor,
    integrated_autocorrelation_time as integrated_autocorrelation_time,
)
from ._parameters import (
    parameter_name as parameter_name,
    parameter_names as parameter_names,
    parameter_units as parameter_units,
    prior_box as prior_box,
)
from ._problem import (
    Part as Part,
    Problem as Problem,
    ProblemSettings as ProblemSettings,
    grip_used as grip_used,
)
from ._simulate import (
    CLEAN_BATCH as CLEAN_BATCH,
    WindowedModel as WindowedModel,
    simulate_draws as simulate_draws,
    windowed_model as windowed_model,
)
