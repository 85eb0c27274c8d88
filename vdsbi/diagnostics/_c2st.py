"""Classifier two-sample test (C2ST) as defined in sbibm.

sbibm: z-score both sample sets by the REFERENCE mean/std, train
``sklearn.neural_network.MLPClassifier(activation="relu", hidden_layer_sizes=(10·d, 10·d),
solver="adam", max_iter=10000)`` under 5-fold shuffled cross-validation and report the mean
held-out accuracy (0.5 = indistinguishable, 1.0 = fully separable).

Here the classifier is written in JAX and mimics sklearn's defaults: Glorot-uniform init,
ReLU, logistic output, Adam (lr 1e-3, β = (0.9, 0.999), ε = 1e-8), L2 penalty
``alpha = 1e-4`` scaled as ``0.5·alpha·‖W‖² / batch`` (weights only), minibatches of 200
reshuffled every epoch (the ragged last batch is dropped), and sklearn's stopping rule on the
epoch-mean TRAINING loss (stop after 10 consecutive epochs without an improvement of
``tol = 1e-4``). ``max_epochs`` defaults to 1000 instead of 10000 (the rule fires long before).
The five folds are trained simultaneously with ``vmap`` inside one ``lax.while_loop``.
"""

import dataclasses
import functools

import jax
import jax.numpy as jnp
import numpy as np
import optax
from jaxtyping import Array, Float, PRNGKeyArray


def _init_mlp(key, sizes):
    params = []
    for k, (fi, fo) in zip(jax.random.split(key, len(sizes) - 1), zip(sizes[:-1], sizes[1:])):
        bound = np.sqrt(6.0 / (fi + fo))
        kw, kb = jax.random.split(k)
        params.append(
            (
                jax.random.uniform(kw, (fi, fo), minval=-bound, maxval=bound),
                jax.random.uniform(kb, (fo,), minval=-bound, maxval=bound),
            )
        )
    return params


def _logits(params, x):
    for w, b in params[:-1]:
        x = jax.nn.relu(x @ w + b)
    w, b = params[-1]
    return (x @ w + b)[..., 0]


@dataclasses.dataclass(frozen=True)
class _Classifier:
    """The C2ST classifier and its training (sklearn's MLPClassifier as sbibm sets it up)."""

    hidden: int
    batch_size: int
    max_epochs: int
    patience: int
    lr: float = 1e-3
    alpha: float = 1e-4
    tol: float = 1e-4


@functools.partial(jax.jit, static_argnames=("classifier",))
def _fit_predict(key, x_tr, y_tr, x_te, y_te, *, classifier: _Classifier):
    """Train on one fold (one example = one fold; vmapped outside); return held-out accuracy."""
    hidden, batch_size, lr, alpha, tol = (
        classifier.hidden,
        classifier.batch_size,
        classifier.lr,
        classifier.alpha,
        classifier.tol,
    )
    max_epochs, patience = classifier.max_epochs, classifier.patience
    n, d = x_tr.shape
    nb = n // batch_size
    opt = optax.adam(lr, b1=0.9, b2=0.999, eps=1e-8)
    k_init, key = jax.random.split(key)
    params = _init_mlp(k_init, (d, hidden, hidden, 1))

    def batch_loss(p, xb, yb):
        logit = _logits(p, xb)
        ce = jnp.mean(optax.sigmoid_binary_cross_entropy(logit, yb))
        l2 = sum(jnp.sum(w**2) for w, _ in p)
        return ce + 0.5 * alpha * l2 / xb.shape[0]

    def epoch(p, s, k):
        perm = jax.random.permutation(k, n)[: nb * batch_size].reshape(nb, batch_size)

        def step(c, idx):
            p, s = c
            val, g = jax.value_and_grad(batch_loss)(p, x_tr[idx], y_tr[idx])
            u, s = opt.update(g, s, p)
            return (optax.apply_updates(p, u), s), val

        (p, s), vals = jax.lax.scan(step, (p, s), perm)
        return p, s, jnp.mean(vals)

    def cond(c):
        _, _, _, ep, _, since = c
        return (ep < max_epochs) & (since <= patience)

    def body(c):
        p, s, k, ep, best, since = c
        k, ke = jax.random.split(k)
        p, s, loss = epoch(p, s, ke)
        since = jnp.where(loss > best - tol, since + 1, 0)
        best = jnp.minimum(best, loss)
        return p, s, k, ep + 1, best, since

    init = (params, opt.init(params), key, 0, jnp.inf, 0)
    params, *_ = jax.lax.while_loop(cond, body, init)
    pred = _logits(params, x_te) > 0
    return jnp.mean(pred == (y_te > 0.5))


def c2st(
    key: PRNGKeyArray,
    reference: Float[Array, "n d"],
    samples: Float[Array, "m d"],
    *,
    n_folds: int = 5,
    batch_size: int = 200,
    max_epochs: int = 1000,
    patience: int = 10,
) -> float:
    """Classifier two-sample test accuracy between ``reference`` and ``samples`` (sbibm's C2ST).

    Args:
        key: PRNG key (fold assignment, initialisation, minibatches).
        reference: reference posterior samples; their mean/std standardise both sets.
        samples: samples to assess.
        n_folds: cross-validation folds.

    Returns:
        mean held-out accuracy over the folds, in [0, 1]; 0.5 is a perfect match.
    """
    ref = np.asarray(reference, np.float32)
    smp = np.asarray(samples, np.float32)
    if ref.ndim != 2 or smp.ndim != 2 or ref.shape[1] != smp.shape[1]:
        raise ValueError(f"need two (n, d) arrays with the same d, got {ref.shape} and {smp.shape}")
    mean, std = ref.mean(0), ref.std(0, ddof=1)
    std = np.where(std > 0, std, 1.0)
    data = np.concatenate([(ref - mean) / std, (smp - mean) / std])
    target = np.concatenate([np.zeros(len(ref)), np.ones(len(smp))]).astype(np.float32)
    if not np.all(np.isfinite(data)):
        raise ValueError("c2st: samples contain non-finite values")
    k_perm, k_fit = jax.random.split(key)
    n = (len(data) // n_folds) * n_folds
    perm = np.asarray(jax.random.permutation(k_perm, len(data)))[:n].reshape(n_folds, -1)
    te = perm
    tr = np.stack([np.concatenate([perm[j] for j in range(n_folds) if j != i]) for i in range(n_folds)])
    d = data.shape[1]
    acc = jax.vmap(
        functools.partial(
            _fit_predict,
            classifier=_Classifier(
                hidden=10 * d,
                batch_size=min(batch_size, tr.shape[1]),
                max_epochs=max_epochs,
                patience=patience,
            ),
        )
    )(jax.random.split(k_fit, n_folds), data[tr], target[tr], data[te], target[te])
    return float(jnp.mean(acc))
