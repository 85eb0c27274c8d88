"""An equal-weight ensemble of spline flows, and what treats a flow and an ensemble alike:
each member's own loss (`member_mean`), the trained weights (`trainable_filter`) and the
skeleton rebuilt from a spec (`flow_from_spec`)."""

import math
from collections.abc import Callable
from typing import Any

import equinox as eqx
import jax
import jax.numpy as jnp
from jax.scipy.special import logsumexp
from jaxtyping import Array, Float, PRNGKeyArray

from ._flow import ConditionalFlow, skeleton_parts
from ._prior import BoxPrior


class FlowEnsemble(eqx.Module):
    """Equal-weight mixture ``q(θ | x) = (1/E) Σ_m q_m(θ | x)`` of ``E`` flows trained at once.

    ``members`` is ONE :class:`ConditionalFlow` whose array leaves carry a leading member axis
    (built with ``eqx.filter_vmap`` from ``E`` keys), so training and sampling run all members
    in one vmapped computation. Each member is trained on its own loss (``fit`` minimises the
    mean of the members' losses, see `member_mean`); the members differ by initialisation. The
    interface is the flow's: ``context``, ``log_prob(_context)``, ``sample(_context)``, ``spec``.
    """

    members: ConditionalFlow
    prior: BoxPrior
    size: int = eqx.field(static=True)

    def __init__(self, make: Callable[[PRNGKeyArray], ConditionalFlow], keys: PRNGKeyArray):
        self.members = eqx.filter_vmap(make)(keys)
        self.size = int(keys.shape[0])
        self.prior = self.member(0).prior

    @property
    def dim(self) -> int:
        return self.members.dim

    @property
    def x_shape(self) -> tuple[int, ...]:
        return self.members.x_shape

    def member(self, i: int) -> ConditionalFlow:
        """Member ``i`` as a plain :class:`ConditionalFlow`."""
        return jax.tree.map(lambda a: a[i] if eqx.is_array(a) else a, self.members)

    def context(self, x: Float[Array, "..."]) -> Float[Array, "e c"]:
        """Each member's embedding of ONE observation."""
        return eqx.filter_vmap(lambda m: m.context(x))(self.members)

    def log_prob_context(self, theta: Float[Array, " d"], context: Float[Array, "e c"]) -> Float[Array, ""]:
        lp = eqx.filter_vmap(lambda m, c: m.log_prob_context(theta, c))(self.members, context)
        return logsumexp(lp) - math.log(self.size)

    def log_prob(self, theta: Float[Array, " d"], x: Float[Array, "..."]) -> Float[Array, ""]:
        return self.log_prob_context(theta, self.context(x))

    def sample_context(self, key: PRNGKeyArray, context: Float[Array, "e c"], n: int) -> Float[Array, "n d"]:
        """``n`` draws: each from a uniformly chosen member (all members draw ``n``, one is kept)."""
        k_pick, k_draw = jax.random.split(key)
        draws = eqx.filter_vmap(lambda m, c, k: m.sample_context(k, c, n))(
            self.members, context, jax.random.split(k_draw, self.size)
        )
        pick = jax.random.randint(k_pick, (n,), 0, self.size)
        return draws[pick, jnp.arange(n)]

    def sample(self, key: PRNGKeyArray, x: Float[Array, "..."], n: int) -> Float[Array, "n d"]:
        return self.sample_context(key, self.context(x), n)

    def box_mass(self, key: PRNGKeyArray, context: Float[Array, "e c"], n: int) -> Float[Array, ""]:
        """The mixture's share of mass inside the box: the members' mean (``n`` draws each)."""
        keys = jax.random.split(key, self.size)
        return jnp.mean(eqx.filter_vmap(lambda m, c, k: m.box_mass(k, c, n))(self.members, context, keys))

    def spec(self) -> dict[str, Any]:
        return {**self.member(0).spec(), "ensemble": self.size}


def member_mean(loss: Callable, flow, *args):
    """``loss(flow, *args)``; for a :class:`FlowEnsemble` the mean of the members' own losses
    (independent training), not the mixture's."""
    if isinstance(flow, FlowEnsemble):
        return jnp.mean(eqx.filter_vmap(lambda m: loss(m, *args))(flow.members))
    return loss(flow, *args)


def flow_from_spec(spec: dict[str, Any]) -> ConditionalFlow | FlowEnsemble:
    """Skeleton :class:`ConditionalFlow` (or :class:`FlowEnsemble`) with the structure in ``spec``."""
    size = int(spec.get("ensemble", 1))
    if size > 1:
        return FlowEnsemble(lambda k: _flow_from_spec(spec, k), jax.random.split(jax.random.key(0), size))
    return _flow_from_spec(spec, jax.random.key(0))


def _flow_from_spec(spec: dict[str, Any], key: PRNGKeyArray) -> ConditionalFlow:
    prior, embedding, x_shape, xstd = skeleton_parts(spec)
    return ConditionalFlow(
        key,
        prior,
        embedding,
        x_shape,
        num_layers=spec["num_layers"],
        num_bins=spec["num_bins"],
        hidden=spec["hidden"],
        num_blocks=spec["num_blocks"],
        tail_bound=spec["tail_bound"],
        use_lu=spec["use_lu"],
        context_gating=spec.get("context_gating", False),  # absent in files written before it
        theta_map=spec.get("theta_map", "logit"),
        x_standardizer=xstd,
    )


def trainable_filter(flow: ConditionalFlow | FlowEnsemble):
    """Boolean pytree: True on the trained weights, False on the frozen prior and standardisations.

    Any estimator with the fields ``prior``, ``theta_standardizer`` and ``x_standardizer`` (the
    spline flow, `FlowMatchingEstimator`): every other inexact array is trained.
    """
    if isinstance(flow, FlowEnsemble):
        spec = jax.tree.map(lambda _: False, flow)
        return eqx.tree_at(lambda f: f.members, spec, replace=trainable_filter(flow.members))
    spec = jax.tree.map(eqx.is_inexact_array, flow)
    frozen = lambda f: (f.prior, f.theta_standardizer, f.x_standardizer)  # noqa: E731
    return eqx.tree_at(frozen, spec, replace=jax.tree.map(lambda _: False, frozen(spec)))
