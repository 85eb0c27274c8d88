"""A point of the search: θ, each window's start-speed offset and every candidate effect's
parameters, in the unbounded coordinates the fits step in; `Space`, the one map from a point to
the simulator's values; and masks of the same shape that split a point's free entries from its
fixed ones.

A Jacobian is taken along a point's flattened free entries (`positions` says where each entry
sits in `ravel_pytree`'s vector), so a candidate with few free entries and one with many share one
compiled program."""

from __future__ import annotations

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, ArrayLike, Bool, Float

from ..problem import Box


class Point(eqx.Module):
    """One point of the search.

    Attributes:
        theta: (6,) θ's logit coordinates in the vehicle's prior box (`Box.to_unbounded`).
        v0: (W,) each fitted window's start-speed offset from its measured speed, m/s.
        effects: (E,) every candidate effect's logit coordinates in its fit box, in the effect
            space's order (`EffectSpace.slices` says whose they are).
    """

    theta: Float[ArrayLike, " 6"]
    v0: Float[ArrayLike, " W"]
    effects: Float[ArrayLike, " E"]

    def numpy(self) -> Point:
        """A writable float64 copy (what a fit's bookkeeping edits)."""
        return jax.tree.map(lambda a: np.array(a, dtype=float), self)

    def jax(self) -> Point:
        return jax.tree.map(jnp.asarray, self)


def ravel(point: Point) -> np.ndarray:
    """The entries of `point` (or of a mask or a `positions` point) as one vector."""
    return np.concatenate([np.ravel(leaf) for leaf in jax.tree.leaves(point)])


def positions(point: Point) -> Point:
    """Each entry's index in `ravel(point)`, as a point of the same shape."""
    leaves, tree = jax.tree.flatten(point)
    starts = np.cumsum([0] + [np.size(leaf) for leaf in leaves])
    return jax.tree.unflatten(tree, [np.arange(a, a + np.size(leaf)) for a, leaf in zip(starts, leaves)])


def free_positions(mask: Point) -> np.ndarray:
    """Indices in the flattened point of the entries `mask` (a point of booleans) frees."""
    return np.flatnonzero(ravel(mask))


class Space(eqx.Module):
    """Maps a `Point` to the simulator's values.

    Attributes:
        theta: the prior box of θ.
        effects: the fit box of every effect parameter, flat.
        null: (E,) values at which each effect vanishes.
        slices: each effect's (start, stop) in the flat effect vector.
    """

    theta: Box
    effects: Box
    null: Float[Array, " E"]
    slices: tuple[tuple[int, int], ...] = eqx.field(static=True)

    def effect_params(self, point: Point, active: Bool[Array, " E"]) -> tuple[jax.Array, ...]:
        """One parameter vector per effect; inactive ones at their null values."""
        flat = jnp.where(active, self.effects.from_unbounded(point.effects), self.null)
        return tuple(flat[a:b] for a, b in self.slices)

    def physical(self, point: Point, active: Bool[Array, " E"]):
        """(θ, one parameter vector per effect) at `point`."""
        return self.theta.from_unbounded(point.theta), self.effect_params(point, active)
