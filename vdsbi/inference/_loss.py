"""Training losses: maximum likelihood (NPE) and the atomic APT / SNPE-C loss."""

from collections.abc import Callable

import equinox as eqx
import jax
import jax.numpy as jnp
from jax.scipy.special import logsumexp
from jaxtyping import Array, Float, Int, PRNGKeyArray


def atom_indices(key: PRNGKeyArray, batch_size: int, num_atoms: int) -> Int[Array, "batch atoms"]:
    """For each row i, column 0 is i and columns 1.. are ``num_atoms - 1`` DISTINCT other rows.

    The contrasting rows are a uniformly random subset of ``{0..B-1} \\ {i}`` (Gumbel top-k).
    """
    if num_atoms < 2 or num_atoms > batch_size:
        raise ValueError(f"need 2 <= num_atoms <= batch_size, got {num_atoms} and {batch_size}")
    noise = jax.random.uniform(key, (batch_size, batch_size - 1))
    _, offsets = jax.lax.top_k(noise, num_atoms - 1)
    rows = jnp.arange(batch_size)[:, None]
    others = (rows + offsets + 1) % batch_size
    return jnp.concatenate([rows, others], axis=1)


def atomic_apt_loss(
    log_prob_fn: Callable[[Array, int], Array],
    prior_log_prob: Callable[[Array], Array],
    theta: Float[Array, "batch d"],
    atoms: Int[Array, "batch atoms"],
) -> Float[Array, ""]:
    """Atomic APT loss (Greenberg et al. 2019), averaged over the batch.

    For row i with atoms ``A_i = {θ_i, θ_j1, ...}`` (all evaluated at ``x_i``):

        ℓ_i = -[ u_i(θ_i) - logsumexp_{θ ∈ A_i} u_i(θ) ],   u_i(θ) = log q(θ | x_i) - log p(θ)

    Args:
        log_prob_fn: ``log_prob_fn(theta_one, i)`` = ``log q(θ | x_i)`` for the i-th example.
        prior_log_prob: ``prior_log_prob(theta_one)``.
        theta: the batch of parameters.
        atoms: from :func:`atom_indices`; column 0 must be the row itself.
    """
    atom_theta = theta[atoms]  # (B, K, d)
    rows = jnp.arange(theta.shape[0])
    lq = jax.vmap(lambda th, i: jax.vmap(lambda t: log_prob_fn(t, i))(th))(atom_theta, rows)
    return _atomic_from_log_probs(lq, jax.vmap(jax.vmap(prior_log_prob))(atom_theta))


def _atomic_from_log_probs(lq, lp):
    """The atomic loss from ``lq[i, k] = log q(θ_{A_ik} | x_i)`` and ``lp[i, k] = log p(θ_{A_ik})``."""
    u = lq - lp
    ll = u[:, 0] - logsumexp(u, axis=1)
    return -jnp.mean(ll)


class AbstractLoss(eqx.Module):
    """``loss(flow, theta, x, prior_mask, key) -> scalar`` on a batch."""

    def __call__(self, flow, theta, x, prior_mask, key):
        raise NotImplementedError


class MaximumLikelihoodLoss(AbstractLoss):
    """NPE: ``-mean log q(θ_i | x_i)``."""

    def __call__(self, flow, theta, x, prior_mask, key):
        del prior_mask, key
        return -jnp.mean(jax.vmap(flow.log_prob)(theta, x))


def leak_penalty(flow, key: PRNGKeyArray, contexts: Float[Array, "batch c"]) -> Float[Array, ""]:
    """Mean squared distance outside the prior box, in box widths, of one reparameterised draw
    of ``q(θ | x_i)`` per context: 0 iff (almost) all of the flow's mass lies in the box.

    The atomic loss compares densities only at atoms inside the box, so it cannot see mass the
    flow puts outside (an `IdentityMap`): that mass drifts freely. The penalty selects, among
    flows equal under the atomic loss, those that keep their mass in the box. Always 0 with a
    `LogitMap`, whose draws all lie in the box (nothing is drawn then).
    """

    def draw(k):
        eps = jax.random.normal(k, (contexts.shape[0], flow.dim), dtype=flow.prior.low.dtype)
        return jax.vmap(flow.unmasked_draw)(eps, contexts)

    return flow.theta_map.leak(draw, flow.prior, key)


def leak_rows_of(contexts: Float[Array, "batch c"], rows: int) -> Float[Array, "m c"]:
    """``rows`` evenly strided rows of a batch (0 or more than it has: all of them). The rows
    of a batch are a random draw already, and a stride takes them from every device's shard."""
    b = contexts.shape[0]
    if rows <= 0 or rows >= b:
        return contexts
    return contexts[:: b // rows][:rows]


class AtomicLoss(AbstractLoss):
    """APT / SNPE-C atomic loss with ``num_atoms`` atoms drawn from the batch, plus
    ``leak_weight`` times `leak_penalty` (0: off) on ``leak_rows`` rows of it (0: all).

    ``leak_at`` (one example, e.g. the observation x_o; None: off) adds the same penalty on as
    many draws at its context: the batch's contexts are the proposal's, and a posterior that
    leaks only at x_o is penalised too weakly by them to stop it.
    """

    num_atoms: int = eqx.field(static=True, default=10)
    leak_weight: float = eqx.field(static=True, default=0.0)
    leak_rows: int = eqx.field(static=True, default=0)
    leak_at: Float[Array, "..."] | None = None

    def __call__(self, flow, theta, x, prior_mask, key):
        del prior_mask
        b = theta.shape[0]
        k = min(self.num_atoms, b)
        key, k_leak = jax.random.split(key) if self.leak_weight > 0 else (key, None)
        atom_theta = theta[atom_indices(key, b, k)]  # (B, K, d)
        contexts = jax.vmap(flow.context)(x)
        # One flat vmap over the B·K (θ, context) pairs with each context broadcast, not
        # gathered per pair: the per-pair gather (and its scatter-add gradient) made the
        # atomic step ~6x slower than these K-fold flow evaluations themselves.
        pair_ctx = jnp.broadcast_to(contexts[:, None, :], (b, k, contexts.shape[-1]))
        lq = jax.vmap(flow.log_prob_context)(
            atom_theta.reshape(b * k, -1), pair_ctx.reshape(b * k, -1)
        ).reshape(b, k)
        lp = jax.vmap(jax.vmap(flow.prior.log_prob))(atom_theta)
        loss = _atomic_from_log_probs(lq, lp)
        if self.leak_weight > 0:
            rows = leak_rows_of(contexts, self.leak_rows)
            pen = leak_penalty(flow, k_leak, rows)
            if self.leak_at is not None:
                at = jnp.broadcast_to(flow.context(jnp.asarray(self.leak_at)), rows.shape)
                pen = pen + leak_penalty(flow, jax.random.fold_in(k_leak, 1), at)
            loss = loss + self.leak_weight * pen
        return loss
