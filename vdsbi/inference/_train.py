"""Training loop: one jitted step, AdamW + clipping, validation split, early stopping."""

import dataclasses
import functools
import math
from collections.abc import Callable
from typing import Any, NamedTuple

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import optax
from jaxtyping import PRNGKeyArray

from ..runtime import in_background
from ._config import TrainingSettings, WeightAveraging
from ._estimator import AbstractEstimator
from ._loss import AbstractLoss
from ._sharding import data_mesh, replicate, stack_batches


def make_optimizer(training: TrainingSettings) -> optax.GradientTransformation:
    """``clip_by_global_norm`` then AdamW, from ``training``'s settings.

    With ``cosine_decay`` the learning rate is an entry of the optimiser state
    (``optax.inject_hyperparams``) that `fit` sets every epoch, so a schedule never recompiles
    the step. The same settings give the same object, so repeated fits reuse the compiled step.
    """
    return _optimizer(
        float(training.learning_rate),
        float(training.weight_decay),
        float(training.clip_norm),
        bool(training.cosine_decay),
    )


@functools.lru_cache(maxsize=32)
def _optimizer(learning_rate: float, weight_decay: float, clip_norm: float, scheduled: bool):
    adamw = optax.inject_hyperparams(optax.adamw) if scheduled else optax.adamw
    return optax.chain(
        optax.clip_by_global_norm(clip_norm),
        adamw(learning_rate, weight_decay=weight_decay),
    )


def cosine_learning_rate(learning_rate: float, epoch: int, max_epochs: int) -> float:
    """The learning rate of ``epoch`` under cosine decay: ``lr·(1 + cos(π·epoch/max_epochs))/2``."""
    return learning_rate * 0.5 * (1.0 + math.cos(math.pi * epoch / max_epochs))


def _set_learning_rate(opt_state, value: float):
    """``opt_state`` with its injected ``learning_rate`` set to ``value`` (placement kept)."""
    old = optax.tree_utils.tree_get(opt_state, "learning_rate")
    if old is None:
        raise ValueError(
            "a learning-rate schedule needs an optimiser whose learning rate is an injected "
            "hyperparameter (optax.inject_hyperparams), as make_optimizer builds it"
        )
    new = jax.device_put(jnp.asarray(value, old.dtype), old.sharding)
    return optax.tree_utils.tree_set(opt_state, learning_rate=new)


def trainable_filter(flow: AbstractEstimator):
    """Boolean pytree: True on the trained weights, False on the frozen prior and standardisations.

    Any `AbstractEstimator`: every inexact array but its prior's and standardisers' is trained.
    """
    spec = jax.tree.map(eqx.is_inexact_array, flow)
    frozen = lambda f: (f.prior, f.theta_standardizer, f.x_standardizer)  # noqa: E731
    return eqx.tree_at(frozen, spec, replace=jax.tree.map(lambda _: False, frozen(spec)))


def _update(params, static, opt_state, batch, key, loss: AbstractLoss, optimizer):
    def f(p):
        return loss(eqx.combine(p, static), *batch, key)

    value, grads = jax.value_and_grad(f)(params)
    updates, opt_state = optimizer.update(grads, opt_state, params)
    return eqx.apply_updates(params, updates), opt_state, value


@eqx.filter_jit
def train_step(flow: AbstractEstimator, opt_state, batch, key: PRNGKeyArray, loss: AbstractLoss, optimizer):
    """One optimisation step on ``batch = (theta, x, prior_mask)``; returns ``(flow, opt_state, loss)``."""
    params, static = eqx.partition(flow, trainable_filter(flow))
    params, opt_state, value = _update(params, static, opt_state, batch, key, loss, optimizer)
    return eqx.combine(params, static), opt_state, value


@eqx.filter_jit
def train_steps(
    flow: AbstractEstimator, opt_state, batches, keys, loss: AbstractLoss, optimizer, live=None, average=None
):
    """Consecutive steps in one ``lax.scan``: ``batches`` leaves are ``(num_steps, batch, ...)``.

    Python dispatch of a small flow's step costs about as much as its arithmetic, so blocks of
    steps run as one compiled loop. ``live`` (``(num_steps,)`` bool, default all True) marks
    padding steps that leave the state untouched, so every block of an epoch has one length and
    the loop is compiled once however the data grow. ``average``: optionally ``(avg_flow, decay)``,
    an exponential moving average of the weights updated after every live step as
    ``avg <- decay·avg + (1 - decay)·weights`` (``decay`` a traced scalar: no recompilation).
    Returns ``(flow, opt_state, mean loss)`` (the mean over live steps), and the updated average
    flow last when ``average`` is given.
    """
    params, static = eqx.partition(flow, trainable_filter(flow))
    live = jnp.ones(keys.shape[0], bool) if live is None else live
    dtype = jax.tree.leaves(params)[0].dtype
    if average is None:
        avg, decay = None, None
    else:
        avg, decay = eqx.filter(average[0], trainable_filter(average[0])), average[1].astype(dtype)

    def body(carry, inp):
        batch, key, on = inp

        def step(c):
            p, s, a = c
            p, s, value = _update(p, static, s, batch, key, loss, optimizer)
            a = None if a is None else jax.tree.map(lambda u, v: decay * u + (1.0 - decay) * v, a, p)
            return (p, s, a), value

        def skip(c):
            return c, jnp.zeros((), dtype)

        return jax.lax.cond(on, step, skip, carry)

    (params, opt_state, avg), values = jax.lax.scan(body, (params, opt_state, avg), (batches, keys, live))
    mean = jnp.sum(jnp.where(live, values, 0.0)) / jnp.maximum(jnp.sum(live), 1)
    out = (eqx.combine(params, static), opt_state, mean)
    return out if avg is None else (*out, eqx.combine(avg, static))


@eqx.filter_jit
def eval_steps(flow: AbstractEstimator, batches, key: PRNGKeyArray, loss: AbstractLoss, live=None):
    """Mean loss over ``(num_batches, batch, ...)`` validation batches (the ``live`` ones), in one
    compiled loop; padding batches are skipped, not evaluated (at 10³ simulations one live batch
    in a block of 32 cost as much as the epoch's training)."""
    live = jnp.ones(jax.tree.leaves(batches)[0].shape[0], bool) if live is None else live

    def value(b):
        return loss(flow, *b, key)

    out = jax.eval_shape(value, jax.tree.map(lambda a: a[0], batches))

    def one(inp):
        b, on = inp
        return jax.lax.cond(on, value, lambda _: jnp.zeros(out.shape, out.dtype), b)

    values = jax.lax.map(one, (batches, live))
    return jnp.sum(jnp.where(live, values, 0.0)) / jnp.maximum(jnp.sum(live), 1)


def init_opt_state(flow: AbstractEstimator, optimizer):
    return optimizer.init(eqx.filter(flow, trainable_filter(flow)))


def _round_down(n: int, m: int) -> int:
    return (n // m) * m


def _batch_size(requested: int, available: int, ndev: int) -> int:
    """``requested`` if enough data, else the largest power of two <= ``available`` (so the
    few distinct shapes across growing rounds are compiled once each), a multiple of ``ndev``."""
    if available >= requested:
        return _round_down(requested, ndev)
    return _round_down(1 << (max(available, 1).bit_length() - 1), ndev)


def _blocks(idx: np.ndarray, size: int) -> list[tuple[np.ndarray, np.ndarray]]:
    """Rows of ``idx`` in blocks of exactly ``size`` rows, the last padded by repeating its first
    row; with each block a ``live`` mask (False on padding). One length: one compiled loop."""
    out = []
    for i in range(0, len(idx), size):
        block = idx[i : i + size]
        live = np.arange(size) < len(block)
        pad = np.repeat(block[:1], size - len(block), axis=0)
        out.append((np.concatenate([block, pad]), live))
    return out


def _batch_sizes(num_train: int, num_val: int, batch_size: int, ndev: int) -> tuple[int, int]:
    """Training and validation batch sizes (see `_batch_size`), or a clear error if too few data."""
    bsz = _batch_size(batch_size, num_train, ndev)
    vsz = _batch_size(batch_size, num_val, ndev)
    if bsz < 2 or vsz < 1:
        raise ValueError(
            f"Too few simulations to train: {num_train} training / {num_val} validation examples "
            f"for {ndev} device(s)."
        )
    return bsz, vsz


def _validation_blocks(data, va: np.ndarray, vsz: int, block: int, mesh) -> list:
    """The validation set in full batches of ``vsz``, grouped in padded blocks of ``block``
    batches: ``(stacked batches, live mask, number of live batches)`` per block."""
    nvb = va.size // vsz
    val_idx = va[: nvb * vsz].reshape(nvb, vsz)
    return [
        (stack_batches(tuple(a[idx] for a in data), mesh), live, live.sum())
        for idx, live in _blocks(val_idx, block)
    ]


class _Epochs(NamedTuple):
    """What stays fixed over `fit`'s epochs: the data and its training rows ``tr``, the batch
    size, the steps per compiled block, the mesh, the loss, the optimiser and the EMA decay
    (None: no averaging)."""

    data: tuple
    tr: np.ndarray
    bsz: int
    block: int
    mesh: Any
    loss: AbstractLoss
    optimizer: optax.GradientTransformation
    decay: Any


def _train_epoch(state, keys, epochs: _Epochs):
    """One pass over a random permutation of the training rows (``keys = (k_perm, k_steps)``),
    in compiled blocks. ``state = (flow, opt_state, avg_flow or None)``; returns the new state
    and the mean training loss."""
    data, tr, bsz, block, mesh, loss, optimizer, decay = epochs
    flow, opt_state, avg = state
    k_perm, k_steps = keys
    nb = tr.size // bsz
    perm = tr[np.asarray(jax.random.permutation(k_perm, tr.size))][: nb * bsz].reshape(nb, bsz)
    step_keys = jax.random.split(k_steps, nb)
    total = jnp.zeros(())
    for j, (idx, live) in enumerate(_blocks(perm, block)):
        batches = stack_batches(tuple(a[idx] for a in data), mesh)
        keys = step_keys[np.minimum(np.arange(j * block, (j + 1) * block), nb - 1)]
        if avg is None:
            flow, opt_state, mean = train_steps(flow, opt_state, batches, keys, loss, optimizer, live)
        else:
            flow, opt_state, mean, avg = train_steps(
                flow, opt_state, batches, keys, loss, optimizer, live, (avg, decay)
            )
        total = total + mean * live.sum()
    return (flow, opt_state, avg), float(total) / nb


def _train_state(flow, optimizer, mesh, averaging: WeightAveraging | None, steps_per_epoch: int):
    """``(flow, opt_state, avg_flow or None)`` replicated over ``mesh``, and the per-step EMA
    decay of ``averaging`` (None when it is off)."""
    flow = replicate(flow, mesh)
    opt_state = replicate(init_opt_state(flow, optimizer), mesh)
    if averaging is None:
        return (flow, opt_state, None), None
    decay = 1.0 - 1.0 / max(averaging.epochs * steps_per_epoch, 1.0)
    return (flow, opt_state, flow), replicate(jnp.asarray(decay), mesh)


def _validation_loss(flow, val_batches: list, key: PRNGKeyArray, loss: AbstractLoss) -> float:
    """Mean loss over the blocks of `_validation_blocks` (weighted by their live batches)."""
    total = sum(float(eval_steps(flow, vb, key, loss, lv)) * n for vb, lv, n in val_batches)
    return total / sum(int(n) for _, _, n in val_batches)


def _scheduled(state, training: TrainingSettings, epoch: int):
    """``state`` with the optimiser's learning rate set for ``epoch`` (as is without a schedule)."""
    if not training.cosine_decay:
        return state
    lr = cosine_learning_rate(training.learning_rate, epoch, training.max_epochs)
    return (state[0], _set_learning_rate(state[1], lr), state[2])


class _EarlyStopping:
    """The best-validation flow so far, the loss histories, and the epochs since the last best."""

    def __init__(self, flow: AbstractEstimator, patience: int):
        self.best, self.flow, self.epoch, self.since = np.inf, flow, -1, 0
        self.patience = patience
        self.train_losses, self.val_losses = [], []

    def update(self, epoch: int, flow: AbstractEstimator, train_loss: float, val_loss: float) -> bool:
        """Record one epoch; True once ``patience`` epochs have passed without a better one."""
        self.train_losses.append(train_loss)
        self.val_losses.append(val_loss)
        if val_loss < self.best:
            self.best, self.flow, self.epoch, self.since = val_loss, flow, epoch, 0
        else:
            self.since += 1
        return self.since >= self.patience

    def info(self, batch_size: int) -> dict:
        return {
            "epochs": len(self.train_losses),
            "best_epoch": self.epoch,
            "best_val_loss": float(self.best),
            "train_losses": self.train_losses,
            "val_losses": self.val_losses,
            "batch_size": batch_size,
        }


@dataclasses.dataclass(frozen=True)
class Examples:
    """The simulations `fit` trains on, host arrays with one row per simulation: ``theta``
    (N, d), ``x`` (N, ...), ``prior_mask`` (N,) True where θ was drawn from the prior, and
    ``is_val`` (N,) True on the rows held out for validation."""

    theta: np.ndarray
    x: np.ndarray
    prior_mask: np.ndarray
    is_val: np.ndarray


#: Training steps per compiled block: enough to amortise Python's dispatch of a small flow's
#: step, few enough that an epoch's padding steps cost little.
STEPS_PER_CALL = 32


def fit(
    key: PRNGKeyArray,
    flow: AbstractEstimator,
    examples: Examples,
    loss: AbstractLoss,
    training: TrainingSettings,
    optimizer: optax.GradientTransformation | None = None,
    *,
    on_epoch_end: Callable[[int, float, float], None] | None = None,
    mesh=None,
):
    """Train ``flow`` on ``examples``; return the best-validation flow and an info dict.

    ``training`` gives the batch size, epochs, patience, learning-rate schedule and weight
    averaging; ``optimizer`` defaults to ``make_optimizer(training)`` (``cosine_decay`` needs
    its learning rate injected, ``optax.inject_hyperparams``).

    Batches have a fixed size (ragged last batch dropped), a multiple of the device count; the
    batch axis is sharded over ``mesh`` and the model is replicated. Steps run in compiled
    blocks of exactly `STEPS_PER_CALL` (a ``lax.scan``; the last block of an epoch padded with
    masked no-op steps), so per-step Python dispatch is amortised and the loop is compiled once
    per loss and batch size, not once per data size. ``cosine_decay`` (see
    `cosine_learning_rate`) sets the learning rate per epoch over ``max_epochs``.
    With ``averaging`` (`WeightAveraging`), validation, early stopping and the returned flow
    use an exponential moving average of the weights, started from ``flow``.
    ``on_epoch_end(epoch, train_loss, val_loss)`` is called after every epoch.
    """
    optimizer = make_optimizer(training) if optimizer is None else optimizer
    mesh = data_mesh() if mesh is None else mesh
    tr, va = np.flatnonzero(~examples.is_val), np.flatnonzero(examples.is_val)
    bsz, vsz = _batch_sizes(tr.size, va.size, training.batch_size, mesh.devices.size)
    state, decay = _train_state(flow, optimizer, mesh, training.averaging, tr.size // bsz)
    key, val_key = jax.random.split(key)
    data = (examples.theta, examples.x, examples.prior_mask)
    val_batches = _validation_blocks(data, va, vsz, STEPS_PER_CALL, mesh)
    # The validation loop compiles on a second thread while the first training block
    # compiles (XLA compiles without holding the GIL); its value, the initial loss, is unused.
    warm = in_background(eval_steps, state[0], val_batches[0][0], val_key, loss, val_batches[0][1])
    epochs = _Epochs(data, tr, bsz, STEPS_PER_CALL, mesh, loss, optimizer, decay)
    stopping = _EarlyStopping(state[0], training.patience)
    for epoch in range(training.max_epochs):
        key, k_perm, k_steps = jax.random.split(key, 3)
        state = _scheduled(state, training, epoch)
        state, train_loss = _train_epoch(state, (k_perm, k_steps), epochs)
        flow = state[0] if state[2] is None else state[2]
        warm.result()  # compiled (or raised) before the loop calls it: never compiled twice
        val_loss = _validation_loss(flow, val_batches, val_key, loss)
        stop = stopping.update(epoch, flow, train_loss, val_loss)
        if on_epoch_end is not None:
            on_epoch_end(epoch, train_loss, val_loss)
        if stop:
            break
    return stopping.flow, stopping.info(bsz)
