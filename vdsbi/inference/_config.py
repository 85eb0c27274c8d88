"""Hyperparameters of the neural posterior estimators (architecture, training, rounds)."""

import dataclasses
from typing import Literal


@dataclasses.dataclass(frozen=True)
class NPEConfig:
    """Architecture and training hyperparameters (defaults follow ``sbi``'s NSF/SNPE-C).

    Attributes:
        num_layers: coupling layers (each followed by a learned LU-linear layer if ``use_lu``).
        num_bins: rational-quadratic spline bins.
        hidden: width of the residual conditioner networks.
        num_blocks: residual blocks per conditioner.
        tail_bound: spline interval ``[-B, B]`` on the standardised logit (or θ) scale; identity
            outside.
        theta_map: ``"logit"`` (default: the flow lives on the logit of the box, a bijection) or
            ``"affine"`` (on θ itself, as sbi; density cut at the box without renormalising,
            samples by rejection). See `ConditionalFlow`.
        use_lu: learned LU-linear layer after each coupling layer.
        context_gating: the context also gates every residual block of the conditioners
            (nflows' ``ResidualNet``, as in sbi's NSF); off by default.
        batch_size: training batch size (rounded down to a multiple of the device count).
        learning_rate, weight_decay: AdamW.
        clip_norm: global-norm gradient clipping.
        max_epochs, patience: early stopping on validation loss; best weights are restored.
        lr_schedule: ``"constant"`` (default) or ``"cosine"``: a round that trains a fresh flow
            (round 1; every round with ``retrain_from_scratch``) decays its learning rate per
            epoch as ``lr·(1 + cos(π·epoch/max_epochs))/2``, so unless stopped early it ends on
            small steps after a fixed budget instead of at a noisy early stop, and counts as
            converged for ``patience_unit="new_data"``. Rounds that continue a trained flow keep
            the constant rate and early stopping (a cosine there would run every later round
            to its end).
        later_max_epochs: opt-in cap for rounds that continue a trained flow, in passes over the
            round's NEW training simulations: ``round(later_max_epochs * new / all)`` epochs, at
            least 2 and at most ``max_epochs``. Such an epoch costs in proportion to all the
            data so far, so the cap bounds every later round's cost to about the same. None
            (default): ``max_epochs``.
        patience_unit: what ``patience`` counts. ``"epochs"``: epochs over all of a round's
            training data (sbi's rule). ``"new_data"`` (default): examples seen, in passes over
            the round's NEW training simulations, i.e. ``ceil(patience * new / all)`` epochs, at
            least 2; with equal rounds, round ``r`` (from 0) waits ``ceil(patience / (r + 1))``
            epochs. The same as ``"epochs"`` in round 1, for NPE, with ``retrain_from_scratch``
            and after a round that ran out of ``max_epochs``.
        average_epochs: 0 (default) or the time constant, in epochs, of an exponential moving
            average of the weights that validation, early stopping and the returned flow use
            (`fit`).
        ensemble: number of flows trained at once (vmapped over members, each on its own loss,
            differing by initialisation); the posterior is their equal-weight mixture
            (`FlowEnsemble`). 1 (default): a single `ConditionalFlow`.
        validation_fraction: fraction of each round's simulations held out for validation.
        num_atoms: atoms per example in the APT loss (rounds > 1); its cost is linear in it.
            Default: sbi's 10.
        combined_loss: add maximum likelihood on prior draws to the atomic loss.
        leak_weight: weight of `leak_penalty` (one draw per example, the squared distance
            outside the box in box widths) added to the atomic loss; matters only for
            ``theta_map="affine"``, whose mass outside the box the atomic loss cannot see.
            0 (default): off.
        leak_rows: rows of each batch the penalty draws for (evenly strided; 0, the default:
            every row). The draw costs about as much as the ten atoms' densities; a subset
            estimates the same penalty.
        leak_at_observation: also penalise the flow's mass outside the box at x_o itself (as
            many draws as ``leak_rows``; `AtomicLoss.leak_at`). False (default): the batch only.
        min_proposal_box_mass: a sequential round whose posterior at x_o has less than this
            share of its mass in the prior box proposes from the prior instead (0, the default:
            never). Below 1 % the rejection sampler repeats draws (under 100·mass of them are
            distinct).
        min_box_mass_ratio: a sequential round after which the posterior at x_o keeps less than
            this share of the box mass it had before the round is undone: its simulations stay,
            the previous round's flow is kept (0, the default: never). Guards the flow on θ
            against sliding out across a face it rests on (`_apt._guard_leak`).
        x_standardize: ``"channel"`` (statistics over all axes but the last), ``"global"``,
            ``"trajectory"`` (minus the mean trajectory, per-channel scale; see `Standardizer.fit`)
            or ``"none"``.
        truncation_epsilon: mass outside the HPD region for ``truncate=True`` (TSNPE).
        truncation_samples: posterior samples used to locate the HPD threshold.
        truncation_widen: widen the HPD region as if the posterior's standard deviations were
            this many times larger (≥ 1; 1, the default, is the plain HPD region). See
            `truncated_prior`.
        retrain_from_scratch: re-initialise the flow every round (default: continue training).
        estimator: ``"nsf"`` (default: the spline flow, fields above) or ``"fmpe"``
            (`FlowMatchingEstimator`, trained by flow matching; ``theta_map``, ``x_standardize``
            and the training fields apply, the spline fields do not). FMPE has no atomic loss:
            amortised NPE (``rounds=1``) or TSNPE (``truncate=True``) only.
        fmpe_hidden, fmpe_num_blocks: width and residual blocks of FMPE's vector field.
        fmpe_ode_steps: fixed Tsit5 steps of FMPE's ODE (sampling and ``log_prob``).
        fmpe_time_power: FMPE training times have density ∝ ``t^fmpe_time_power`` (0: uniform;
            1, the default, weights training towards the data end of the path).
    """

    num_layers: int = 5
    num_bins: int = 10
    hidden: int = 50
    num_blocks: int = 2
    tail_bound: float = 3.0
    use_lu: bool = True
    context_gating: bool = False
    theta_map: Literal["logit", "affine"] = "logit"
    batch_size: int = 128
    learning_rate: float = 5e-4
    weight_decay: float = 0.0
    clip_norm: float = 5.0
    max_epochs: int = 1000
    patience: int = 20
    patience_unit: Literal["epochs", "new_data"] = "new_data"
    lr_schedule: Literal["constant", "cosine"] = "constant"
    later_max_epochs: int | None = None
    average_epochs: float = 0.0
    ensemble: int = 1
    validation_fraction: float = 0.1
    num_atoms: int = 10
    combined_loss: bool = False
    leak_weight: float = 0.0
    leak_rows: int = 0
    leak_at_observation: bool = False
    min_proposal_box_mass: float = 0.0
    min_box_mass_ratio: float = 0.0
    x_standardize: str = "channel"
    truncation_epsilon: float = 1e-4
    truncation_samples: int = 10_000
    truncation_widen: float = 1.0
    retrain_from_scratch: bool = False
    estimator: Literal["nsf", "fmpe"] = "nsf"
    fmpe_hidden: int = 128
    fmpe_num_blocks: int = 3
    fmpe_ode_steps: int = 10
    fmpe_time_power: float = 1.0

    def __post_init__(self):
        if self.estimator not in ("nsf", "fmpe"):
            raise ValueError(f"estimator must be 'nsf' or 'fmpe', got {self.estimator!r}")
        if self.estimator == "fmpe" and self.ensemble > 1:
            raise ValueError("ensemble > 1 is implemented for estimator='nsf' only")
        if self.x_standardize not in ("channel", "global", "trajectory", "none"):
            raise ValueError(
                "x_standardize must be 'channel', 'global', 'trajectory' or 'none', "
                f"got {self.x_standardize!r}"
            )
        if self.patience_unit not in ("epochs", "new_data"):
            raise ValueError(f"patience_unit must be 'epochs' or 'new_data', got {self.patience_unit!r}")
        if not 0.0 < self.validation_fraction < 1.0:
            raise ValueError("validation_fraction must be in (0, 1)")
        if self.lr_schedule not in ("constant", "cosine"):
            raise ValueError(f"lr_schedule must be 'constant' or 'cosine', got {self.lr_schedule!r}")
        if self.theta_map not in ("logit", "affine"):
            raise ValueError(f"theta_map must be 'logit' or 'affine', got {self.theta_map!r}")
        if self.later_max_epochs is not None and self.later_max_epochs < 1:
            raise ValueError(f"later_max_epochs must be >= 1 or None, got {self.later_max_epochs}")
        if self.average_epochs < 0:
            raise ValueError(f"average_epochs must be >= 0, got {self.average_epochs}")
        if self.ensemble < 1:
            raise ValueError(f"ensemble must be >= 1, got {self.ensemble}")
        if self.truncation_widen < 1.0:
            raise ValueError(f"truncation_widen must be >= 1, got {self.truncation_widen}")
        if self.leak_weight < 0:
            raise ValueError(f"leak_weight must be >= 0, got {self.leak_weight}")
        if not 0.0 <= self.min_proposal_box_mass <= 1.0:
            raise ValueError(f"min_proposal_box_mass must be in [0, 1], got {self.min_proposal_box_mass}")
        if not 0.0 <= self.min_box_mass_ratio <= 1.0:
            raise ValueError(f"min_box_mass_ratio must be in [0, 1], got {self.min_box_mass_ratio}")
        if self.leak_rows < 0:
            raise ValueError(f"leak_rows must be >= 0, got {self.leak_rows}")
        if self.leak_at_observation and self.leak_weight == 0:
            raise ValueError("leak_at_observation needs leak_weight > 0 (it adds to that penalty)")
        if self.num_atoms < 2:
            raise ValueError("num_atoms must be >= 2")


TrainConfig = NPEConfig
