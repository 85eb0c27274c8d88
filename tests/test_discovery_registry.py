"""Discovery reads the effect registry at call time: an effect defined here and added with
`register_effect` is searched by `diagnose` like a built-in one, with nothing in discovery
touched."""

import jax
import jax.numpy as jnp
import numpy as np

from vdsbi.discovery import diagnose_mismatch, effect_names
from vdsbi.discovery._candidates import effect_space, single_candidates
from vdsbi.io import build_recording
from vdsbi.simulator import (
    CHANNELS,
    PARAM_NAMES,
    SEED_TRUE_THETA,
    Vehicle,
    default_vehicle,
    random_profile,
    simulate,
)
from vdsbi.simulator._vehicle import VEHICLE_KEYS
from vdsbi.simulator.effects import EFFECTS, AbstractEffect, EffectSettings, Param, register_effect

NOISE = {"ax": 0.1, "ay": 0.1, "yaw_rate": 0.004, "omega_front": 0.1, "omega_rear": 0.1}


class TowPull(AbstractEffect):
    """A constant rearward pull on the body, e.g. a trailer (felt by the accelerometer)."""

    name = "test_tow_pull"
    params = (Param("force", "N", null=0.0, typical=(0.0, 2000.0), bounds=(0.0, 5000.0), start=100.0),)
    description = "constant rearward pull"

    def body_force(self, p, ctx):
        return -p[0], jnp.zeros_like(p[0])


def _recording(vehicle: Vehicle, force: float):
    inputs = random_profile(jax.random.key(5), 6.0)
    theta = np.array([SEED_TRUE_THETA[n] for n in PARAM_NAMES])
    with jax.enable_x64(True):
        ys, ok = simulate(
            theta,
            inputs,
            vehicle,
            v0=15.0,
            effects=EffectSettings(enabled=[TowPull.name], params={TowPull.name: {"force": force}}),
        )
    assert ok
    rng = np.random.default_rng(0)
    cols = {
        "t": np.asarray(inputs.ts),
        "steer": np.asarray(inputs.steer),
        "torque_front": np.asarray(inputs.torque_front),
        "torque_rear": np.asarray(inputs.torque_rear),
    }
    cols.update({c: ys[:, CHANNELS.index(c)] + NOISE[c] * rng.standard_normal(len(ys)) for c in NOISE})
    return build_recording(cols, "tow.csv")


def test_registered_effect_is_searched_by_diagnose():
    d = default_vehicle()
    vehicle = Vehicle(**{k: float(getattr(d, k)) for k in VEHICLE_KEYS}, noise_std=NOISE)
    try:
        register_effect(TowPull)
        assert TowPull.name in effect_names() and (TowPull.name,) in single_candidates()
        space = effect_space()
        assert space.slices[TowPull.name].stop == space.num_params  # appended last, one parameter
        rec = _recording(vehicle, force=600.0)
        res = diagnose_mismatch(
            rec,
            vehicle,
            candidates=(TowPull.name, "sensor_bias"),
            max_effects=1,
            num_draws=50,
            single_iters=6,
            final_iters=10,
            final_dt=0.005,
        )
        rows = {tuple(r["effects"]): r for r in res.report["effects"]}
        assert (TowPull.name,) in rows and ("sensor_bias",) in rows
        assert np.isfinite(rows[(TowPull.name,)]["params"][TowPull.name]["force"])
    finally:
        EFFECTS.pop(TowPull.name, None)
    assert TowPull.name not in effect_names()


def test_an_effect_not_searched_is_simulated_but_no_candidate():
    assert "steer_offset" in EFFECTS and not EFFECTS["steer_offset"].searched
    assert "steer_offset" not in effect_names() and "steer_offset" not in effect_space().names
