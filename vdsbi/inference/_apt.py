"""Sequential neural posterior estimation: NPE (round 1) and APT / SNPE-C (later rounds)."""

import dataclasses
import functools
import math
import time
from collections.abc import Callable, Sequence
from typing import Any, NamedTuple

import equinox as eqx
import jax
import numpy as np
from jaxtyping import Array, PRNGKeyArray

from ._apt_state import APTState
from ._build import build_flow, first_round_loss
from ._config import FlowMatchingSettings, NPEConfig, SequentialSettings, TrainingSettings
from ._embeddings import AbstractEmbedding
from ._estimator import AbstractEstimator
from ._loss import AtomicLoss
from ._posterior import Posterior, on_one_device, sample_flow
from ._prior import BoxPrior
from ._sharding import data_mesh
from ._train import Examples, fit
from ._truncation import truncated_prior


@dataclasses.dataclass(frozen=True, kw_only=True)
class RoundSchedule:
    """The rounds :func:`apt` runs: how many, the simulations in each, and what the rounds after
    the first propose from.

    Attributes:
        rounds: total number of rounds (1: amortised NPE).
        sims_per_round: simulations per round (an int, or one int per round).
        truncate: TSNPE: propose from the prior truncated to the posterior's HPD region
            (trained by maximum likelihood) instead of from the posterior (atomic loss).
    """

    rounds: int
    sims_per_round: int | Sequence[int]
    truncate: bool = False


@dataclasses.dataclass(frozen=True, kw_only=True)
class Execution:
    """How a run is carried out, apart from what it computes: the callbacks it reports to, the
    state it resumes from and the devices it trains on. A resumed run continues exactly as the
    run it was saved from.

    Attributes:
        on_round_end: called with the new `APTState` after each round (e.g. to checkpoint it
            with `save_state`).
        on_epoch_end: ``on_epoch_end(round, epoch, train_loss, val_loss)`` after every
            training epoch.
        on_simulate: ``on_simulate(n)`` before each batch of ``n`` simulations.
        state: resume after the rounds recorded in it (None: start afresh from the key).
        mesh: 1-D device mesh for data parallelism (None: all devices).
    """

    on_round_end: Callable[[APTState], None] | None = None
    on_epoch_end: Callable[[int, int, float, float], None] | None = None
    on_simulate: Callable[[int], None] | None = None
    state: APTState | None = None
    mesh: jax.sharding.Mesh | None = None


@dataclasses.dataclass(frozen=True)
class _Problem:
    """What stays fixed across the rounds of one :func:`apt` call."""

    simulate: Callable[[PRNGKeyArray, Array], tuple[Array, Array]]
    prior: BoxPrior
    x_o: Array
    embedding: AbstractEmbedding
    config: NPEConfig
    truncate: bool
    on_epoch_end: Callable[[int, int, float, float], None] | None
    on_simulate: Callable[[int], None] | None
    mesh: Any


def apt(
    key: PRNGKeyArray,
    simulate: Callable[[PRNGKeyArray, Array], tuple[Array, Array]],
    prior: BoxPrior,
    x_o,
    *,
    embedding: AbstractEmbedding,
    schedule: RoundSchedule,
    config: NPEConfig = NPEConfig(),
    execution: Execution = Execution(),
) -> tuple[Posterior, APTState]:
    """Automatic posterior transformation (APT / SNPE-C); one round is amortised NPE.

    Args:
        key: PRNG key; the only source of randomness (ignored when resuming from
            ``execution.state``).
        simulate: ``simulate(key, theta (N, d)) -> (x (N, ...), valid (N,) bool)``. Draws with
            ``valid=False`` or non-finite x are excluded from training and counted in the history.
        prior: the uniform box prior.
        x_o: the observation (one example).
        embedding: network mapping one standardised x to the flow's context.
        schedule: the rounds, their simulations and their proposal (`RoundSchedule`).
        config: hyperparameters.
        execution: callbacks, the state to resume from and the device mesh (`Execution`).

    Returns:
        ``(posterior at x_o, final state)``.
    """
    rounds, truncate = schedule.rounds, schedule.truncate
    x_o = on_one_device(x_o)
    sims = _sims_schedule(schedule.sims_per_round, rounds)
    if isinstance(config.flow, FlowMatchingSettings) and rounds > 1 and not truncate:
        raise ValueError("flow matching has no atomic (APT) loss: use rounds=1 or truncate=True")
    mesh = data_mesh() if execution.mesh is None else execution.mesh
    problem = _Problem(
        simulate, prior, x_o, embedding, config, truncate, execution.on_epoch_end, execution.on_simulate, mesh
    )
    state = execution.state
    if state is None:
        state = _initial_state(key, prior, x_o)
    for r in range(state.round, rounds):
        state = _run_round(problem, state, r, sims[r])
        if execution.on_round_end is not None:
            execution.on_round_end(state)
    if state.flow is None:
        raise ValueError("rounds must be >= 1")
    return Posterior(state.flow, x_o), state


def _sims_schedule(sims_per_round: int | Sequence[int], rounds: int) -> list[int]:
    """Simulations in each round: ``sims_per_round`` repeated, or checked to have one per round."""
    sims = (
        [int(sims_per_round)] * rounds if np.ndim(sims_per_round) == 0 else [int(s) for s in sims_per_round]
    )
    if len(sims) != rounds:
        raise ValueError(f"sims_per_round has {len(sims)} entries for {rounds} rounds")
    return sims


def _initial_state(key: PRNGKeyArray, prior: BoxPrior, x_o: Array) -> APTState:
    """The state before round 1: no simulations, no estimator; rounds start from ``key``."""
    return APTState(
        round=0,
        key=key,
        theta=np.zeros((0, prior.dim), np.float32),
        x=np.zeros((0, *x_o.shape), np.float32),
        round_ids=np.zeros((0,), np.int32),
        is_val=np.zeros((0,), bool),
        flow=None,
    )


def _run_round(problem: _Problem, state: APTState, r: int, n: int) -> APTState:
    """Round ``r``: propose ``n`` parameters, simulate them, train on all kept data, record."""
    t0 = time.perf_counter()
    k_round, k_next = jax.random.split(state.key)
    k_prop, k_sim, k_split, k_init, k_train = jax.random.split(k_round, 5)
    info: dict[str, Any] = {"round": r, "num_simulations": n}
    theta, proposal_info = _propose(problem, state.flow, r, k_prop, n)
    info.update(proposal_info)
    theta, x, sim_info = _simulate_kept(problem, k_sim, theta, n)
    info.update(sim_info)
    fraction = problem.config.training.validation_fraction
    data = _append_round(state, theta, x, r, k_split, fraction)
    previous = state.history[-1] if state.history else None
    config = problem.config
    patience = _round_patience(config.training, config.sequential, data.round_ids, data.is_val, r, previous)
    flow, fit_info = _train_round(problem, state.flow, r, (k_init, k_train), data, patience)
    info.update(fit_info, train_s=time.perf_counter() - t0)
    return APTState(
        round=r + 1,
        key=k_next,
        theta=data.theta,
        x=data.x,
        round_ids=data.round_ids,
        is_val=data.is_val,
        flow=flow,
        history=(*state.history, info),
    )


def _propose(
    problem: _Problem, flow: AbstractEstimator | None, r: int, key: PRNGKeyArray, n: int
) -> tuple[Array, dict[str, Any]]:
    """``n`` parameters for round ``r``: from the prior, the truncated prior or the posterior."""
    if r == 0 or flow is None:
        return problem.prior.sample(key, n), {"proposal": "prior"}
    if problem.truncate:
        seq = problem.config.sequential
        theta, tinfo = truncated_prior(
            key, flow, problem.prior, problem.x_o, n, seq.truncation.epsilon, seq.truncation.samples
        )
        return theta, {"proposal": "truncated_prior", **tinfo}
    k_draw, k_mass = jax.random.split(key)
    mass = float(_box_mass(flow, k_mass, problem.x_o, _BOX_MASS_DRAWS))
    return sample_flow(flow, k_draw, problem.x_o, n), {"proposal": "posterior", "box_mass": mass}


_BOX_MASS_DRAWS = 10_000


@eqx.filter_jit
def _box_mass(flow, key, x, n):
    return flow.box_mass(key, flow.context(x), n)


def _simulate_kept(
    problem: _Problem, key: PRNGKeyArray, theta: Array, n: int
) -> tuple[np.ndarray, np.ndarray, dict[str, int]]:
    """Simulate ``theta``; keep the valid, finite draws and count the discarded ones."""
    if problem.on_simulate is not None:
        problem.on_simulate(theta.shape[0])
    x, valid = problem.simulate(key, theta)
    theta, x = np.asarray(theta, np.float32), np.asarray(x, np.float32)
    valid = np.asarray(valid, bool).reshape(n)
    x_shape = problem.x_o.shape
    if x.shape[0] != n or x.shape[1:] != x_shape:
        raise ValueError(f"simulate returned x of shape {x.shape}; expected ({n}, *{x_shape})")
    finite = np.all(np.isfinite(x.reshape(n, -1)), axis=1)
    keep = valid & finite
    counts = {
        "num_invalid": int((~valid).sum()),
        "num_nonfinite": int((valid & ~finite).sum()),
        "num_used": int(keep.sum()),
    }
    return theta[keep], x[keep], counts


class _Data(NamedTuple):
    """All kept simulations so far, each with its round and whether it is held out."""

    theta: np.ndarray
    x: np.ndarray
    round_ids: np.ndarray
    is_val: np.ndarray


def _append_round(
    state: APTState, theta: np.ndarray, x: np.ndarray, r: int, key: PRNGKeyArray, fraction: float
) -> _Data:
    """``state``'s data plus round ``r``'s kept draws, a ``fraction`` of them held out for validation."""
    m = theta.shape[0]
    n_val = max(1, int(round(fraction * m)))
    is_val_new = np.zeros(m, bool)
    is_val_new[np.asarray(jax.random.permutation(key, m))[:n_val]] = True
    return _Data(
        np.concatenate([state.theta, theta]),
        np.concatenate([state.x, x]),
        np.concatenate([state.round_ids, np.full(m, r, np.int32)]),
        np.concatenate([state.is_val, is_val_new]),
    )


def _train_round(
    problem: _Problem,
    flow: AbstractEstimator | None,
    r: int,
    keys: tuple[PRNGKeyArray, PRNGKeyArray],
    data: _Data,
    patience: int,
) -> tuple[AbstractEstimator, dict[str, Any]]:
    """Train the flow on all kept data (``keys = (k_init, k_train)``; a new flow from
    ``k_init`` in round 1)."""
    config, seq = problem.config, problem.config.sequential
    k_init, k_train = keys
    theta, x, round_ids, is_val = data
    fresh = flow is None
    if fresh:
        flow = build_flow(k_init, problem.prior, problem.embedding, theta[~is_val], x[~is_val], config.flow)
        training = dataclasses.replace(config.training, patience=patience)
    else:  # see TrainingSettings.cosine_decay
        max_epochs = _later_max_epochs(config.training, seq, round_ids, is_val, r)
        training = dataclasses.replace(
            config.training, max_epochs=max_epochs, patience=patience, cosine_decay=False
        )
    if r == 0 or problem.truncate:
        loss = first_round_loss(config.flow)
    else:
        loss = _atomic_loss(seq, problem.x_o)
    report = None if problem.on_epoch_end is None else functools.partial(problem.on_epoch_end, r)
    examples = Examples(theta, x, round_ids == 0, is_val)
    flow, finfo = fit(k_train, flow, examples, loss, training, on_epoch_end=report, mesh=problem.mesh)
    info = {"loss": type(loss).__name__, "patience": patience, "cosine_decay": training.cosine_decay}
    return flow, {**finfo, **info, "max_epochs": training.max_epochs}


def _atomic_loss(seq: SequentialSettings, x_o: Array) -> AtomicLoss:
    """The atomic loss of ``seq``, with its `LeakPenalty` if any."""
    leak = seq.leak
    if leak is None:
        return AtomicLoss(num_atoms=seq.num_atoms)
    return AtomicLoss(
        num_atoms=seq.num_atoms,
        leak_weight=leak.weight,
        leak_rows=leak.rows,
        leak_at=np.asarray(x_o) if leak.at_observation else None,
    )


_MIN_PATIENCE = 2


def _round_patience(
    training: TrainingSettings,
    seq: SequentialSettings,
    round_ids: np.ndarray,
    is_val: np.ndarray,
    r: int,
    previous: dict | None,
) -> int:
    """Early-stopping patience in epochs for round ``r`` (see ``SequentialSettings.patience_over_new_data``).

    A flow carried over from a previous round that stopped early has already fitted the older
    draws; how many updates it needs to take in a round's new draws scales with their number,
    not with all the data: waiting ``patience`` epochs over everything would make late rounds
    pay mostly for waiting. A previous round cut off by ``max_epochs`` had not converged: full
    patience then.
    """
    # a decaying schedule that ran its course ended on small steps: converged by design
    ran_out = previous is not None and previous["epochs"] >= previous.get("max_epochs", training.max_epochs)
    decayed = previous is not None and previous.get("cosine_decay", False)
    converged = previous is not None and (not ran_out or decayed)
    if not seq.patience_over_new_data or not converged:
        return training.patience
    num_new, num_all = _new_and_all(round_ids, is_val, r)
    scaled = math.ceil(training.patience * num_new / num_all)
    # at least two epochs: one noisy validation epoch must not end a round
    return min(training.patience, max(_MIN_PATIENCE, scaled))


def _new_and_all(round_ids: np.ndarray, is_val: np.ndarray, r: int) -> tuple[int, int]:
    """Round ``r``'s training examples and all training examples (at least 1)."""
    train = ~is_val
    return int(np.sum(train & (round_ids == r))), max(int(np.sum(train)), 1)


def _later_max_epochs(
    training: TrainingSettings, seq: SequentialSettings, round_ids: np.ndarray, is_val: np.ndarray, r: int
) -> int:
    """Epoch cap of round ``r`` continuing a trained flow (see ``SequentialSettings.later_max_epochs``)."""
    if seq.later_max_epochs is None:
        return training.max_epochs
    # rounded, not ceil'd: one invalid draw must not add an epoch (15.002 -> 16)
    num_new, num_all = _new_and_all(round_ids, is_val, r)
    capped = round(seq.later_max_epochs * num_new / num_all)
    return min(training.max_epochs, max(_MIN_PATIENCE, capped))
