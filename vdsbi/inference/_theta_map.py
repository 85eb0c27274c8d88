"""How an estimator's space relates to the prior box: the logit bijection or θ itself.

``LogitMap`` maps the box onto ℝ^d, so the estimator's density is zero outside the box and every
draw lies inside it. ``IdentityMap`` (sbi's choice) leaves θ as it is: the density is cut at the
box without renormalising (the mass outside is lost; ratios at one x, e.g. the APT loss, are
unaffected), and draws are turned into posterior draws by rejection. Both maps are followed by
the estimator's own affine standardisation.
"""

from collections.abc import Callable
from typing import ClassVar

import equinox as eqx
import jax
import jax.numpy as jnp
from jaxtyping import Array, Float, PRNGKeyArray

from ._prior import BoxPrior
from ._rejection import box_rejection

Draw = Callable[[PRNGKeyArray], Float[Array, "n d"]]


class AbstractThetaMap(eqx.Module):
    """θ in the box of a `BoxPrior` ↔ the estimator's space, for ONE θ."""

    name: eqx.AbstractClassVar[str]

    def forward(
        self, prior: BoxPrior, theta: Float[Array, " d"]
    ) -> tuple[Float[Array, " d"], Float[Array, ""]]:
        """``(z, log|dz/dθ|)`` for one θ inside the box."""
        raise NotImplementedError

    def inverse(self, prior: BoxPrior, z: Float[Array, " d"]) -> Float[Array, " d"]:
        """θ for one ``z``; possibly outside the box unless the map confines it."""
        raise NotImplementedError

    def sample(self, draw: Draw, prior: BoxPrior, key: PRNGKeyArray, n: int) -> Float[Array, "n d"]:
        """``n`` draws inside the box from ``draw(key) -> (n, d)`` (the estimator's, mapped)."""
        raise NotImplementedError

    def box_mass(self, draw: Draw, prior: BoxPrior, key: PRNGKeyArray) -> Float[Array, ""]:
        """Monte-Carlo share of ``draw``'s mass inside the box."""
        raise NotImplementedError

    def leak(self, draw: Draw, prior: BoxPrior, key: PRNGKeyArray) -> Float[Array, ""]:
        """Mean over ``draw(key)``'s rows of the squared distance outside the box, in box
        widths: 0 iff (almost) all the mass lies in the box."""
        raise NotImplementedError


class LogitMap(AbstractThetaMap):
    """``z = logit((θ - low) / (high - low))``: a bijection from the box onto ℝ^d."""

    name: ClassVar[str] = "logit"

    def forward(self, prior, theta):
        return prior.to_unbounded(theta)

    def inverse(self, prior, z):
        return prior.from_unbounded(z)

    def sample(self, draw, prior, key, n):
        return draw(key)

    def box_mass(self, draw, prior, key):
        del draw, key  # every draw lies inside: nothing to draw
        return jnp.ones((), prior.low.dtype)

    def leak(self, draw, prior, key):
        del draw, key
        return jnp.zeros((), prior.low.dtype)


class IdentityMap(AbstractThetaMap):
    """``z = θ``: the estimator lives on ℝ^d; its draws outside the box are rejected."""

    name: ClassVar[str] = "affine"

    def forward(self, prior, theta):
        return theta, jnp.zeros((), theta.dtype)

    def inverse(self, prior, z):
        return z

    def sample(self, draw, prior, key, n):
        return box_rejection(draw, prior, key, n)

    def box_mass(self, draw, prior, key):
        draws = draw(key)
        return jnp.mean(jnp.all((draws >= prior.low) & (draws <= prior.high), axis=1))

    def leak(self, draw, prior, key):
        draws = draw(key)
        width = prior.high - prior.low
        excess = (jax.nn.relu(draws - prior.high) + jax.nn.relu(prior.low - draws)) / width
        return jnp.mean(jnp.sum(excess**2, axis=-1))


THETA_MAPS: dict[str, type[AbstractThetaMap]] = {m.name: m for m in (LogitMap, IdentityMap)}


def theta_map_from_name(name: str) -> AbstractThetaMap:
    """The map stored in an estimator's spec under ``name`` (``"logit"`` or ``"affine"``)."""
    if name not in THETA_MAPS:
        raise ValueError(f"unknown theta map {name!r}; expected one of {sorted(THETA_MAPS)}")
    return THETA_MAPS[name]()
