"""The batched simulator: one compilation per shape, failed draws masked without spoiling the
others, the sharded path equal to the single-device one; bad input at the API boundary."""

import json
import os
import subprocess
import sys
import textwrap

import jax.numpy as jnp
import numpy as np
import pytest

from vdsbi.simulator import (
    PARAM_NAMES,
    SEED_TRUE_THETA,
    Inputs,
    Vehicle,
    default_vehicle,
    make_model,
    seed_profile,
    simulate,
    solve_batch,
)
from vdsbi.simulator._solve import TRACE_COUNT
from vdsbi.simulator.effects import EffectSettings

VEHICLE = default_vehicle()
MODEL = make_model(VEHICLE, ["aero_drag"])
INPUTS = seed_profile(1.0)
THETA = np.array([SEED_TRUE_THETA[n] for n in PARAM_NAMES], dtype=np.float32)


def draws(n, seed=0):
    rng = np.random.default_rng(seed)
    theta = THETA * rng.uniform(0.9, 1.1, size=(n, 6)).astype(np.float32)
    return theta, rng.uniform(10, 11, size=n).astype(np.float32), (np.full((n, 1), 0.6, np.float32),)


def test_compiles_once_per_shape():
    theta, v0, ep = draws(8)
    start = TRACE_COUNT["batch"]
    ys1, ok1 = solve_batch(MODEL, theta, INPUTS, v0, ep)
    ys2, ok2 = solve_batch(MODEL, theta * 1.01, INPUTS, v0 + 0.1, (ep[0] * 2,))
    assert TRACE_COUNT["batch"] == start + 1  # new values, same shapes: no retrace
    assert ys1.shape == (8, INPUTS.num_samples, 6) and bool(ok1.all() & ok2.all())
    assert not np.allclose(ys1, ys2)
    solve_batch(MODEL, theta[:5], INPUTS, v0[:5], (ep[0][:5],))
    assert TRACE_COUNT["batch"] == start + 2  # a new batch size compiles once more
    solve_batch(MODEL, theta[3:], INPUTS, v0[3:], (ep[0][3:],))
    assert TRACE_COUNT["batch"] == start + 2


def test_failed_draws_are_masked_and_spoil_nothing():
    theta, v0, ep = draws(8)
    bad = theta.copy()
    bad[1, 0] = VEHICLE.wheelbase + 0.1  # l_f >= L: l_r < 0, I_z < 0
    bad[3, 4] = np.nan  # NaN cornering stiffness
    bad[5, 2] = -1e5  # negative slip stiffness
    bad_v0 = v0.copy()
    bad_v0[6] = np.inf
    good_ys, good_ok = solve_batch(MODEL, theta, INPUTS, v0, ep)
    ys, ok = solve_batch(MODEL, bad, INPUTS, bad_v0, ep)
    assert bool(good_ok.all())
    assert np.asarray(ok).tolist() == [True, False, True, False, True, False, False, True]
    keep = np.asarray(ok)
    np.testing.assert_array_equal(np.asarray(ys)[keep], np.asarray(good_ys)[keep])


SHARDED = textwrap.dedent(
    """
    import json, sys
    import jax, numpy as np
    sys.path.insert(0, {tests!r})
    import test_simulator_batch as T
    theta, v0, ep = T.draws(6)  # 6 draws on 4 devices: padded to 8, then cut
    theta[2, 0] = 9.0  # one failed draw
    ys, ok = T.solve_batch(T.MODEL, theta, T.INPUTS, v0, ep)
    np.save({out!r}, np.asarray(ys))
    print(json.dumps({{"devices": jax.device_count(), "ok": np.asarray(ok).tolist()}}))
    """
)


def test_sharded_over_four_host_devices_matches_one(tmp_path):
    out = str(tmp_path / "ys.npy")
    code = SHARDED.format(tests=os.path.dirname(__file__), out=out)
    env = {
        **os.environ,
        "XLA_FLAGS": f"{os.environ.get('XLA_FLAGS', '')} --xla_force_host_platform_device_count=4",
        "JAX_PLATFORMS": "cpu",
    }
    proc = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True, timeout=600)
    assert proc.returncode == 0, proc.stderr[-3000:]
    info = json.loads(proc.stdout.strip().splitlines()[-1])
    assert info["devices"] == 4
    theta, v0, ep = draws(6)
    theta[2, 0] = 9.0
    ys, ok = solve_batch(MODEL, theta, INPUTS, v0, ep)
    assert info["ok"] == np.asarray(ok).tolist() == [True, True, False, True, True, True]
    sharded = np.load(out)
    good = np.asarray(ok)
    # Not bit for bit: a shard's batch of 2 is vectorised differently from a batch of 6, and
    # float32 rounding differs by a few ulps after ~1200 RK4 steps (9e-6 with the tests' XLA flags).
    np.testing.assert_allclose(sharded[good], np.asarray(ys)[good], rtol=3e-5, atol=3e-5)


# ---------------------------------------------------------------- bad input at the boundary


def call(theta=None, inputs=INPUTS, vehicle=VEHICLE, **kw):
    theta = THETA.astype(float) if theta is None else theta
    kw.setdefault("v0", 10.5)
    return simulate(theta, inputs, vehicle, **kw)


def with_theta(name, value):
    theta = THETA.astype(float)
    theta[PARAM_NAMES.index(name)] = value
    return theta


@pytest.mark.parametrize(
    "kwargs,field",
    [
        (dict(theta=with_theta("l_f", 2.7)), "l_f"),
        (dict(theta=with_theta("l_f", 3.5)), "l_f"),
        (dict(theta=with_theta("l_f", -0.1)), "l_f"),
        (dict(theta=with_theta("C_alpha_r", -6e4)), "C_alpha_r"),
        (dict(theta=with_theta("C_kappa_f", 0.0)), "C_kappa_f"),
        (dict(theta=with_theta("h_cog", np.nan)), "h_cog"),
        (dict(theta=np.ones(5)), "theta"),
        (dict(effects=EffectSettings(enabled=["aero_dragg"])), "aero_dragg"),
        (dict(effects=EffectSettings(enabled=["aero_drag", "aero_drag"])), "duplicate"),
        (dict(effects=EffectSettings(enabled=["aero_drag"], params={"aero_drag": {"cda": 0.5}})), "cda"),
        (
            dict(effects=EffectSettings(enabled=["aero_drag"], params={"aero_drag": {"CdA": np.nan}})),
            "aero_drag",
        ),
        (dict(effects=EffectSettings(params={"road_grade": {"grade": 0.01}})), "road_grade"),
        (dict(v0=-3.0), "v0"),
        (dict(v0=float("nan")), "v0"),
    ],
)
def test_bad_arguments_raise_value_error_naming_the_field(kwargs, field):
    with pytest.raises(ValueError, match=field):
        call(**kwargs)


@pytest.mark.parametrize("name", ["steer", "torque_front", "torque_rear"])
def test_nan_in_inputs_is_named(name):
    arrays = {k: np.asarray(getattr(INPUTS, k)).copy() for k in ("steer", "torque_front", "torque_rear")}
    arrays[name][17] = np.nan
    bad = Inputs(INPUTS.t0, INPUTS.dt, **arrays)
    with pytest.raises(ValueError, match=f"{name}.*sample 17"):
        call(inputs=bad)


@pytest.mark.parametrize(
    "key,value",
    [("mass", "1500"), ("wheelbase", [2.7]), ("friction", None), ("wheel_radius", True), ("mass", -1.0)],
)
def test_bad_vehicle_values_are_named(key, value):
    data = VEHICLE.to_dict()
    data[key] = value
    with pytest.raises(ValueError, match=key):
        Vehicle.from_dict(data)


def test_missing_vehicle_key_is_named():
    data = VEHICLE.to_dict()
    del data["relaxation_length"]
    with pytest.raises(ValueError, match="relaxation_length"):
        Vehicle.from_dict(data)


def test_inputs_shape_errors():
    with pytest.raises(ValueError, match="dt"):
        Inputs(0.0, 0.0, jnp.zeros(10), jnp.zeros(10), jnp.zeros(10))
    with pytest.raises(ValueError, match="equal length"):
        Inputs(0.0, 0.005, jnp.zeros(10), jnp.zeros(9), jnp.zeros(10))
