"""Flow-matching posterior estimation (FMPE; Dax et al. 2023) on a box-bounded parameter space.

A conditional vector field ``v(t, z, c)`` transports noise ``z_0 ~ N(0, I)`` at ``t = 0`` to the
posterior at ``t = 1`` along ``dz/dt = v``. ``z`` is θ mapped exactly as the spline flow maps it
(`ConditionalFlow`): by its `LogitMap` or `IdentityMap`, then standardised. Training
regresses ``v`` on the optimal-transport (Gaussian) conditional path of Lipman et al. (2023),

    z_t = (1 - (1 - σ_min) t) z_0 + t z_1,    target  u = z_1 - (1 - σ_min) z_0,

with ``z_1`` a training θ, ``c = embedding(standardise(x))`` and training times of density
``2t`` on [0, 1] (more of them near the data end, where the field is hardest): no ODE is
solved in training.
Sampling integrates the ODE from noise; ``log q`` integrates it backwards with the exact
divergence (instantaneous change of variables; ``jax.jacfwd``, d forward-mode passes, meant for
small d). Both use diffrax's Tsit5 with ``ode_steps`` fixed steps.
"""

import math
from typing import Any

import diffrax
import equinox as eqx
import jax
import jax.numpy as jnp
from jaxtyping import Array, Float, PRNGKeyArray

from ._config import FlowMatchingSettings
from ._embeddings import AbstractEmbedding
from ._estimator import AbstractEstimator, skeleton_parts
from ._loss import AbstractLoss
from ._prior import BoxPrior
from ._standardize import Standardizer
from ._theta_map import AbstractThetaMap, theta_map_from_name

_LOG_2PI = math.log(2.0 * math.pi)


def _time_features(t: Float[Array, ""], num_freqs: int) -> Float[Array, " f"]:
    """``[t, cos(π 2^k t), sin(π 2^k t)]`` for ``k < num_freqs``: length ``1 + 2 num_freqs``."""
    w = math.pi * 2.0 ** jnp.arange(num_freqs, dtype=t.dtype)
    return jnp.concatenate([t[None], jnp.cos(w * t), jnp.sin(w * t)])


class VectorField(eqx.Module):
    """Residual MLP ``v(t, z, c)`` for ONE point: ``[z, τ(t), c] -> hidden``, ``num_blocks``
    SiLU residual blocks each gated by ``sigmoid(W [τ(t), c] + b)``, ``hidden -> d``.

    SiLU rather than ReLU keeps ``v`` smooth in ``z``, which the ODE solver's order and the
    divergence in ``log_prob`` rely on. Time and context gate every block (as the GLU
    conditioning of Dax et al.) so the field can change with ``t`` at every depth.
    """

    first: eqx.nn.Linear
    blocks: tuple[tuple[eqx.nn.Linear, eqx.nn.Linear], ...]
    gates: tuple[eqx.nn.Linear, ...]
    last: eqx.nn.Linear
    dim: int = eqx.field(static=True)
    context_dim: int = eqx.field(static=True)
    num_freqs: int = eqx.field(static=True)

    def __init__(self, key, dim: int, context_dim: int, hidden: int, num_blocks: int, num_freqs: int):
        self.dim, self.context_dim, self.num_freqs = int(dim), int(context_dim), int(num_freqs)
        cond = context_dim + 1 + 2 * num_freqs
        k0, k1, kb, kg = jax.random.split(key, 4)
        kb = jax.random.split(kb, 2 * num_blocks)
        kg = jax.random.split(kg, num_blocks)
        self.first = eqx.nn.Linear(dim + cond, hidden, key=k0)
        self.blocks = tuple(
            (eqx.nn.Linear(hidden, hidden, key=kb[2 * i]), eqx.nn.Linear(hidden, hidden, key=kb[2 * i + 1]))
            for i in range(num_blocks)
        )
        self.gates = tuple(eqx.nn.Linear(cond, hidden, key=kg[i]) for i in range(num_blocks))
        self.last = eqx.nn.Linear(hidden, dim, key=k1)

    def __call__(
        self, t: Float[Array, ""], z: Float[Array, " d"], context: Float[Array, " c"]
    ) -> Float[Array, " d"]:
        cond = jnp.concatenate([_time_features(t, self.num_freqs), context])
        h = self.first(jnp.concatenate([z, cond]))
        for (a, b), g in zip(self.blocks, self.gates):
            r = b(jax.nn.silu(a(jax.nn.silu(h))))
            h = h + r * jax.nn.sigmoid(g(cond))
        return self.last(jax.nn.silu(h))


def _odeint(f, y0, t0: float, t1: float, steps: int):
    """``y(t1)`` of ``dy/dt = f(t, y)`` from ``y(t0) = y0``: Tsit5 at ``steps`` equal steps."""
    ts = jnp.linspace(t0, t1, steps + 1, dtype=jax.tree.leaves(y0)[0].dtype)
    sol = diffrax.diffeqsolve(
        diffrax.ODETerm(lambda t, y, _: f(t, y)),
        diffrax.Tsit5(),
        t0,
        t1,
        None,
        y0,
        stepsize_controller=diffrax.StepTo(ts=ts),
        saveat=diffrax.SaveAt(t1=True),
        max_steps=steps,
    )
    return jax.tree.map(lambda a: a[0], sol.ys)


class FlowMatchingEstimator(AbstractEstimator):
    """Conditional density ``q(θ | x)`` on the box of ``prior``, as a flow-matching ODE.

    An `AbstractEstimator`, as `ConditionalFlow` is.

    Args:
        key: PRNG key for initialisation.
        prior: a :class:`BoxPrior`; fixes ``dim`` and the box map.
        embedding: maps one standardised x to a context vector of length ``embedding.out_dim``.
        x_shape: shape of ONE observation.
        architecture: the vector field, the ODE's steps, the path's width and the θ map
            (`FlowMatchingSettings`; its ``x_standardize`` is not read here: ``x_standardizer`` is
            the fit).
        theta_standardizer: affine map in the unbounded (logit, or θ) space, shape ``(d,)``.
        x_standardizer: applied to x before the embedding.
    """

    vector_field: VectorField
    embedding: AbstractEmbedding
    prior: BoxPrior
    theta_standardizer: Standardizer
    x_standardizer: Standardizer
    dim: int = eqx.field(static=True)
    x_shape: tuple[int, ...] = eqx.field(static=True)
    hidden: int = eqx.field(static=True)
    num_blocks: int = eqx.field(static=True)
    num_freqs: int = eqx.field(static=True)
    ode_steps: int = eqx.field(static=True)
    sigma_min: float = eqx.field(static=True)
    theta_map: AbstractThetaMap

    def __init__(
        self,
        key: PRNGKeyArray,
        prior: BoxPrior,
        embedding: AbstractEmbedding,
        x_shape: tuple[int, ...],
        architecture: FlowMatchingSettings = FlowMatchingSettings(),
        *,
        theta_standardizer: Standardizer | None = None,
        x_standardizer: Standardizer | None = None,
    ):
        a = architecture
        self.dim = prior.dim
        self.x_shape = tuple(int(s) for s in x_shape)
        self.hidden, self.num_blocks, self.num_freqs = int(a.hidden), int(a.num_blocks), int(a.num_freqs)
        self.ode_steps, self.sigma_min = int(a.ode_steps), float(a.sigma_min)
        self.theta_map = a.theta_map
        self.prior = prior
        self.embedding = embedding
        self.theta_standardizer = theta_standardizer or Standardizer.identity(self.dim)
        self.x_standardizer = x_standardizer or Standardizer.identity(self.x_shape[-1] if self.x_shape else 1)
        self.vector_field = VectorField(
            key, self.dim, embedding.out_dim, self.hidden, self.num_blocks, self.num_freqs
        )

    def __check_init__(self):
        if not isinstance(self.theta_map, AbstractThetaMap):
            raise TypeError(f"theta_map must be a LogitMap or an IdentityMap, got {self.theta_map!r}")
        if self.ode_steps < 1 or not 0.0 <= self.sigma_min < 1.0:
            raise ValueError("need ode_steps >= 1 and 0 <= sigma_min < 1")

    # ---- one example -------------------------------------------------------------------------
    def _to_z(self, theta):
        """θ (inside the box) to the standardised space the ODE lives in, and ``log|dz/dθ|``."""
        u, ld = self.theta_map.forward(self.prior, theta)
        return self.theta_standardizer(u), ld + self.theta_standardizer.log_det()

    def _from_z(self, z):
        u = self.theta_standardizer.inverse(z)
        return self.theta_map.inverse(self.prior, u)

    def loss(
        self, key: PRNGKeyArray, theta: Float[Array, " d"], context: Float[Array, " c"]
    ) -> Float[Array, ""]:
        """Conditional flow-matching loss of ONE pair: ``|v(t, z_t, c) - u|²`` at a random ``t``."""
        k_t, k_z = jax.random.split(key)
        t = jax.random.uniform(k_t, (), theta.dtype) ** 0.5  # density 2t on [0, 1]
        z1, _ = self._to_z(theta)
        z0 = jax.random.normal(k_z, z1.shape, z1.dtype)
        zt = (1.0 - (1.0 - self.sigma_min) * t) * z0 + t * z1
        target = z1 - (1.0 - self.sigma_min) * z0
        return jnp.sum((self.vector_field(t, zt, context) - target) ** 2)

    def log_prob_context(self, theta: Float[Array, " d"], context: Float[Array, " c"]) -> Float[Array, ""]:
        """``log q(θ | x)`` for ONE θ given a precomputed context; ``-inf`` outside the box."""
        inside = jnp.all((theta >= self.prior.low) & (theta <= self.prior.high))
        safe = jnp.where(inside, theta, 0.5 * (self.prior.low + self.prior.high))
        z1, ld_map = self._to_z(safe)

        def field_and_div(t, state):
            z, _ = state
            # jacfwd returns v itself as aux: one batch of d tangents, no separate primal pass
            jac, v = jax.jacfwd(lambda y: (self.vector_field(t, y, context),) * 2, has_aux=True)(z)
            return v, jnp.trace(jac)

        # backwards from the data (t = 1) to the noise (t = 0); a(0) = -∫₀¹ div v dt
        z0, a0 = _odeint(field_and_div, (z1, jnp.zeros((), z1.dtype)), 1.0, 0.0, self.ode_steps)
        base = -0.5 * jnp.sum(z0**2) - 0.5 * self.dim * _LOG_2PI
        return jnp.where(inside, base + a0 + ld_map, -jnp.inf)

    def transport(
        self, z: Float[Array, "n d"], context: Float[Array, " c"], t0: float, t1: float
    ) -> Float[Array, "n d"]:
        """Points ``z`` at time ``t0`` carried along the ODE to ``t1`` (0: noise, 1: data)."""
        vf = jax.vmap(self.vector_field, in_axes=(None, 0, None))
        return _odeint(lambda t, y: vf(t, y, context), z, t0, t1, self.ode_steps)

    def sample_context(self, key: PRNGKeyArray, context: Float[Array, " c"], n: int) -> Float[Array, "n d"]:
        def draw(k):
            z0 = jax.random.normal(k, (n, self.dim), dtype=self.prior.low.dtype)
            return jax.vmap(self._from_z)(self.transport(z0, context, 0.0, 1.0))

        return self.theta_map.sample(draw, self.prior, key, n)

    # ---- reconstruction ------------------------------------------------------------------------
    def structure(self) -> dict[str, Any]:
        return {
            "estimator": "fmpe",
            "hidden": self.hidden,
            "num_blocks": self.num_blocks,
            "num_freqs": self.num_freqs,
            "ode_steps": self.ode_steps,
            "sigma_min": self.sigma_min,
        }


def fmpe_from_spec(spec: dict[str, Any]) -> FlowMatchingEstimator:
    """Skeleton :class:`FlowMatchingEstimator` with the structure in ``spec``."""
    prior, embedding, x_shape, xstd = skeleton_parts(spec)
    return FlowMatchingEstimator(
        jax.random.key(0),
        prior,
        embedding,
        x_shape,
        FlowMatchingSettings(
            hidden=spec["hidden"],
            num_blocks=spec["num_blocks"],
            num_freqs=spec["num_freqs"],
            ode_steps=spec["ode_steps"],
            sigma_min=spec["sigma_min"],
            theta_map=theta_map_from_name(spec["theta_map"]),
        ),
        x_standardizer=xstd,
    )


class FlowMatchingLoss(AbstractLoss):
    """FMPE training loss: mean conditional flow-matching loss over the batch (one ``t`` and
    one noise draw per pair). It fits the posterior under the proposal the θ were drawn from,
    so it serves NPE (prior draws) and TSNPE (truncated prior); it has no atomic (APT) form."""

    def __call__(self, flow, theta, x, prior_mask, key):
        del prior_mask
        keys = jax.random.split(key, theta.shape[0])
        return jnp.mean(jax.vmap(lambda k, t, xi: flow.loss(k, t, flow.context(xi)))(keys, theta, x))
