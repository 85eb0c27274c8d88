"""The tyre-friction effect: the lateral limit scales with μ·s, and below half of it nothing changes."""

import numpy as np
import pytest

from vdsbi.simulator import SEED_TRUE_THETA, Inputs, default_vehicle, simulate, theta_from_dict
from vdsbi.simulator.effects import EffectSettings


def _ramp_steer(max_steer: float, duration: float = 8.0, dt: float = 0.005):
    t = np.arange(0.0, duration, dt)
    steer = max_steer * np.clip(t / (0.75 * duration), 0.0, 1.0)
    return Inputs(0.0, dt, steer, np.full_like(t, 150.0), np.zeros_like(t))


@pytest.mark.parametrize("scale", [0.8, 1.2])
def test_peak_lateral_acceleration_scales_with_friction(x64, scale):
    vehicle = default_vehicle()
    theta = theta_from_dict(SEED_TRUE_THETA)
    inputs = _ramp_steer(0.12)
    base, ok0 = simulate(theta, inputs, vehicle, v0=15.0)
    scaled, ok1 = simulate(
        theta,
        inputs,
        vehicle,
        v0=15.0,
        effects=EffectSettings(
            enabled=("tyre_friction",), params={"tyre_friction": {"scale_front": scale, "scale_rear": scale}}
        ),
    )
    assert ok0 and ok1
    peak = lambda ys: np.max(np.abs(ys[:, 1]))
    limit = vehicle.friction * 9.81
    assert peak(base) == pytest.approx(limit, rel=0.1)
    assert peak(scaled) / peak(base) == pytest.approx(scale, rel=0.06)


def test_no_effect_far_below_the_limit(x64):
    vehicle = default_vehicle()
    theta = theta_from_dict(SEED_TRUE_THETA)
    inputs = _ramp_steer(0.01)  # |ay| ≈ 1 m/s², far below μg/2
    base, _ = simulate(theta, inputs, vehicle, v0=15.0)
    scaled, _ = simulate(
        theta,
        inputs,
        vehicle,
        v0=15.0,
        effects=EffectSettings(
            enabled=("tyre_friction",), params={"tyre_friction": {"scale_front": 1.3, "scale_rear": 1.3}}
        ),
    )
    assert np.max(np.abs(scaled[:, 1] - base[:, 1])) < 1e-3 * np.max(np.abs(base[:, 1]))


def test_prior_reaches_the_grip_the_drive_used():
    # A race car that pulls 2 × vehicle.json's μ·g (slicks, downforce) needs friction factors of
    # at least 2: the box reaches past that, unless the user or vehicle.json set it.
    import dataclasses

    from vdsbi.problem import prior_box
    from vdsbi.simulator.effects import get_effect

    vehicle = default_vehicle()
    effects = ("tyre_friction",)
    high = lambda box: box["tyre_friction.scale_rear"][1]
    assert high(prior_box(vehicle, effects, grip=0.9)) == pytest.approx(1.8)  # the effect's own bound
    assert high(prior_box(vehicle, effects, grip=2.0)) == pytest.approx(
        get_effect("tyre_friction").grip_margin * 2.0
    )
    asked = {"tyre_friction.scale_rear": (0.5, 1.6)}
    assert high(prior_box(vehicle, effects, asked, grip=2.0)) == pytest.approx(1.6)
    fixed = dataclasses.replace(vehicle, prior={"tyre_friction.scale_rear": (0.5, 1.7)})
    assert high(prior_box(fixed, effects, grip=2.0)) == pytest.approx(1.7)
    assert prior_box(vehicle, (), grip=2.0) == prior_box(vehicle, ())


@pytest.mark.parametrize("grip", [0.3, 0.8, 1.2, 2.0])
def test_prior_floor_is_the_grip_the_drive_used(grip):
    # The car pulled grip × μ·g on its weight alone: neither axle's factor may sit far below grip
    # (per axle 0.9 × grip), whatever the effect's own lower bound; the box stays a box.
    from vdsbi.problem import prior_box
    from vdsbi.simulator.effects import get_effect

    eff = get_effect("tyre_friction")
    box = prior_box(default_vehicle(), ("tyre_friction",), grip=grip)
    for axle, (lo_own, _) in zip(eff.param_names, eff.bounds):
        lo, hi = box[f"tyre_friction.{axle}"]
        assert lo == pytest.approx(max(lo_own, eff.grip_floor * grip)) and lo >= 0.9 * grip - 1e-12
        assert lo < hi
    assert prior_box(default_vehicle(), ("tyre_friction",))["tyre_friction.scale_front"] == eff.bounds[0]
