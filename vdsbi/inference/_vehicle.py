"""Identifying a vehicle's θ by APT: the simulator, the observation's form and the embedding."""

import dataclasses
from collections.abc import Callable

import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float, PRNGKeyArray

from ..io import InputError, SimulationError
from ..simulator import PARAM_NAMES
from ..simulator.measurement import StochasticSimulator
from ._apt import Execution, RoundSchedule, apt
from ._apt_state import APTState
from ._config import NPEConfig
from ._observation import AbstractObservation, TrajectoryCNN
from ._posterior import Posterior
from ._prior import BoxPrior


@dataclasses.dataclass(frozen=True)
class IdentifySettings:
    """How to identify.

    Attributes:
        rounds: APT rounds (1 = amortised NPE from the prior).
        sims_per_round: simulations per round.
        embedding: what the estimator sees and the net that embeds it: `TrajectoryCNN`
            (default) or `StatisticsMLP`.
        embed_dim: embedding size.
        num_samples: posterior samples to return.
        truncate: TSNPE (default): later rounds draw from the prior truncated to the current
            posterior's highest-density region and train by maximum likelihood (Deistler et
            al. 2022); False: APT's posterior proposals and atomic loss (Greenberg et al. 2019),
            which on the seed's maneuver can leave much of the posterior in a spurious mode.
        config: flow and training hyperparameters (default: the embedding's
            ``default_config``; one given is used as given). Later rounds
            wait ``ceil(patience · new/all)`` epochs (``patience_over_new_data``), as for the
            other tasks.
    """

    rounds: int = 5
    sims_per_round: int = 5000
    embedding: AbstractObservation = TrajectoryCNN()
    embed_dim: int = 32
    num_samples: int = 1000
    truncate: bool = True
    config: NPEConfig | None = None

    def __post_init__(self):
        if not isinstance(self.embedding, AbstractObservation):
            what = f"must be TrajectoryCNN() or StatisticsMLP(), got {self.embedding!r}"
            raise InputError("settings", "embedding", what)
        if self.config is None:  # the embedding's own training default
            object.__setattr__(self, "config", self.embedding.default_config)
        if self.rounds < 1:
            raise InputError("settings", "rounds", f"must be >= 1, got {self.rounds}")
        if self.sims_per_round < 10:
            raise InputError("settings", "sims_per_round", f"must be >= 10, got {self.sims_per_round}")


#: Fewest usable simulations training can start from: two to train on, one to validate.
MIN_USABLE_SIMULATIONS = 3


def seed_prior(literal: bool = False) -> BoxPrior:
    """The seed's Table II prior box, in absolute units.

    Literal: l_f ∈ [1, 1.5], h ∈ [0.2, 0.6], ΔC_κ ∈ [−2, 0.5]·1e5 around 1e5 (so C_κ down to
    −1e5 N: negative stiffness; the simulator masks those draws), ΔC_α ∈ ±0.3·1e5 around 6e4.
    Physical (default): C_κ ≥ 2e4 N (≈ 3× the axle load; softer tires do not exist), and
    l_f up to 1.7 m, because the seed's true l_f = 1.5 sits on its prior's edge, where no
    95 % interval of a posterior on the box can contain it.
    """
    if literal:
        lo = [1.0, 0.2, 1e5 - 2e5, 1e5 - 2e5, 6e4 - 3e4, 6e4 - 3e4]
        hi = [1.5, 0.6, 1e5 + 0.5e5, 1e5 + 0.5e5, 6e4 + 3e4, 6e4 + 3e4]
    else:
        lo = [1.0, 0.2, 2e4, 2e4, 6e4 - 3e4, 6e4 - 3e4]
        hi = [1.7, 0.6, 1.5e5, 1.5e5, 6e4 + 3e4, 6e4 + 3e4]
    return BoxPrior(jnp.array(lo), jnp.array(hi), names=PARAM_NAMES)


def identify(
    key: PRNGKeyArray,
    simulator: StochasticSimulator,
    prior: BoxPrior,
    readings_o: Float[Array, "T C"],
    settings: IdentifySettings = IdentifySettings(),
    *,
    execution: Execution = Execution(),
) -> tuple[Posterior, np.ndarray, APTState]:
    """Posterior over θ given one recording's measured channels.

    Args:
        key: PRNG key (all randomness).
        simulator: p(x | θ) for the recording's inputs and channels.
        prior: uniform box over θ (PARAM_NAMES order).
        readings_o: observed channels, (T, C) in `simulator.channels` order.
        settings: rounds, budget, embedding.
        execution: progress and checkpoint callbacks, a checkpoint to resume from, the device
            mesh (see `Execution`).

    Returns:
        (posterior at the observation, (num_samples, 6) samples, final APT state).

    Raises:
        SimulationError: fewer than `MIN_USABLE_SIMULATIONS` usable simulations after a round.
    """
    readings_o = jnp.asarray(readings_o, dtype=jnp.float32)
    if readings_o.shape[-1] != len(simulator.channels):
        raise ValueError(
            f"observation has {readings_o.shape[-1]} channels, simulator {len(simulator.channels)}"
        )
    inp = simulator.inputs
    u = jnp.stack([inp.steer, inp.torque_front, inp.torque_rear], axis=-1).astype(jnp.float32)
    # Inputs are standardised per channel by the flow's x-standardiser like any channel.
    obs = jax.jit(jax.vmap(lambda r: settings.embedding(r, u)))
    x_o = obs(readings_o[None])[0]

    def simulate(k, theta):
        ys, ok = simulator(k, jnp.asarray(theta, jnp.float32))
        return obs(ys), ok

    return fit_posterior(key, simulate, prior, x_o, settings, execution=execution)


def fit_posterior(
    key: PRNGKeyArray,
    simulate: Callable,
    prior: BoxPrior,
    x_o,
    settings: IdentifySettings,
    *,
    execution: Execution = Execution(),
) -> tuple[Posterior, np.ndarray, APTState]:
    """APT with `settings`' embedding and budget on `simulate(key, θ) -> (x, ok)` at `x_o`.

    Raises:
        SimulationError: fewer than `MIN_USABLE_SIMULATIONS` usable simulations after a round.
    """
    state = execution.state
    usable = [0 if state is None else int(state.x.shape[0])]

    def guarded(k, theta):
        x, ok = simulate(k, theta)
        finite = np.all(np.isfinite(np.asarray(x).reshape(x.shape[0], -1)), axis=1)
        usable[0] += int(np.sum(np.asarray(ok) & finite))
        if usable[0] < MIN_USABLE_SIMULATIONS:
            raise SimulationError(usable[0], theta.shape[0])
        return x, ok

    k_emb, k_apt, k_s = jax.random.split(key, 3)
    embedding = settings.embedding.embedding(k_emb, x_o.shape, settings.embed_dim)
    schedule = RoundSchedule(
        rounds=settings.rounds, sims_per_round=settings.sims_per_round, truncate=settings.truncate
    )
    posterior, state = apt(
        k_apt,
        guarded,
        prior,
        x_o,
        embedding=embedding,
        schedule=schedule,
        config=settings.config,
        execution=execution,
    )
    samples = np.asarray(posterior.sample(k_s, settings.num_samples))
    return posterior, samples, state
