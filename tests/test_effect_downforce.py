"""The downforce effect: axle loads grow with speed² split by the aero balance, so the tyres
saturate later at speed; at its null it is the base model exactly; it is registered, searched
and chosen by default where a drive is fast and uses more grip than the car's weight gives."""

import dataclasses

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from vdsbi.discovery import effect_names
from vdsbi.discovery._candidates import LOOKALIKE_GROUPS, effect_space, single_candidates
from vdsbi.io import build_recording
from vdsbi.problem import default_effects, make_problem, prior_box
from vdsbi.simulator import (
    GRAVITY,
    SEED_TRUE_THETA,
    Inputs,
    SeedManeuver,
    default_vehicle,
    make_model,
    seed_profile,
    simulate,
    solve,
    theta_from_dict,
)
from vdsbi.simulator._effects._aero_drag import AIR_DENSITY
from vdsbi.simulator._effects._downforce import REFERENCE_SPEED
from vdsbi.simulator.effects import EFFECTS, EffectSettings, effect_params_from
from vdsbi.simulator.solvers import Solver

VEHICLE = default_vehicle()
THETA = theta_from_dict(SEED_TRUE_THETA)
AY = 1  # CHANNELS index of ay


def _front_share(theta=THETA) -> float:
    """The static load's share on the front axle: l_r / L."""
    return float((VEHICLE.wheelbase - theta[0]) / VEHICLE.wheelbase)


def test_registered_searched_and_a_lookalike_of_tyre_friction():
    cls = EFFECTS["downforce"]
    assert cls.param_names == ("coef", "balance_front") and cls.adds_load
    assert "downforce" in effect_names() and ("downforce",) in single_candidates()
    space = effect_space()
    assert space.slices["downforce"].stop - space.slices["downforce"].start == 2
    assert any({"downforce", "tyre_friction"} <= set(g) for g in LOOKALIKE_GROUPS)


def test_null_reproduces_the_base_model_exactly(x64):
    inputs = seed_profile(3.0)
    base, ok = simulate(THETA, inputs, VEHICLE, v0=30.0)
    assert ok
    # at coef = 0 the balance moves nothing
    for params in ({}, {"coef": 0.0, "balance_front": 0.3}):
        effects = EffectSettings(enabled=("downforce",), params={"downforce": params})
        ys, ok = simulate(THETA, inputs, VEHICLE, v0=30.0, effects=effects)
        assert ok
        # identical but for rounding: the compiler may order the same sums differently
        np.testing.assert_allclose(ys, base, rtol=1e-13, atol=1e-13)


@pytest.mark.parametrize("longitudinal", ["torque", "speed"])
def test_axle_loads_grow_with_speed_squared_split_by_the_balance(x64, longitudinal):
    model = make_model(VEHICLE, ("downforce",), longitudinal)
    c_la, balance = 3.2, 0.42  # m², front share
    weight = VEHICLE.mass * GRAVITY
    coef = 0.5 * AIR_DENSITY * c_la * REFERENCE_SPEED**2 / weight
    _, params = effect_params_from(("downforce",), {"downforce": {"coef": coef, "balance_front": balance}})
    static = np.array(model.static_loads(THETA))
    for vx in (0.0, 10.0, 25.0, 50.0, 70.0):
        aero = 0.5 * AIR_DENSITY * c_la * vx**2
        extra = np.array(model.vertical_loads(THETA, params, jnp.asarray(vx))) - static
        np.testing.assert_allclose(extra, [balance * aero, (1 - balance) * aero], rtol=1e-12, atol=1e-9)
        # load transfer under a_x comes on top, unchanged
        with_ax = np.array(model.loads(THETA, params, jnp.asarray(vx), 2.0))
        np.testing.assert_allclose(with_ax.sum(), static.sum() + aero, rtol=1e-12)


def test_the_tyres_saturate_later_at_speed(x64):
    """At a constant 40 m/s a steer ramp takes the car to its limit: downforce worth
    coef·(40/50)² of the weight, on the axles in the static split, raises the peak a_y by that
    share; in the linear range early in the ramp nothing changes."""
    speed, coef = 40.0, 0.8
    dt = 0.005
    t = np.arange(0.0, 8.0, dt)
    steer = 0.03 * np.clip(t / 6.0, 0.0, 1.0)
    zeros = np.zeros_like(t)
    inputs = Inputs(0.0, dt, steer, zeros, zeros, speed=np.full_like(t, speed), accel=zeros)
    effects = EffectSettings(enabled=("downforce",))
    base, ok0 = simulate(THETA, inputs, VEHICLE, longitudinal="speed", effects=effects)
    params = {"downforce": {"coef": coef, "balance_front": _front_share()}}
    loaded_effects = dataclasses.replace(effects, params=params)
    loaded, ok1 = simulate(THETA, inputs, VEHICLE, longitudinal="speed", effects=loaded_effects)
    assert ok0 and ok1
    peak = lambda ys: np.max(np.abs(ys[:, AY]))
    assert peak(base) == pytest.approx(VEHICLE.friction * GRAVITY, rel=0.06)
    assert peak(loaded) / peak(base) == pytest.approx(1 + coef * (speed / REFERENCE_SPEED) ** 2, rel=0.02)
    early = t < 1.0  # |a_y| below a fifth of μg
    np.testing.assert_allclose(loaded[early, AY], base[early, AY], rtol=0, atol=0.02)


def test_gradient_with_respect_to_coef_matches_finite_differences(x64, getkey):
    model = make_model(VEHICLE, ("downforce",))
    # a fast second of the seed's maneuver: near the limit, so a_y and yaw rate feel the load
    inputs = seed_profile(
        1.0, maneuver=SeedManeuver(steer_amplitude=0.03, torque_period=1.0, steer_period=1.0)
    )
    weights = jax.random.normal(getkey(), (inputs.num_samples, 6), dtype=jnp.float64)
    theta = jnp.asarray(THETA)

    def channels(coef):
        p = jnp.stack([coef, jnp.asarray(0.45)])
        ys, _ = solve(model, theta, inputs, jnp.asarray(35.0), (p,), Solver(dt=0.005))
        return ys

    scale = jnp.abs(channels(jnp.asarray(1.0))).mean(0) + 1e-3
    loss = lambda coef: jnp.mean(weights * channels(coef) / scale)
    value_and_grad = jax.jit(jax.value_and_grad(loss))
    coef, h = 1.0, 1e-5
    grad = float(value_and_grad(jnp.asarray(coef))[1])
    fd = (
        float(value_and_grad(jnp.asarray(coef + h))[0]) - float(value_and_grad(jnp.asarray(coef - h))[0])
    ) / (2 * h)
    assert abs(fd) > 1e-7
    assert grad == pytest.approx(fd, rel=1e-4)


def _kinematic_drive(speed_mean: float, peak_grip: float, duration: float = 60.0, rate: float = 50.0):
    """A neutral-steering car on a weave at a slowly varying speed (r = v·δ/L, a_y = v·r),
    its steer sized so that |a_y| peaks at `peak_grip` × μ·g: a speed-mode recording."""
    t = np.arange(0.0, duration, 1 / rate)
    v = speed_mean * (1 + 0.1 * np.sin(2 * np.pi * t / 20.0))
    shape = np.sin(2 * np.pi * t / 8.0)
    amp = peak_grip * VEHICLE.friction * GRAVITY * VEHICLE.wheelbase / np.max(v**2 * np.abs(shape))
    steer = amp * shape
    r = v * steer / VEHICLE.wheelbase
    cols = {"t": t, "steer": steer, "ay": v * r, "yaw_rate": r, "vx": v}
    return make_problem(build_recording(cols, "weave.csv"), VEHICLE)


def test_chosen_by_default_on_a_fast_drive_beyond_the_weights_grip():
    named = lambda prob: dict(default_effects(prob))
    fast_hard = named(_kinematic_drive(40.0, 1.2))
    assert "downforce" in fast_hard and "tyre_friction" in fast_hard
    assert "m/s" in fast_hard["downforce"]
    assert "downforce" not in named(_kinematic_drive(12.0, 0.4))  # slow and mild
    assert "downforce" not in named(_kinematic_drive(12.0, 1.2))  # hard, but too slow to matter
    assert "downforce" not in named(_kinematic_drive(40.0, 0.5))  # fast, but within the weight's grip


def test_friction_floor_gives_way_to_downforce():
    """Beside downforce the tyres can carry the grip a drive used with smaller friction factors:
    only the upper bounds follow the grip then; downforce's own box is its bounds."""
    alone = prior_box(VEHICLE, ("tyre_friction",), grip=1.6)
    both = prior_box(VEHICLE, ("tyre_friction", "downforce"), grip=1.6)
    for axle in ("scale_front", "scale_rear"):
        name = f"tyre_friction.{axle}"
        assert alone[name][0] >= 0.9 * 1.6
        assert both[name] == (0.4, alone[name][1]) and both[name][1] >= 1.25 * 1.6
    assert both["downforce.coef"] == (0.0, 3.0) and both["downforce.balance_front"] == (0.2, 0.8)
