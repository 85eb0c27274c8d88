"""A recording plus a vehicle as one problem: windows, channels, noise, inputs, initial states, held-out."""

from ._box import Box as Box
from ._concat import concat_problems as concat_problems
from ._default_effects import default_effects as default_effects
from ._envelope import (
    ENVELOPE_UNITS as ENVELOPE_UNITS,
    beyond_envelope as beyond_envelope,
    envelope as envelope,
    window_peaks as window_peaks,
)
from ._limit import slides as slides
from ._make import longitudinal_mode as longitudinal_mode, make_problem as make_problem
from ._measured import (
    measured_longitudinal as measured_longitudinal,
    smoothed_yaw_rate as smoothed_yaw_rate,
)
from ._noise import (
    dof_factor as dof_factor,
    integrated_autocorrelation_time as integrated_autocorrelation_time,
    lag1_autocorrelation as lag1_autocorrelation,
)
from ._parameters import (
    parameter_names as parameter_names,
    parameter_units as parameter_units,
    prior_box as prior_box,
    split_parameters as split_parameters,
)
from ._problem import (
    LONGITUDINAL_MODES as LONGITUDINAL_MODES,
    Part as Part,
    Problem as Problem,
    ProblemSettings as ProblemSettings,
    compared_speed as compared_speed,
    grip_used as grip_used,
    top_speed as top_speed,
    yaw_at_zero_steer as yaw_at_zero_steer,
)
from ._simulate import (
    CLEAN_BATCH as CLEAN_BATCH,
    WindowedModel as WindowedModel,
    simulate_draws as simulate_draws,
    windowed_model as windowed_model,
)
from ._validate import (
    band_coverage as band_coverage,
    channel_scores as channel_scores,
    predict as predict,
    predictive_band as predictive_band,
    validate as validate,
)
from ._windows import (
    Window as Window,
    choose_windows as choose_windows,
    lateral_information_share as lateral_information_share,
)
