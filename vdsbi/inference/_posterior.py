"""The trained posterior ``q(θ | x)``, by default at the observation ``x_o``."""

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import optax
from jaxtyping import Array, Float, PRNGKeyArray

from ._estimator import AbstractEstimator
from ._prior import BoxPrior
from ._serialise import FORMAT_VERSION, flow_from_bytes, flow_to_bytes, read_npz, write_npz


def on_one_device(x):
    """An observation as one array on one device. Only a concrete array spanning several devices
    goes through the host (one simulated under sharding; the flow's parameters live on one):
    the others stay where they are, so a Posterior called in a loop copies nothing."""
    if isinstance(x, jax.Array) and not isinstance(x, jax.core.Tracer) and len(x.sharding.device_set) > 1:
        x = np.asarray(x)
    return jnp.asarray(x)


@eqx.filter_jit
def sample_flow(flow, key, x, n):
    return flow.sample(key, x, n)


@eqx.filter_jit
def flow_log_prob(flow, theta, x):
    ctx = flow.context(x)
    return jax.vmap(lambda t: flow.log_prob_context(t, ctx))(theta)


@eqx.filter_jit
def _ascend(flow, z0, x, num_steps, learning_rate):
    ctx = flow.context(x)
    opt = optax.adam(learning_rate)

    def neg(z):
        return -flow.log_prob_context(flow.prior.from_unbounded(z), ctx)

    def step(carry, _):
        z, s = carry
        g = jax.grad(neg)(z)
        u, s = opt.update(g, s, z)
        return (optax.apply_updates(z, u), s), None

    (z, _), _ = jax.lax.scan(step, (z0, opt.init(z0)), None, length=num_steps)
    return z


class Posterior(eqx.Module):
    """A conditional flow together with a default observation ``x_o``.

    Args:
        flow: the trained `AbstractEstimator`.
        x_o: default observation (one example, shape ``flow.x_shape``), or None.
    """

    flow: AbstractEstimator
    x_o: Float[Array, "..."] | None = None

    @property
    def prior(self) -> BoxPrior:
        return self.flow.prior

    def _x(self, x):
        x = self.x_o if x is None else x
        if x is None:
            raise ValueError("No observation: pass x= or build the Posterior with x_o.")
        x = on_one_device(x)
        if tuple(x.shape) != self.flow.x_shape:
            raise ValueError(f"x has shape {tuple(x.shape)}, the estimator expects {self.flow.x_shape}")
        return x

    def sample(self, key: PRNGKeyArray, n: int, x=None) -> Float[Array, "n d"]:
        """``n`` draws from ``q(θ | x)`` (``x`` defaults to ``x_o``); always inside the prior box."""
        return sample_flow(self.flow, key, self._x(x), int(n))

    def log_prob(self, theta: Float[Array, "*batch d"], x=None) -> Float[Array, "*batch"]:
        """``log q(θ | x)``; ``-inf`` outside the prior box (with an `IdentityMap` not
        renormalised for the flow's mass outside the box; see `ConditionalFlow`)."""
        theta = jnp.asarray(theta)
        batch = theta.shape[:-1]
        lp = flow_log_prob(self.flow, theta.reshape(-1, self.flow.dim), self._x(x))
        return lp.reshape(batch)

    def map(
        self,
        key: PRNGKeyArray,
        x=None,
        *,
        num_init: int = 1000,
        num_steps: int = 300,
        learning_rate: float = 1e-2,
    ) -> Float[Array, " d"]:
        """MAP estimate: best of ``num_init`` samples, refined by Adam on the unbounded (logit) scale."""
        x = self._x(x)
        cand = self.sample(key, num_init, x)
        best = cand[jnp.argmax(self.log_prob(cand, x))]
        z0, _ = self.prior.to_unbounded(best)
        z = _ascend(self.flow, z0, x, int(num_steps), float(learning_rate))
        theta = self.prior.from_unbounded(z)
        return jnp.where(self.log_prob(theta, x) >= self.log_prob(best, x), theta, best)

    def save(self, path) -> None:
        """Write to ONE file (atomic); reload with :meth:`Posterior.load` in any process."""
        header = {"kind": "Posterior", "version": FORMAT_VERSION, "flow": self.flow.spec()}
        arrays = {"flow": flow_to_bytes(self.flow)}
        if self.x_o is not None:
            arrays["x_o"] = np.asarray(self.x_o)
        write_npz(path, header, arrays)

    @classmethod
    def load(cls, path) -> "Posterior":
        header, arrays = read_npz(path)
        if header.get("kind") != "Posterior":
            raise ValueError(f"{path} does not hold a Posterior (kind={header.get('kind')!r})")
        flow = flow_from_bytes(header["flow"], arrays["flow"])
        x_o = jnp.asarray(arrays["x_o"]) if "x_o" in arrays else None
        return cls(flow, x_o)
