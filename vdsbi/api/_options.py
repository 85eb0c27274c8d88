"""What `identify` is asked to do, as typed options: how the drive becomes a problem, which
model it fits, how much the neural estimator spends, and where progress goes."""

from __future__ import annotations

import dataclasses
from collections.abc import Callable, Mapping
from typing import TYPE_CHECKING, Any, Literal

from ..simulator.models import LongitudinalChoice

if TYPE_CHECKING:
    from ..inference import AbstractObservation, APTState


@dataclasses.dataclass(frozen=True)
class DriveOptions:
    """How the recording becomes the problem `identify` fits.

    Attributes:
        segment: (t0, t1) s to restrict the drive to (default: all of it).
        max_duration: longest window, s (default 20 in torque mode, 10 in speed mode).
        longitudinal: "torque", "speed" (follow the measured speed) or "auto".
        bandwidth: low-pass cutoff, Hz, shared by measured and simulated channels.
        holdout: share of the usable driving held out to validate on (0: none; the estimate is
            always refit on all of it).
        rate: model rate, Hz.
    """

    segment: tuple[float, float] | None = None
    max_duration: float | None = None
    longitudinal: LongitudinalChoice = "auto"
    bandwidth: float | Literal["auto"] | None = "auto"
    holdout: float = 0.3
    rate: float = 200.0


@dataclasses.dataclass(frozen=True)
class ModelOptions:
    """Which model `identify` fits.

    Attributes:
        effects: effects whose parameters join θ; None: `vdsbi.problem.default_effects`.
        add_effects: effects added to `effects` (or to the defaults): what a diagnosis named.
        priors: {name: (low, high)} replacing the prior box of any parameter (e.g. the ranges
            `vdsbi diagnose` measured for an effect's parameters).
    """

    effects: tuple[str, ...] | None = None
    add_effects: tuple[str, ...] = ()
    priors: Mapping[str, tuple[float, float]] = dataclasses.field(default_factory=dict)

    def __post_init__(self):
        if self.effects is not None:
            object.__setattr__(self, "effects", tuple(self.effects))
        object.__setattr__(self, "add_effects", tuple(self.add_effects))


@dataclasses.dataclass(frozen=True)
class Budget:
    """What the estimators spend.

    Attributes:
        rounds, sims: APT rounds and simulations per round of the neural posterior (it proposes
            the likelihood fit's starts).
        epochs: maximum training epochs per round (None: the embedding's default).
        embedding: `vdsbi.inference.StatisticsMLP()` (None, the default) or `TrajectoryCNN()`.
        num_samples: posterior samples kept.
        ppc_draws: posterior draws simulated for the predictive band.
    """

    rounds: int = 2
    sims: int = 1000
    epochs: int | None = None
    embedding: AbstractObservation | None = None
    num_samples: int = 1000
    ppc_draws: int = 100


@dataclasses.dataclass(frozen=True)
class IdentifyOptions:
    """Everything `identify` is told.

    Attributes:
        drive: how the recording becomes the problem.
        model: the effects and the prior box.
        budget: what the estimators spend.
        seed: the only source of randomness; same seed, same machine → identical samples.
        compare: reference values {param: value} (e.g. a lab's) scored on the held-out part.
    """

    drive: DriveOptions = DriveOptions()
    model: ModelOptions = ModelOptions()
    budget: Budget = Budget()
    seed: int = 0
    compare: Mapping[str, Any] | None = None


@dataclasses.dataclass(frozen=True)
class Progress:
    """Where a long run reports.

    Attributes:
        say: receives one-line messages (stages, rounds, the table).
        bars: tqdm bars of each round's simulations and epochs.
        on_round_end: called with the APT state after each round's checkpoint.
    """

    say: Callable[[str], None] = print
    bars: bool = False
    on_round_end: Callable[[APTState], None] | None = None
