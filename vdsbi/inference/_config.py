"""Hyperparameters of the neural posterior estimators: the estimator, its training, the rounds.

Defaults follow ``sbi``'s NSF / SNPE-C.
"""

import dataclasses
from typing import Any

import equinox as eqx

from ._standardize import AbstractStandardization, ChannelStandardization
from ._theta_map import AbstractThetaMap, LogitMap


def _check_common(settings) -> None:
    if not isinstance(settings.theta_map, AbstractThetaMap):
        raise TypeError(f"theta_map must be a LogitMap or an IdentityMap, got {settings.theta_map!r}")
    if not isinstance(settings.x_standardize, AbstractStandardization):
        raise TypeError(f"x_standardize must be an AbstractStandardization, got {settings.x_standardize!r}")


@dataclasses.dataclass(frozen=True, kw_only=True)
class SplineFlowSettings:
    """A conditional neural spline flow (`ConditionalFlow`).

    Attributes:
        num_layers: coupling layers (each followed by a learned LU-linear layer if ``use_lu``).
        num_bins: rational-quadratic spline bins.
        hidden: width of the residual conditioner networks.
        num_blocks: residual blocks per conditioner.
        tail_bound: spline interval ``[-B, B]`` on the standardised logit (or θ) scale; identity
            outside.
        use_lu: learned LU-linear layer after each coupling layer.
        theta_map: `LogitMap` (default: the flow lives on the logit of the box, a bijection) or
            `IdentityMap` (on θ itself, as sbi; density cut at the box without renormalising,
            samples by rejection).
        x_standardize: how x's standardisation is fitted: `ChannelStandardization` (default:
            statistics over all axes but the last), `GlobalStandardization`,
            `TrajectoryStandardization` (minus the mean trajectory, per-channel scale) or
            `NoStandardization`.
    """

    num_layers: int = 5
    num_bins: int = 10
    hidden: int = 50
    num_blocks: int = 2
    tail_bound: float = 3.0
    use_lu: bool = True
    theta_map: AbstractThetaMap = LogitMap()
    x_standardize: AbstractStandardization = ChannelStandardization()

    def __post_init__(self):
        _check_common(self)


@dataclasses.dataclass(frozen=True, kw_only=True)
class FlowMatchingSettings:
    """A flow-matching estimator (FMPE, `FlowMatchingEstimator`). It has no atomic loss:
    amortised NPE (one round) or TSNPE (`RoundSchedule`'s ``truncate=True``) only.

    Attributes:
        hidden, num_blocks, num_freqs: width, residual blocks and time frequencies of the vector
            field.
        ode_steps: fixed Tsit5 steps of the ODE (sampling and ``log_prob``).
        sigma_min: width of the conditional path at ``t = 1``.
        theta_map, x_standardize: as for `SplineFlowSettings`.
    """

    hidden: int = 128
    num_blocks: int = 3
    num_freqs: int = 4
    ode_steps: int = 10
    sigma_min: float = 1e-4
    theta_map: AbstractThetaMap = LogitMap()
    x_standardize: AbstractStandardization = ChannelStandardization()

    def __post_init__(self):
        _check_common(self)


@dataclasses.dataclass(frozen=True, kw_only=True)
class WeightAveraging:
    """An exponential moving average of the weights over training steps; it damps the SGD noise
    a short, early-stopped round leaves in the weights.

    Attributes:
        epochs: its time constant, in epochs (> 0); it starts from the untrained flow.
    """

    epochs: float

    def __post_init__(self):
        if not self.epochs > 0:
            raise ValueError(f"WeightAveraging.epochs must be > 0, got {self.epochs}")


@dataclasses.dataclass(frozen=True, kw_only=True)
class TrainingSettings:
    """One round's training (`fit`; the optimiser is `make_optimizer`'s).

    Attributes:
        batch_size: training batch size (rounded down to a multiple of the device count).
        learning_rate, weight_decay: AdamW.
        clip_norm: global-norm gradient clipping.
        max_epochs, patience: early stopping on validation loss; best weights are restored.
        cosine_decay: False (default): a constant learning rate. True: a round that trains a
            fresh flow decays it per epoch as ``lr·(1 + cos(π·epoch/max_epochs))/2``, so
            unless stopped early it ends on small steps after a fixed budget instead of at a
            noisy early stop, and counts as converged for ``patience_over_new_data``. Rounds
            that continue a trained flow keep the constant rate and early stopping (a cosine
            there would run every later round to its end).
        averaging: None (default) or a `WeightAveraging` of the weights that validation,
            early stopping and the returned flow use.
        validation_fraction: fraction of each round's simulations held out for validation.
    """

    batch_size: int = 128
    learning_rate: float = 5e-4
    weight_decay: float = 0.0
    clip_norm: float = 5.0
    max_epochs: int = 1000
    patience: int = 20
    cosine_decay: bool = False
    averaging: WeightAveraging | None = None
    validation_fraction: float = 0.1

    def __post_init__(self):
        if not 0.0 < self.validation_fraction < 1.0:
            raise ValueError("validation_fraction must be in (0, 1)")
        if self.averaging is not None and not isinstance(self.averaging, WeightAveraging):
            raise TypeError(f"averaging must be a WeightAveraging or None, got {self.averaging!r}")


@dataclasses.dataclass(frozen=True, kw_only=True)
class LeakPenalty:
    """A penalty on the flow's mass outside the box, added to the atomic loss. It matters only
    for an `IdentityMap`, whose mass outside the box the atomic loss cannot see.

    Attributes:
        weight: weight of `leak_penalty` (one draw per example, the squared distance outside
            the box in box widths); > 0.
        rows: rows of each batch the penalty draws for (evenly strided; 0, the default: every
            row). The draw costs about as much as the ten atoms' densities; a subset estimates
            the same penalty.
        at_observation: also penalise the mass outside the box at x_o itself (as many draws as
            ``rows``; `AtomicLoss.leak_at`). False (default): the batch only.
    """

    weight: float
    rows: int = 0
    at_observation: bool = False

    def __post_init__(self):
        if not self.weight > 0:
            raise ValueError(f"LeakPenalty.weight must be > 0, got {self.weight}")
        if self.rows < 0:
            raise ValueError(f"LeakPenalty.rows must be >= 0, got {self.rows}")


@dataclasses.dataclass(frozen=True, kw_only=True)
class Truncation:
    """TSNPE's region: the prior truncated to the posterior's highest-density region.

    Attributes:
        epsilon: posterior mass outside the region.
        samples: posterior samples that locate its density threshold.
    """

    epsilon: float = 1e-4
    samples: int = 10_000

    def __post_init__(self):
        if not 0.0 < self.epsilon < 1.0:
            raise ValueError(f"Truncation.epsilon must be in (0, 1), got {self.epsilon}")
        if self.samples < 1:
            raise ValueError(f"Truncation.samples must be >= 1, got {self.samples}")


@dataclasses.dataclass(frozen=True, kw_only=True)
class SequentialSettings:
    """Rounds after the first (`apt`): their training schedule, APT's loss and TSNPE's region.

    Attributes:
        patience_over_new_data: what ``patience`` counts in a round that continues a trained
            flow. True (default): examples seen, in passes over the round's NEW training
            simulations, i.e. ``ceil(patience * new / all)`` epochs, at least 2; with equal
            rounds, round ``r`` (from 0) waits ``ceil(patience / (r + 1))`` epochs. False:
            epochs over all of a round's training data (sbi's rule). The two agree in round 1,
            for NPE, and after a round that ran out of ``max_epochs``.
        later_max_epochs: opt-in cap for rounds that continue a trained flow, in passes over the
            round's NEW training simulations: ``round(later_max_epochs * new / all)`` epochs, at
            least 2 and at most ``max_epochs``. Such an epoch costs in proportion to all the
            data so far, so the cap bounds every later round's cost to about the same. None
            (default): ``max_epochs``.
        num_atoms: atoms per example in the APT loss (rounds > 1); its cost is linear in it.
            Default: sbi's 10.
        leak: None (default) or a `LeakPenalty` added to the atomic loss.
        truncation: TSNPE's region, for a `RoundSchedule` with ``truncate=True`` (`Truncation`).
    """

    patience_over_new_data: bool = True
    later_max_epochs: int | None = None
    num_atoms: int = 10
    leak: LeakPenalty | None = None
    truncation: Truncation = Truncation()

    def __post_init__(self):
        if self.later_max_epochs is not None and self.later_max_epochs < 1:
            raise ValueError(f"later_max_epochs must be >= 1 or None, got {self.later_max_epochs}")
        if self.leak is not None and not isinstance(self.leak, LeakPenalty):
            raise TypeError(f"leak must be a LeakPenalty or None, got {self.leak!r}")
        if not isinstance(self.truncation, Truncation):
            raise TypeError(f"truncation must be a Truncation, got {self.truncation!r}")
        if self.num_atoms < 2:
            raise ValueError("num_atoms must be >= 2")


@dataclasses.dataclass(frozen=True, kw_only=True)
class NPEConfig:
    """Everything `apt` and `npe` are tuned by, in three groups.

    Attributes:
        flow: the estimator and its architecture: `SplineFlowSettings` (default) or
            `FlowMatchingSettings`.
        training: one round's training (`TrainingSettings`).
        sequential: the rounds after the first (`SequentialSettings`).
    """

    flow: SplineFlowSettings | FlowMatchingSettings = SplineFlowSettings()
    training: TrainingSettings = TrainingSettings()
    sequential: SequentialSettings = SequentialSettings()

    def __post_init__(self):
        if not isinstance(self.flow, (SplineFlowSettings, FlowMatchingSettings)):
            raise TypeError(f"flow must be SplineFlowSettings or FlowMatchingSettings, got {self.flow!r}")


def as_record(settings: Any) -> Any:
    """Settings as JSON-ready nested dicts, a typed choice (a θ map, a standardisation, an
    observation) by its ``name``."""
    if isinstance(settings, eqx.Module) and isinstance(getattr(type(settings), "name", None), str):
        return settings.name
    if dataclasses.is_dataclass(settings):
        return {f.name: as_record(getattr(settings, f.name)) for f in dataclasses.fields(settings)}
    return settings
