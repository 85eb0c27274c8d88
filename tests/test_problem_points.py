"""A problem's parameters as one pytree: the flattened entries a fit steps along, and the one map
from a point to the simulator's values (free entries through the box, held ones exactly)."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from vdsbi.problem import Box, parameter_names, prior_box
from vdsbi.problem.points import (
    Point,
    Space,
    free_positions,
    gather,
    mask_of,
    padded,
    positions,
    ravel,
    scatter,
)
from vdsbi.simulator import default_vehicle
from vdsbi.simulator.effects import EFFECTS

EFFECTS_USED = ("steering_lag", "sensor_bias")


def _space():
    names = parameter_names(EFFECTS_USED)
    box = Box.from_dict(prior_box(default_vehicle(), EFFECTS_USED), names)
    return Space.of(box, [EFFECTS[e] for e in EFFECTS_USED]), box


def test_a_space_splits_the_box_by_effect_and_joins_it_back():
    space, box = _space()
    sizes = [len(EFFECTS[e].param_names) for e in EFFECTS_USED]
    assert space.slices == ((0, sizes[0]), (sizes[0], sum(sizes)))
    assert space.box.names == box.names
    np.testing.assert_array_equal(space.box.low, box.low)
    np.testing.assert_array_equal(space.box.high, box.high)
    with pytest.raises(ValueError, match="box over"):
        Space.of(box, [EFFECTS["steering_lag"]])


def test_scatter_and_gather_are_inverse_along_padded_entries():
    point = Point(jnp.arange(6.0), jnp.arange(10.0, 13.0), jnp.arange(20.0, 24.0))
    at = positions(point)
    np.testing.assert_array_equal(ravel(at), np.arange(13))
    np.testing.assert_array_equal(ravel(point)[ravel(at)], ravel(point))
    index = jnp.asarray(padded([1, 7, 11], width=5, size=13))
    assert index.tolist() == [1, 7, 11, 13, 13]
    taken = gather(point, index)
    np.testing.assert_array_equal(taken, [1.0, 11.0, 22.0, 0.0, 0.0])  # the padding reads 0
    moved = scatter(point, index, taken + 100.0)  # and writes nowhere
    np.testing.assert_array_equal(ravel(moved) - ravel(point), np.isin(np.arange(13), [1, 7, 11]) * 100.0)
    np.testing.assert_array_equal(free_positions(mask_of(point, index)), [1, 7, 11])


def test_held_entries_keep_their_values_exactly_and_free_ones_follow_the_box():
    space, box = _space()
    nt, ne = len(space.theta.names), len(space.effects.names)
    key_t, key_e = jax.random.split(jax.random.key(0))
    z = Point(jax.random.normal(key_t, (nt,)), jnp.zeros(2), jax.random.normal(key_e, (ne,)))
    # Held at the effects' null values (outside their fit box for the lag: τ = 0), θ at a point.
    null = jnp.asarray([v for e in EFFECTS_USED for v in EFFECTS[e].null])
    held = Point(jnp.full(nt, 0.123), jnp.zeros(2), null)
    free = Point(jnp.arange(nt) % 2 == 0, jnp.ones(2, bool), jnp.arange(ne) == 0)
    theta, effect_params = space.values(z, held, free)
    flat = np.concatenate(effect_params)
    mapped = np.asarray(box.from_unbounded(jnp.concatenate([z.theta, z.effects])))
    np.testing.assert_array_equal(theta, np.where(free.theta, mapped[:nt], 0.123))
    np.testing.assert_array_equal(flat, np.where(free.effects, mapped[nt:], null))
    assert [len(p) for p in effect_params] == [len(EFFECTS[e].param_names) for e in EFFECTS_USED]
    # The held entries carry no derivative; each free one its box's dθ/dz.
    jac = jax.jacfwd(lambda t: space.values(Point(t, z.v0, z.effects), held, free)[0])(z.theta)
    np.testing.assert_allclose(
        np.diag(jac), np.where(free.theta, space.theta.dtheta_dz(z.theta), 0.0), rtol=1e-6
    )
