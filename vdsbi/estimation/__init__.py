"""The one estimator of a problem's parameters: the MAP fit through the simulator
(Levenberg–Marquardt), its noise model (sensor noise only, or with the model's own error), the
start speeds and their marginalisation, and the Laplace covariance with its widening. identify,
diagnose and the experiments all fit with it."""

from ._least_squares import (
    GaussianPrior as GaussianPrior,
    StepControl as StepControl,
    laplace_covariance as laplace_covariance,
    levenberg_marquardt as levenberg_marquardt,
)
from ._likelihood import (
    PRIOR_Z_STD as PRIOR_Z_STD,
    FitRequest as FitRequest,
    fit_likelihood as fit_likelihood,
)
from ._noise import (
    ModelError as ModelError,
    NoiseModel as NoiseModel,
    SensorNoise as SensorNoise,
    measure_noise as measure_noise,
)
from ._screen import screened_sample as screened_sample
from ._start_speed import V0_STD as V0_STD
