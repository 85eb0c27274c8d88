"""Conditional neural spline flow on a box-bounded parameter space.

Density of θ given x, for ONE θ and ONE x (vmap outside):

    θ ∈ box --theta_map--> z --standardise--> z' --[coupling RQ-spline, LU-linear] × L--> ε ~ N(0, I)

conditioned on ``c = embedding(standardise(x))``. The box map is a `LogitMap` (default: the
density is zero outside the prior box and samples always lie inside it) or an `IdentityMap`
(as sbi: the flow lives on θ, its density is cut at the box and samples are drawn by rejection).
Layers are stacked with ``eqx.filter_vmap`` and applied with ``lax.scan``.
"""

import dataclasses
import math
from typing import Any

import equinox as eqx
import jax
import jax.numpy as jnp
import jax.scipy.linalg as jsl
from jaxtyping import Array, Bool, Float, PRNGKeyArray

from ._config import SplineFlowSettings
from ._embeddings import AbstractEmbedding
from ._estimator import AbstractEstimator, skeleton_parts
from ._prior import BoxPrior
from ._spline import num_spline_params, rq_spline_forward, rq_spline_inverse
from ._standardize import Standardizer
from ._theta_map import AbstractThetaMap, theta_map_from_name

_LOG_2PI = math.log(2.0 * math.pi)


class _ResidualNet(eqx.Module):
    """``in -> hidden``, ``num_blocks`` pre-activation residual blocks, ``hidden -> out`` (the
    context enters with the input, through the first layer)."""

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

    def features(self, h):
        """The last hidden layer (before ``last``)."""
        h = self.first(h)
        for a, b in self.blocks:
            h = h + b(jax.nn.relu(a(jax.nn.relu(h))))
        return h

    def __call__(self, h):
        return self.last(self.features(h))


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

    def __init__(self, mask, context_dim, *, dim: int, architecture: SplineFlowSettings, key):
        self.mask = mask
        self.dim, self.num_bins = dim, architecture.num_bins
        self.bound, self.use_lu = architecture.tail_bound, architecture.use_lu
        out = dim * num_spline_params(self.num_bins)
        hidden, num_blocks = architecture.hidden, architecture.num_blocks
        self.conditioner = _ResidualNet(dim + context_dim, out, hidden, num_blocks, key=key)
        self.lower = jnp.zeros((dim, dim))
        self.upper = jnp.zeros((dim, dim))
        self.diag_raw = jnp.full((dim,), math.log(math.expm1(1.0 - 1e-3)), dtype=self.lower.dtype)
        self.bias = jnp.zeros((dim,))

    def _selection(self):
        """``(P, valid)``: ``P[j]`` is the one-hot row of the j-th transformed coordinate.

        Only the coordinates a coupling layer transforms (at most ``ceil(d/2)``; ``valid`` is
        False on the padding of a layer that transforms fewer) get conditioner outputs and a
        spline: the conditioning half would be computed and thrown away, a third of the APT
        step's time at d = 5. The selection is a product with a one-hot matrix, computed once
        per layer (not per example), so a batch needs no gather or scatter.
        """
        m = _num_transformed(self.dim)
        order = jnp.argsort(self.mask, stable=True)[:m]  # transformed (False) coordinates first
        onehot = jax.nn.one_hot(order, self.dim, dtype=self.lower.dtype)
        return onehot, ~self.mask[order]

    def _spline_params(self, z, context, onehot):
        """Spline parameters of the transformed coordinates, ``(m, 3K-1)``; the conditioner's
        output rows of the conditioning coordinates are never used."""
        h = self.conditioner.features(jnp.concatenate([jnp.where(self.mask, z, 0.0), context]))
        last = self.conditioner.last
        p = num_spline_params(self.num_bins)
        weight = jnp.einsum("md,dph->mph", onehot, last.weight.reshape(self.dim, p, -1))
        bias = onehot @ last.bias.reshape(self.dim, p)
        return weight @ h + bias

    def _couple(self, spline, z, context):
        """Apply ``spline`` to the transformed coordinates of ``z``; ``(out, log|det|)``."""
        onehot, valid = self._selection()
        params = self._spline_params(z, context, onehot)
        zt = onehot @ z
        yt, ld = jax.vmap(spline, in_axes=(0, 0, None))(zt, params, self.bound)
        out = z + (jnp.where(valid, yt - zt, 0.0)) @ onehot
        return out, jnp.sum(jnp.where(valid, ld, 0.0))

    def _lu(self):
        eye = jnp.eye(self.dim, dtype=self.lower.dtype)
        diag = 1e-3 + jax.nn.softplus(self.diag_raw)
        L = jnp.tril(self.lower, -1) + eye
        U = jnp.triu(self.upper, 1) + jnp.diag(diag)
        return L, U, jnp.sum(jnp.log(diag))

    def forward(self, z, context):
        y, logdet = self._couple(rq_spline_forward, z, context)
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
        z, ld = self._couple(rq_spline_inverse, y, context)
        return z, logdet + ld


def _num_transformed(dim: int) -> int:
    """Most coordinates one coupling layer transforms (see `_masks`)."""
    return 1 if dim == 1 else (dim + 1) // 2


def _masks(num_layers: int, dim: int):
    if dim == 1:
        return jnp.zeros((num_layers, 1), bool)
    idx = jnp.arange(dim)
    return jnp.stack([(idx % 2) == (i % 2) for i in range(num_layers)])


class ConditionalFlow(AbstractEstimator):
    """Conditional density estimator ``q(θ | x)`` on the box of ``prior``.

    Args:
        key: PRNG key for initialisation.
        prior: a :class:`BoxPrior`; fixes ``dim`` and the box bijection.
        embedding: maps one standardised x to a context vector of length ``embedding.out_dim``.
        x_shape: shape of ONE observation.
        architecture: the layers and the θ map (`SplineFlowSettings`; its ``x_standardize``,
            how a standardisation is fitted, is not read here: ``x_standardizer`` is the fit).
        theta_standardizer: affine map in the unbounded (logit, or θ) space, shape ``(d,)``.
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
    theta_map: AbstractThetaMap

    def __init__(
        self,
        key: PRNGKeyArray,
        prior: BoxPrior,
        embedding: AbstractEmbedding,
        x_shape: tuple[int, ...],
        architecture: SplineFlowSettings = SplineFlowSettings(),
        *,
        theta_standardizer: Standardizer | None = None,
        x_standardizer: Standardizer | None = None,
    ):
        a = architecture
        self.dim = prior.dim
        self.x_shape = tuple(int(s) for s in x_shape)
        self.num_layers, self.num_bins, self.hidden = int(a.num_layers), int(a.num_bins), int(a.hidden)
        self.num_blocks, self.tail_bound, self.use_lu = int(a.num_blocks), float(a.tail_bound), bool(a.use_lu)
        self.theta_map = a.theta_map
        self.prior = prior
        self.embedding = embedding
        self.theta_standardizer = theta_standardizer or Standardizer.identity(self.dim)
        self.x_standardizer = x_standardizer or Standardizer.identity(self.x_shape[-1] if self.x_shape else 1)
        # the architecture with the casts above (the layers' static fields compare equal)
        cast = dataclasses.replace(
            a,
            num_bins=self.num_bins,
            hidden=self.hidden,
            num_blocks=self.num_blocks,
            tail_bound=self.tail_bound,
            use_lu=self.use_lu,
        )
        keys = jax.random.split(key, self.num_layers)
        masks = _masks(self.num_layers, self.dim)
        self.layers = eqx.filter_vmap(
            lambda k, m: _Layer(m, embedding.out_dim, dim=self.dim, architecture=cast, key=k)
        )(keys, masks)

    # ---- one example -------------------------------------------------------------------------
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
        z, ld_box = self.theta_map.forward(self.prior, safe)
        zs = self.theta_standardizer(z)
        eps, ld_flow = self._to_noise(zs, context)
        base = -0.5 * jnp.sum(eps**2) - 0.5 * self.dim * _LOG_2PI
        lp = base + ld_flow + self.theta_standardizer.log_det() + ld_box
        return jnp.where(inside, lp, -jnp.inf)

    def unmasked_draw(self, eps: Float[Array, " d"], context: Float[Array, " c"]) -> Float[Array, " d"]:
        """The flow's draw for ONE base-noise vector, before any box constraint: always inside
        the box with a `LogitMap`; with an `IdentityMap` possibly outside it (a leak).
        Differentiable in the flow's parameters (reparameterised)."""
        zs, _ = self._from_noise(eps, context)
        return self.theta_map.inverse(self.prior, self.theta_standardizer.inverse(zs))

    def _draw(self, context: Float[Array, " c"], n: int):
        def draw(k):
            eps = jax.random.normal(k, (n, self.dim), dtype=self.prior.low.dtype)
            return jax.vmap(lambda e: self.unmasked_draw(e, context))(eps)

        return draw

    def box_mass(self, key: PRNGKeyArray, context: Float[Array, " c"], n: int) -> Float[Array, ""]:
        """Monte-Carlo share of the flow's mass inside the prior box, from ``n`` draws: 1 with a
        `LogitMap`; with an `IdentityMap`, the acceptance rate of `sample`'s rejection."""
        return self.theta_map.box_mass(self._draw(context, n), self.prior, key)

    def sample_context(self, key: PRNGKeyArray, context: Float[Array, " c"], n: int) -> Float[Array, "n d"]:
        return self.theta_map.sample(self._draw(context, n), self.prior, key, n)

    # ---- reconstruction ------------------------------------------------------------------------
    def structure(self) -> dict[str, Any]:
        return {
            "num_layers": self.num_layers,
            "num_bins": self.num_bins,
            "hidden": self.hidden,
            "num_blocks": self.num_blocks,
            "tail_bound": self.tail_bound,
            "use_lu": self.use_lu,
        }


def flow_from_spec(spec: dict[str, Any]) -> ConditionalFlow:
    """Skeleton :class:`ConditionalFlow` with the structure in ``spec``."""
    prior, embedding, x_shape, xstd = skeleton_parts(spec)
    return ConditionalFlow(
        jax.random.key(0),
        prior,
        embedding,
        x_shape,
        SplineFlowSettings(
            num_layers=spec["num_layers"],
            num_bins=spec["num_bins"],
            hidden=spec["hidden"],
            num_blocks=spec["num_blocks"],
            tail_bound=spec["tail_bound"],
            use_lu=spec["use_lu"],
            theta_map=theta_map_from_name(spec.get("theta_map", "logit")),
        ),
        x_standardizer=xstd,
    )
