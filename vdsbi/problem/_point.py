"""The parameters of a problem as one pytree, and the one map from it to the simulator's values.

A `Point` holds θ, each window's start-speed offset and every effect's parameters, in the
unbounded coordinates fits step in. A `Space` maps a point to (θ, one parameter vector per
effect) through each part's box. A point of booleans of the same shape splits a point's free
entries (mapped from the fitted coordinates) from its held ones (kept exactly at their values,
so an effect held at its null value vanishes exactly): `Space.values`, the elementwise form of
`eqx.partition` / `eqx.combine`.

A fit steps along a point's flattened free entries: `positions` says where each entry sits in
`ravel`'s vector, and `scatter` writes a vector of free entries back into a point, so fits with
few free entries and with many share one compiled program (`padded`).
"""

from __future__ import annotations

from collections.abc import Sequence

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jax.flatten_util import ravel_pytree
from jaxtyping import Array, ArrayLike, Float

from ..simulator import PARAM_NAMES
from ._box import Box


class Point(eqx.Module):
    """θ, the start speeds and the effects' parameters of one problem.

    Attributes:
        theta: (6,) θ in PARAM_NAMES order.
        v0: (W,) each fitted window's start-speed offset from its measured speed, m/s (none
            where the problem follows the measured speed).
        effects: (E,) every effect's parameters, flat in the space's order (`Space.slices`).

    The same type holds unbounded coordinates, physical values, or a mask of free entries.
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


def padded(index: Sequence[int] | np.ndarray, width: int, size: int) -> np.ndarray:
    """`index` padded to `width` with the out-of-range index `size`: every number of free
    entries then shares one compilation (the padding's slots are dropped by `scatter` and read
    as 0 by `gather`)."""
    out = np.full(max(len(index), width), size)
    out[: len(index)] = index
    return out


def scatter(point: Point, index: Array, values: Array) -> Point:
    """`point` with the flattened entries `index` (padded: `padded`) set to `values`."""
    flat, unravel = ravel_pytree(point)
    return unravel(flat.at[index].set(values, mode="drop"))


def gather(point: Point, index: Array) -> Array:
    """The flattened entries `index` of `point`, the padding's slots at 0."""
    flat, _ = ravel_pytree(point)
    return jnp.where(index < flat.size, flat[jnp.minimum(index, flat.size - 1)], 0.0)


def mask_of(point: Point, index: Array) -> Point:
    """A point of booleans: True at the flattened entries `index` (padded: `padded`)."""
    return scatter(jax.tree.map(lambda a: jnp.zeros(jnp.shape(a), bool), point), index, True)


class Space(eqx.Module):
    """Maps a `Point` to the simulator's values.

    Attributes:
        theta: the box of θ.
        effects: the box of every effect parameter, flat.
        slices: each effect's (start, stop) in the flat effect vector.
    """

    theta: Box
    effects: Box
    slices: tuple[tuple[int, int], ...] = eqx.field(static=True)

    @classmethod
    def of(cls, box: Box, effects: Sequence[type]) -> Space:
        """The space of a box over θ, then the parameters of `effects` (effect classes) in order
        (`parameter_names`' order)."""
        nt, sizes = len(PARAM_NAMES), [len(e.param_names) for e in effects]
        if box.dim != nt + sum(sizes):
            raise ValueError(f"box over {box.dim} parameters, θ and the effects have {nt + sum(sizes)}")
        stops = np.cumsum([0, *sizes])
        return cls(
            Box(box.low[:nt], box.high[:nt], box.names[:nt]),
            Box(box.low[nt:], box.high[nt:], box.names[nt:]),
            tuple((int(a), int(b)) for a, b in zip(stops[:-1], stops[1:])),
        )

    @property
    def box(self) -> Box:
        """The box over θ, then every effect parameter."""
        return Box(
            jnp.concatenate([self.theta.low, self.effects.low]),
            jnp.concatenate([self.theta.high, self.effects.high]),
            (*self.theta.names, *self.effects.names),
        )

    def values(self, z: Point, held: Point, free: Point) -> tuple[Array, tuple[Array, ...]]:
        """(θ, one parameter vector per effect): where `free` (a point of booleans) is set, the
        box map of `z`'s coordinates; elsewhere exactly `held`'s values. The start speeds are
        offsets added to the measured ones, not boxed: they are read from `z` directly."""
        theta = jnp.where(free.theta, self.theta.from_unbounded(z.theta), held.theta)
        flat = jnp.where(free.effects, self.effects.from_unbounded(z.effects), held.effects)
        return theta, tuple(flat[a:b] for a, b in self.slices)
