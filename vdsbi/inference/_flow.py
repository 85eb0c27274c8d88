"""Conditional neural spline flow on a box-bounded parameter space.

Density of θ given x, for ONE θ and ONE x (vmap outside):

    θ ∈ box --logit--> z --standardise--> z' --[coupling RQ-spline, LU-linear] × L--> ε ~ N(0, I)

conditioned on ``c = embedding(standardise(x))``. The box map is a fixed bijection,
so the density is zero outside the prior box and samples always lie inside it.
Layers are stacked with ``eqx.filter_vmap`` and applied with ``lax.scan``.
"""

import math
from typing import Any

import equinox as eqx
import jax
import jax.numpy as jnp
import jax.scipy.linalg as jsl
from jaxtyping import Array, Bool, Float, PRNGKeyArray

from ._embeddings import AbstractEmbedding, embedding_from_spec
from ._prior import BoxPrior
from ._spline import num_spline_params, rq_spline_forward, rq_spline_inverse
from ._standardize import Standardizer

_LOG_2PI = math.log(2.0 * math.pi)


class _ResidualNet(eqx.Module):
    """``in -> hidden``, ``num_blocks`` pre-activation residual blocks, ``hidden -> out``."""

    first: eqx.nn.Linear
    blocks: tuple[tuple[eqx.nn.Linear, eqx.nn.Linear], ...]
    last: eqx.nn.Linear

    def __init__(self, in_dim: int, out_dim: int, hidden: int, num_blocks: int, *, key: PRNGKeyArray):
        k0, k1, *kb = jax.random.split(key, 2 + 2 * num_blocks)
        self.first = eqx.nn.Linear(in_dim, hidden, key=k0)
        self.blocks = tuple(
            (eqx.nn.Linear(hidden, hidden, key=kb[2 * i]), eqx.nn.Linear(hidden, hidden, key=kb[2 * i + 1]))
            for i in range(num_blocks)
        )
        last = eqx.nn.Linear(hidden, out_dim, key=k1)
        # Near-zero output: every spline starts close to the identity.
        self.last = eqx.tree_at(lambda m: (m.weight, m.bias), last, (last.weight * 1e-2, last.bias * 0.0))

    def __call__(self, h):
        h = self.first(h)
        for a, b in self.blocks:
            h = h + b(jax.nn.relu(a(jax.nn.relu(h))))
        return self.last(h)


class _Layer(eqx.Module):
    """One flow layer (data→noise direction): RQ-spline coupling, then optional LU-linear."""

    mask: Bool[Array, " d"]  # True = conditioning (identity) coordinates
    conditioner: _ResidualNet
    lower: Float[Array, "d d"]
    upper: Float[Array, "d d"]
    diag_raw: Float[Array, " d"]
    bias: Float[Array, " d"]
    dim: int = eqx.field(static=True)
    num_bins: int = eqx.field(static=True)
    bound: float = eqx.field(static=True)
    use_lu: bool = eqx.field(static=True)

    def __init__(self, mask, context_dim, *, dim, num_bins, hidden, num_blocks, bound, use_lu, key):
        self.mask = mask
        self.dim, self.num_bins, self.bound, self.use_lu = dim, num_bins, bound, use_lu
        out = dim * num_spline_params(num_bins)
        self.conditioner = _ResidualNet(dim + context_dim, out, hidden, num_blocks, key=key)
        self.lower = jnp.zeros((dim, dim))
        self.upper = jnp.zeros((dim, dim))
        self.diag_raw = jnp.full((dim,), math.log(math.expm1(1.0 - 1e-3)), dtype=self.lower.dtype)
        self.bias = jnp.zeros((dim,))

    def _spline_params(self, z, context):
        h = jnp.concatenate([jnp.where(self.mask, z, 0.0), context])
        return self.conditioner(h).reshape(self.dim, num_spline_params(self.num_bins))

    def _lu(self):
        eye = jnp.eye(self.dim, dtype=self.lower.dtype)
        diag = 1e-3 + jax.nn.softplus(self.diag_raw)
        L = jnp.tril(self.lower, -1) + eye
        U = jnp.triu(self.upper, 1) + jnp.diag(diag)
        return L, U, jnp.sum(jnp.log(diag))

    def forward(self, z, context):
        params = self._spline_params(z, context)
        y, ld = jax.vmap(rq_spline_forward, in_axes=(0, 0, None))(z, params, self.bound)
        y = jnp.where(self.mask, z, y)
        logdet = jnp.sum(jnp.where(self.mask, 0.0, ld))
        if self.use_lu:
            L, U, ld_lu = self._lu()
            y = L @ (U @ y) + self.bias
            logdet = logdet + ld_lu
        return y, logdet

    def inverse(self, y, context):
        logdet = jnp.zeros((), y.dtype)
        if self.use_lu:
            L, U, ld_lu = self._lu()
            v = jsl.solve_triangular(L, y - self.bias, lower=True, unit_diagonal=True)
            y = jsl.solve_triangular(U, v, lower=False)
            logdet = -ld_lu
        # The conditioning coordinates are unchanged by the coupling, so params are recoverable.
        params = self._spline_params(y, context)
        z, ld = jax.vmap(rq_spline_inverse, in_axes=(0, 0, None))(y, params, self.bound)
        z = jnp.where(self.mask, y, z)
        return z, logdet + jnp.sum(jnp.where(self.mask, 0.0, ld))


def _masks(num_layers: int, dim: int):
    if dim == 1:
        return jnp.zeros((num_layers, 1), bool)
    idx = jnp.arange(dim)
    return jnp.stack([(idx % 2) == (i % 2) for i in range(num_layers)])


class ConditionalFlow(eqx.Module):
    """Conditional density estimator ``q(θ | x)`` on the box of ``prior``.

    Args:
        key: PRNG key for initialisation.
        prior: a :class:`BoxPrior`; fixes ``dim`` and the box bijection.
        embedding: maps one standardised x to a context vector of length ``embedding.out_dim``.
        x_shape: shape of ONE observation.
        num_layers, num_bins, hidden, num_blocks, tail_bound, use_lu: architecture.
        theta_standardizer: affine map in the unbounded (logit) space, shape ``(d,)``.
        x_standardizer: applied to x before the embedding.
    """

    layers: _Layer  # stacked along a leading layer axis
    embedding: AbstractEmbedding
    prior: BoxPrior
    theta_standardizer: Standardizer
    x_standardizer: Standardizer
    dim: int = eqx.field(static=True)
    x_shape: tuple[int, ...] = eqx.field(static=True)
    num_layers: int = eqx.field(static=True)
    num_bins: int = eqx.field(static=True)
    hidden: int = eqx.field(static=True)
    num_blocks: int = eqx.field(static=True)
    tail_bound: float = eqx.field(static=True)
    use_lu: bool = eqx.field(static=True)

    def __init__(
        self,
        key: PRNGKeyArray,
        prior: BoxPrior,
        embedding: AbstractEmbedding,
        x_shape: tuple[int, ...],
        *,
        num_layers: int = 5,
        num_bins: int = 10,
        hidden: int = 50,
        num_blocks: int = 2,
        tail_bound: float = 3.0,
        use_lu: bool = True,
        theta_standardizer: Standardizer | None = None,
        x_standardizer: Standardizer | None = None,
    ):
        self.dim = prior.dim
        self.x_shape = tuple(int(s) for s in x_shape)
        self.num_layers, self.num_bins, self.hidden = int(num_layers), int(num_bins), int(hidden)
        self.num_blocks, self.tail_bound, self.use_lu = int(num_blocks), float(tail_bound), bool(use_lu)
        self.prior = prior
        self.embedding = embedding
        self.theta_standardizer = theta_standardizer or Standardizer.identity(self.dim)
        self.x_standardizer = x_standardizer or Standardizer.identity(self.x_shape[-1] if self.x_shape else 1)
        kw = dict(
            dim=self.dim,
            num_bins=self.num_bins,
            hidden=self.hidden,
            num_blocks=self.num_blocks,
            bound=self.tail_bound,
            use_lu=self.use_lu,
        )
        keys = jax.random.split(key, self.num_layers)
        masks = _masks(self.num_layers, self.dim)
        self.layers = eqx.filter_vmap(lambda k, m: _Layer(m, embedding.out_dim, key=k, **kw))(keys, masks)

    # ---- one example -------------------------------------------------------------------------
    def context(self, x: Float[Array, "..."]) -> Float[Array, " c"]:
        """Embedding of ONE observation."""
        return self.embedding(self.x_standardizer(x))

    def _to_noise(self, zs, context):
        params, static = eqx.partition(self.layers, eqx.is_array)

        def body(carry, p):
            z, ld = carry
            z, l = eqx.combine(p, static).forward(z, context)
            return (z, ld + l), None

        (eps, logdet), _ = jax.lax.scan(body, (zs, jnp.zeros((), zs.dtype)), params)
        return eps, logdet

    def _from_noise(self, eps, context):
        params, static = eqx.partition(self.layers, eqx.is_array)

        def body(carry, p):
            y, ld = carry
            y, l = eqx.combine(p, static).inverse(y, context)
            return (y, ld + l), None

        (zs, logdet), _ = jax.lax.scan(body, (eps, jnp.zeros((), eps.dtype)), params, reverse=True)
        return zs, logdet

    def log_prob_context(self, theta: Float[Array, " d"], context: Float[Array, " c"]) -> Float[Array, ""]:
        """``log q(θ | x)`` for ONE θ given a precomputed context; ``-inf`` outside the box."""
        inside = jnp.all((theta >= self.prior.low) & (theta <= self.prior.high))
        safe = jnp.where(inside, theta, 0.5 * (self.prior.low + self.prior.high))
        z, ld_box = self.prior.to_unbounded(safe)
        zs = self.theta_standardizer(z)
        eps, ld_flow = self._to_noise(zs, context)
        base = -0.5 * jnp.sum(eps**2) - 0.5 * self.dim * _LOG_2PI
        lp = base + ld_flow + self.theta_standardizer.log_det() + ld_box
        return jnp.where(inside, lp, -jnp.inf)

    def log_prob(self, theta: Float[Array, " d"], x: Float[Array, "..."]) -> Float[Array, ""]:
        """``log q(θ | x)`` for ONE θ and ONE x."""
        return self.log_prob_context(theta, self.context(x))

    def sample_context(self, key: PRNGKeyArray, context: Float[Array, " c"], n: int) -> Float[Array, "n d"]:
        eps = jax.random.normal(key, (n, self.dim), dtype=self.prior.low.dtype)

        def one(e):
            zs, _ = self._from_noise(e, context)
            return self.prior.from_unbounded(self.theta_standardizer.inverse(zs))

        return jax.vmap(one)(eps)

    def sample(self, key: PRNGKeyArray, x: Float[Array, "..."], n: int) -> Float[Array, "n d"]:
        """``n`` draws of θ from ``q(θ | x)`` for ONE x; always strictly inside the prior box."""
        return self.sample_context(key, self.context(x), n)

    # ---- reconstruction ------------------------------------------------------------------------
    def spec(self) -> dict[str, Any]:
        """JSON-serialisable description from which :func:`flow_from_spec` rebuilds the structure."""
        return {
            "low": [float(v) for v in self.prior.low],
            "high": [float(v) for v in self.prior.high],
            "names": None if self.prior.names is None else list(self.prior.names),
            "x_shape": list(self.x_shape),
            "x_std_shape": list(self.x_standardizer.mean.shape),
            "num_layers": self.num_layers,
            "num_bins": self.num_bins,
            "hidden": self.hidden,
            "num_blocks": self.num_blocks,
            "tail_bound": self.tail_bound,
            "use_lu": self.use_lu,
            "embedding": [type(self.embedding).__name__, self.embedding.spec()],
        }


def flow_from_spec(spec: dict[str, Any]) -> ConditionalFlow:
    """Skeleton :class:`ConditionalFlow` with the structure described by ``spec``."""
    prior = BoxPrior(jnp.asarray(spec["low"]), jnp.asarray(spec["high"]), spec["names"])
    name, espec = spec["embedding"]
    xs = tuple(spec["x_std_shape"])
    xstd = Standardizer(mean=jnp.zeros(xs), std=jnp.ones(xs))
    return ConditionalFlow(
        jax.random.key(0),
        prior,
        embedding_from_spec(name, espec),
        tuple(spec["x_shape"]),
        num_layers=spec["num_layers"],
        num_bins=spec["num_bins"],
        hidden=spec["hidden"],
        num_blocks=spec["num_blocks"],
        tail_bound=spec["tail_bound"],
        use_lu=spec["use_lu"],
        x_standardizer=xstd,
    )


def trainable_filter(flow: ConditionalFlow):
    """Boolean pytree: True on the trained weights (layers and embedding), False on frozen stats."""
    spec = jax.tree.map(lambda _: False, flow)
    return eqx.tree_at(
        lambda f: (f.layers, f.embedding),
        spec,
        replace=(
            jax.tree.map(eqx.is_inexact_array, flow.layers),
            jax.tree.map(eqx.is_inexact_array, flow.embedding),
        ),
    )
