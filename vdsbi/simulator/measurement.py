"""What the sensors make of a simulation: `SensorNoise` (relative and additive; the seed's
`SEED_RELATIVE_NOISE`), the seed's process noise on the stiffnesses (`StiffnessMixtureNoise`),
the anti-alias filter and decimation (`Decimator`), and `StochasticSimulator`, p(x | θ) for one
recording's inputs."""

from ._filter import Decimator as Decimator
from ._sensors import (
    SEED_RELATIVE_NOISE as SEED_RELATIVE_NOISE,
    SensorNoise as SensorNoise,
    StiffnessMixtureNoise as StiffnessMixtureNoise,
)
from ._stochastic import StochasticSimulator as StochasticSimulator
