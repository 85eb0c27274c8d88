"""Sequential neural posterior estimation: NPE (round 1) and APT / SNPE-C (later rounds)."""

import dataclasses
import math
import time
from collections.abc import Callable, Sequence
from typing import Any, Literal

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, PRNGKeyArray

from ._embeddings import AbstractEmbedding
from ._flow import ConditionalFlow, FlowEnsemble
from ._flow_matching import FlowMatchingEstimator, FlowMatchingLoss
from ._loss import AtomicLoss, MaximumLikelihoodLoss
from ._posterior import Posterior, _log_prob, _sample
from ._prior import BoxPrior
from ._serialise import FORMAT_VERSION, flow_from_bytes, flow_to_bytes, read_npz, write_npz
from ._sharding import data_mesh
from ._standardize import Standardizer
from ._train import fit


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
            the constant rate and early stopping (a 30-epoch cosine there ran round 2 of the
            vehicle's Table II to its end, 124 s instead of ~45 s).
        later_max_epochs: opt-in cap for rounds that continue a trained flow, in passes over the
            round's NEW training simulations: ``round(later_max_epochs * new / all)`` epochs, at
            least 2 and at most ``max_epochs``. Such an epoch costs in proportion to all the
            data so far, so the cap bounds every later round's cost to about the same (the
            vehicle's Table II, whose later rounds ran 3-20 epochs). None (default): ``max_epochs``.
        patience_unit: what ``patience`` counts. ``"epochs"``: epochs over all of a round's
            training data (sbi's rule). ``"new_data"`` (default): examples seen, in passes over
            the round's NEW training simulations, i.e. ``ceil(patience * new / all)`` epochs, at
            least 2; with equal rounds, round ``r`` (from 0) waits ``ceil(patience / (r + 1))``
            epochs. The same as ``"epochs"`` in round 1, for NPE, with ``retrain_from_scratch``
            and after a round that ran out of ``max_epochs``. APT two_moons at 10⁴, sbibm
            observation 1: 243 → 65 s, C2ST 0.548 → 0.552 (``benchmarks/results/apt_patience/``).
        ensemble: number of flows trained at once (vmapped over members, each on its own loss,
            differing by initialisation); the posterior is their equal-weight mixture
            (`FlowEnsemble`). 1 (default): a single `ConditionalFlow`.
        validation_fraction: fraction of each round's simulations held out for validation.
        num_atoms: atoms per example in the APT loss (rounds > 1).
        combined_loss: add maximum likelihood on prior draws to the atomic loss.
        x_standardize: ``"channel"`` (statistics over all axes but the last), ``"global"``,
            ``"trajectory"`` (minus the mean trajectory, per-channel scale; see `Standardizer.fit`)
            or ``"none"``.
        truncation_epsilon: mass outside the HPD region for ``truncate=True`` (TSNPE).
        truncation_samples: posterior samples used to locate the HPD threshold.
        retrain_from_scratch: re-initialise the flow every round (default: continue training).
        estimator: ``"nsf"`` (default: the spline flow, fields above) or ``"fmpe"``
            (`FlowMatchingEstimator`, trained by flow matching; ``theta_map``, ``x_standardize``
            and the training fields apply, the spline fields do not). FMPE has no atomic loss:
            amortised NPE (``rounds=1``) or TSNPE (``truncate=True``) only.
        fmpe_hidden, fmpe_num_blocks: width and residual blocks of FMPE's vector field.
        fmpe_ode_steps: fixed Tsit5 steps of FMPE's ODE (sampling and ``log_prob``).
        fmpe_time_power: FMPE training times have density ∝ ``t^fmpe_time_power`` (0: uniform;
            1, the default, beat 0 on held-out NLL: two_moons 10⁴ −3.70 vs −3.51, slcp 10⁴ 4.95
            vs 5.33, ``benchmarks/results/fmpe_tuning.jsonl``).
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
    ensemble: int = 1
    validation_fraction: float = 0.1
    num_atoms: int = 10
    combined_loss: bool = False
    x_standardize: str = "channel"
    truncation_epsilon: float = 1e-4
    truncation_samples: int = 10_000
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
        if self.ensemble < 1:
            raise ValueError(f"ensemble must be >= 1, got {self.ensemble}")
        if self.num_atoms < 2:
            raise ValueError("num_atoms must be >= 2")


TrainConfig = NPEConfig


@dataclasses.dataclass(frozen=True)
class APTState:
    """Everything needed to resume :func:`apt` exactly after a finished round.

    Attributes:
        round: number of completed rounds.
        key: the PRNG key the next round starts from.
        theta: ``(N, d)`` parameters of all kept (valid, finite) simulations so far.
        x: ``(N, ...)`` their simulations.
        round_ids: ``(N,)`` round in which each simulation was made (0 = prior draws).
        is_val: ``(N,)`` held out for validation (fixed when the simulation is made).
        flow: the current estimator (None before round 1 finishes).
        history: one dict per round: simulation counts (incl. ``num_invalid``,
            ``num_nonfinite``, ``num_used``), proposal, epochs, losses, wall time.
    """

    round: int
    key: PRNGKeyArray
    theta: np.ndarray
    x: np.ndarray
    round_ids: np.ndarray
    is_val: np.ndarray
    flow: ConditionalFlow | None
    history: tuple[dict[str, Any], ...] = ()

    @property
    def num_invalid(self) -> int:
        """Total simulations discarded (``valid=False`` or non-finite) over all rounds."""
        return sum(h["num_invalid"] + h["num_nonfinite"] for h in self.history)


def save_state(path, state: APTState) -> None:
    """Write ``state`` to ONE file atomically (temp file + ``os.replace``)."""
    header = {
        "kind": "APTState",
        "version": FORMAT_VERSION,
        "round": state.round,
        "history": list(state.history),
        "flow": None if state.flow is None else state.flow.spec(),
    }
    arrays = {
        "key": np.asarray(jax.random.key_data(state.key)),
        "theta": state.theta,
        "x": state.x,
        "round_ids": state.round_ids,
        "is_val": state.is_val,
    }
    if state.flow is not None:
        arrays["flow"] = flow_to_bytes(state.flow)
    write_npz(path, header, arrays)


def load_state(path, like: APTState | None = None) -> APTState:
    """Read a state written by :func:`save_state`.

    ``like`` is accepted for API symmetry; the estimator is rebuilt from the stored spec.
    """
    del like
    header, arrays = read_npz(path)
    if header.get("kind") != "APTState":
        raise ValueError(f"{path} does not hold an APTState (kind={header.get('kind')!r})")
    flow = None if header["flow"] is None else flow_from_bytes(header["flow"], arrays["flow"])
    return APTState(
        round=int(header["round"]),
        key=jax.random.wrap_key_data(jnp.asarray(arrays["key"])),
        theta=arrays["theta"],
        x=arrays["x"],
        round_ids=arrays["round_ids"],
        is_val=arrays["is_val"],
        flow=flow,
        history=tuple(header["history"]),
    )


def build_flow(
    key: PRNGKeyArray,
    prior: BoxPrior,
    embedding: AbstractEmbedding,
    theta: np.ndarray,
    x: np.ndarray,
    config: NPEConfig,
) -> ConditionalFlow | FlowEnsemble:
    """A fresh flow (``config.ensemble > 1``: an ensemble of them, sharing the standardisations)
    whose θ (logit- or θ-scale) and x standardisations are fitted on ``theta``/``x``."""
    z = jnp.asarray(theta)
    if config.theta_map == "logit":
        z, _ = jax.vmap(prior.to_unbounded)(z)
    x_standardizer = Standardizer.fit(jnp.asarray(x), config.x_standardize)
    # data-dependent initialisation of the embedding (a fixed subset bounds the cost)
    embedding = embedding.calibrate(jax.vmap(x_standardizer)(jnp.asarray(x[:2048])))
    theta_standardizer = Standardizer.fit(z, "channel")

    def make(k):
        if config.estimator == "fmpe":
            return FlowMatchingEstimator(
                k,
                prior,
                embedding,
                x.shape[1:],
                hidden=config.fmpe_hidden,
                num_blocks=config.fmpe_num_blocks,
                ode_steps=config.fmpe_ode_steps,
                time_power=config.fmpe_time_power,
                theta_map=config.theta_map,
                theta_standardizer=theta_standardizer,
                x_standardizer=x_standardizer,
            )
        return ConditionalFlow(
            k,
            prior,
            embedding,
            x.shape[1:],
            num_layers=config.num_layers,
            num_bins=config.num_bins,
            hidden=config.hidden,
            num_blocks=config.num_blocks,
            tail_bound=config.tail_bound,
            use_lu=config.use_lu,
            context_gating=config.context_gating,
            theta_map=config.theta_map,
            theta_standardizer=theta_standardizer,
            x_standardizer=x_standardizer,
        )

    if config.ensemble > 1:  # members share the embedding's initial weights, not the flows'
        return _init_compiled(lambda k: FlowEnsemble(make, jax.random.split(k, config.ensemble)), key)
    return _init_compiled(make, key)


# XLA's CPU backend at optimisation level 1 (default 2+). Used for the initialisation only: the
# training steps also compile faster at level 1 and took 88 instead of 124 ms per epoch in one
# A/B (two_moons 10⁴, s7), but their results are not bit-identical, and over 4 training seeds
# two_moons 10⁴ scored C2ST 0.554 against 0.544 (benchmarks/results/vs_sbi_variants.jsonl,
# "affine_s7" vs "affine"): not adopted on that evidence.
_INIT_CPU_OPTIONS = {"xla_backend_optimization_level": 1}


def _init_compiled(make: Callable[[PRNGKeyArray], Any], key: PRNGKeyArray):
    """``make(key)`` as one compiled program (on the CPU at XLA optimisation level 1).

    Built op by op, the initialisation compiled dozens of small kernels (~2-5 s of a
    10⁴-simulation NPE run); as one program at the CPU's default level its threefry draws
    still took ~1.5 s to compile for a program that runs once. Level 1 gives the same weights
    bit for bit in about half the time (``benchmarks/results/train_profile.md``).
    """
    options = _INIT_CPU_OPTIONS if jax.default_backend() == "cpu" else None
    arrays = jax.jit(lambda k: eqx.filter(make(k), eqx.is_array), compiler_options=options)(key)
    shapes = eqx.filter_eval_shape(make, key)
    static = eqx.filter(shapes, lambda a: isinstance(a, jax.ShapeDtypeStruct), inverse=True)
    return eqx.combine(arrays, static)


def _truncated_prior(key, flow, prior, x_o, n, config) -> tuple[Array, dict]:
    """Prior restricted to the ``1 - ε`` highest-density region of ``flow`` at ``x_o`` (TSNPE)."""
    k_q, key = jax.random.split(key)
    ref = _sample(flow, k_q, x_o, config.truncation_samples)
    threshold = jnp.quantile(_log_prob(flow, ref, x_o), config.truncation_epsilon)
    out, drawn = [], 0
    for _ in range(200):
        key, k = jax.random.split(key)
        cand = prior.sample(k, max(n, 10_000))
        drawn += cand.shape[0]
        out.append(np.asarray(cand[_log_prob(flow, cand, x_o) >= threshold]))
        if sum(o.shape[0] for o in out) >= n:
            break
    acc = np.concatenate(out)[:n]
    info = {"acceptance": acc.shape[0] / drawn, "num_from_posterior": int(n - acc.shape[0])}
    if acc.shape[0] < n:  # region too small to reach by rejection: fill with posterior draws
        acc = np.concatenate([acc, np.asarray(_sample(flow, key, x_o, n - acc.shape[0]))])
    return jnp.asarray(acc), info


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
    mesh: Any


def apt(
    key: PRNGKeyArray,
    simulate: Callable[[PRNGKeyArray, Array], tuple[Array, Array]],
    prior: BoxPrior,
    x_o,
    *,
    embedding: AbstractEmbedding,
    rounds: int,
    sims_per_round: int | Sequence[int],
    config: NPEConfig = NPEConfig(),
    truncate: bool = False,
    on_round_end: Callable[[APTState], None] | None = None,
    on_epoch_end: Callable[[int, int, float, float], None] | None = None,
    state: APTState | None = None,
    mesh=None,
) -> tuple[Posterior, APTState]:
    """Automatic posterior transformation (APT / SNPE-C); ``rounds=1`` is amortised NPE.

    Args:
        key: PRNG key; the only source of randomness (ignored when resuming from ``state``).
        simulate: ``simulate(key, theta (N, d)) -> (x (N, ...), valid (N,) bool)``. Draws with
            ``valid=False`` or non-finite x are excluded from training and counted in the history.
        prior: the uniform box prior.
        x_o: the observation (one example).
        embedding: network mapping one standardised x to the flow's context.
        rounds: total number of rounds.
        sims_per_round: simulations per round (an int or one int per round).
        config: hyperparameters.
        truncate: TSNPE — propose from the prior truncated to the posterior's HPD region
            (trained by maximum likelihood) instead of from the posterior (atomic loss).
        on_round_end: called with the new state after each round (e.g. for checkpointing).
        on_epoch_end: ``on_epoch_end(round, epoch, train_loss, val_loss)``.
        state: resume after the rounds recorded in it.
        mesh: 1-D device mesh for data parallelism (default: all devices).

    Returns:
        ``(posterior at x_o, final state)``.
    """
    # Through the host: an observation simulated under sharding lives on several devices,
    # and the flow's parameters on one.
    x_o = jnp.asarray(np.asarray(x_o))
    sims = _sims_schedule(sims_per_round, rounds)
    if config.estimator == "fmpe" and rounds > 1 and not truncate:
        raise ValueError("estimator='fmpe' has no atomic (APT) loss: use rounds=1 or truncate=True")
    mesh = data_mesh() if mesh is None else mesh
    problem = _Problem(simulate, prior, x_o, embedding, config, truncate, on_epoch_end, mesh)
    if state is None:
        state = _initial_state(key, prior, x_o)
    for r in range(state.round, rounds):
        state = _run_round(problem, state, r, sims[r])
        if on_round_end is not None:
            on_round_end(state)
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
    all_theta, all_x, round_ids, is_val = _append_round(state, theta, x, r, k_split, problem.config)
    previous = state.history[-1] if state.history else None
    patience = _round_patience(problem.config, round_ids, is_val, r, previous)
    flow, fit_info = _train_round(
        problem, state.flow, r, k_init, k_train, all_theta, all_x, round_ids, is_val, patience
    )
    info.update(fit_info, train_s=time.perf_counter() - t0)
    return APTState(
        round=r + 1,
        key=k_next,
        theta=all_theta,
        x=all_x,
        round_ids=round_ids,
        is_val=is_val,
        flow=flow,
        history=(*state.history, info),
    )


def _propose(
    problem: _Problem, flow: ConditionalFlow | None, r: int, key: PRNGKeyArray, n: int
) -> tuple[Array, dict[str, Any]]:
    """``n`` parameters for round ``r``: from the prior, the truncated prior or the posterior."""
    if r == 0 or flow is None:
        return problem.prior.sample(key, n), {"proposal": "prior"}
    if problem.truncate:
        theta, tinfo = _truncated_prior(key, flow, problem.prior, problem.x_o, n, problem.config)
        return theta, {"proposal": "truncated_prior", **tinfo}
    return _sample(flow, key, problem.x_o, n), {"proposal": "posterior"}


def _simulate_kept(
    problem: _Problem, key: PRNGKeyArray, theta: Array, n: int
) -> tuple[np.ndarray, np.ndarray, dict[str, int]]:
    """Simulate ``theta``; keep the valid, finite draws and count the discarded ones."""
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


def _append_round(
    state: APTState, theta: np.ndarray, x: np.ndarray, r: int, key: PRNGKeyArray, config: NPEConfig
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """``state``'s data plus round ``r``'s kept draws, a random share of them held out for validation."""
    m = theta.shape[0]
    n_val = max(1, int(round(config.validation_fraction * m)))
    is_val_new = np.zeros(m, bool)
    is_val_new[np.asarray(jax.random.permutation(key, m))[:n_val]] = True
    return (
        np.concatenate([state.theta, theta]),
        np.concatenate([state.x, x]),
        np.concatenate([state.round_ids, np.full(m, r, np.int32)]),
        np.concatenate([state.is_val, is_val_new]),
    )


def _train_round(
    problem: _Problem,
    flow: ConditionalFlow | None,
    r: int,
    k_init: PRNGKeyArray,
    k_train: PRNGKeyArray,
    theta: np.ndarray,
    x: np.ndarray,
    round_ids: np.ndarray,
    is_val: np.ndarray,
    patience: int,
) -> tuple[ConditionalFlow, dict[str, Any]]:
    """Train the flow on all kept data (a new one from ``k_init`` if none or retraining from scratch)."""
    config = problem.config
    fresh = flow is None or config.retrain_from_scratch
    schedule = config.lr_schedule if fresh else "constant"  # see NPEConfig.lr_schedule
    if fresh:
        flow = build_flow(k_init, problem.prior, problem.embedding, theta[~is_val], x[~is_val], config)
    max_epochs = config.max_epochs if fresh else _later_max_epochs(config, round_ids, is_val, r)
    if r == 0 or problem.truncate:
        loss = first_round_loss(config)
    else:
        loss = AtomicLoss(num_atoms=config.num_atoms, combined=config.combined_loss)
    flow, finfo = fit(
        k_train,
        flow,
        theta,
        x,
        round_ids == 0,
        is_val,
        loss,
        batch_size=config.batch_size,
        learning_rate=config.learning_rate,
        weight_decay=config.weight_decay,
        clip_norm=config.clip_norm,
        max_epochs=max_epochs,
        patience=patience,
        on_epoch_end=problem.on_epoch_end,
        round_index=r,
        mesh=problem.mesh,
        lr_schedule=schedule,
    )
    info = {"loss": type(loss).__name__, "patience": patience, "lr_schedule": schedule}
    return flow, {**finfo, **info, "max_epochs": max_epochs}


def first_round_loss(config: NPEConfig) -> MaximumLikelihoodLoss | FlowMatchingLoss:
    """The loss on prior (or truncated-prior) draws: maximum likelihood, or flow matching."""
    return FlowMatchingLoss() if config.estimator == "fmpe" else MaximumLikelihoodLoss()


_MIN_PATIENCE = 2


def _round_patience(
    config: NPEConfig, round_ids: np.ndarray, is_val: np.ndarray, r: int, previous: dict | None
) -> int:
    """Early-stopping patience in epochs for round ``r`` (see ``NPEConfig.patience_unit``).

    A flow carried over from a previous round that stopped early has already fitted the older
    draws; how many updates it needs to take in a round's new draws scales with their number,
    not with all the data, so waiting ``patience`` epochs over everything made late rounds pay
    mostly for waiting (APT at 10⁴: best epoch 0–12, then 20 epochs over up to 9000 examples).
    A previous round cut off by ``max_epochs`` had not converged: full patience then (scaling
    it anyway, two_moons 2 × 1500 at 40 epochs scored C2ST 0.72 instead of 0.66).
    """
    # a decaying schedule that ran its course ended on small steps: converged by design
    ran_out = previous is not None and previous["epochs"] >= previous.get("max_epochs", config.max_epochs)
    decayed = previous is not None and previous.get("lr_schedule", "constant") != "constant"
    converged = previous is not None and (not ran_out or decayed)
    if config.patience_unit == "epochs" or config.retrain_from_scratch or not converged:
        return config.patience
    num_new, num_all = _new_and_all(round_ids, is_val, r)
    scaled = math.ceil(config.patience * num_new / num_all)
    # at least two epochs: one noisy validation epoch must not end a round
    return min(config.patience, max(_MIN_PATIENCE, scaled))


def _new_and_all(round_ids: np.ndarray, is_val: np.ndarray, r: int) -> tuple[int, int]:
    """Round ``r``'s training examples and all training examples (at least 1)."""
    train = ~is_val
    return int(np.sum(train & (round_ids == r))), max(int(np.sum(train)), 1)


def _later_max_epochs(config: NPEConfig, round_ids: np.ndarray, is_val: np.ndarray, r: int) -> int:
    """Epoch cap of round ``r`` continuing a trained flow (see ``NPEConfig.later_max_epochs``)."""
    if config.later_max_epochs is None:
        return config.max_epochs
    # rounded, not ceil'd: one invalid draw must not add an epoch (15.002 -> 16)
    num_new, num_all = _new_and_all(round_ids, is_val, r)
    capped = round(config.later_max_epochs * num_new / num_all)
    return min(config.max_epochs, max(_MIN_PATIENCE, capped))
