"""The real-car effects (torque gain, signal delay, sensor scale factors, tyre friction): each
is the base model at its null value, differentiable in its parameters, does what its equation
says, and its parameters come back from a small noise-free recording.

One model with the four effects enabled serves every test (one compilation)."""

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import pytest

from vdsbi.estimation import levenberg_marquardt
from vdsbi.simulator import CHANNELS, PARAM_NAMES, SEED_TRUE_THETA, Inputs, default_vehicle, make_model, solve
from vdsbi.simulator.effects import effect_params_from
from vdsbi.simulator.solvers import Solver

VEHICLE = default_vehicle()
NAMES = ("torque_gain", "signal_delay", "sensor_scale", "tyre_friction")
TRUE = {
    "torque_gain": {"gain": 0.85},
    "signal_delay": {"delay": 0.08},
    "sensor_scale": {"ax": 0.03, "ay": -0.04, "yaw_rate": 0.02},
    "tyre_friction": {"scale_front": 0.8, "scale_rear": 0.9},
}
SOLVER = Solver(dt=0.005)
RATE, V0 = 100.0, 15.0
I = {c: k for k, c in enumerate(CHANNELS)}


def _inputs(steer_amp=0.04, duration=6.0):
    """Sine steer and a torque varying around a drive level: excites every parameter."""
    t = np.arange(int(duration * RATE) + 1) / RATE
    steer = steer_amp * np.sin(2 * np.pi * 0.6 * t) * np.clip(t, 0, 1)
    tq = 250.0 + 200.0 * np.sin(2 * np.pi * 0.4 * t)
    return Inputs(0.0, 1 / RATE, steer, tq, -0.3 * np.clip(-tq, 0, None))


@eqx.filter_jit
def _run(model, theta, inputs, params):
    return solve(model, theta, inputs, jnp.asarray(V0, theta.dtype), params, SOLVER)


@pytest.fixture(scope="module")
def setup():
    with jax.enable_x64(True):
        theta = jnp.array([SEED_TRUE_THETA[n] for n in PARAM_NAMES])
        model = make_model(VEHICLE, NAMES)
        yield model, theta


def _params(values):
    return tuple(jnp.asarray(p) for p in effect_params_from(NAMES, values)[1])


def test_null_values_are_the_base_model(setup):
    model, theta = setup
    inputs = _inputs()
    base, ok0 = _run(make_model(VEHICLE), theta, inputs, ())
    null, ok1 = _run(model, theta, inputs, _params({}))
    assert ok0 and ok1
    # equal to round-off (a different compiled program)
    np.testing.assert_allclose(np.asarray(null), np.asarray(base), rtol=1e-12, atol=1e-12)


def test_gradients_are_finite_and_nonzero(setup):
    model, theta = setup
    inputs = _inputs(steer_amp=0.12)  # past half the grip, so friction acts

    def loss(flat):
        parts, k = [], 0
        for name in NAMES:
            n = len(TRUE[name])
            parts.append(flat[k : k + n])
            k += n
        return jnp.sum(_run(model, theta, inputs, tuple(parts))[0] ** 2)

    x = jnp.concatenate(_params(TRUE))
    g = np.asarray(jax.grad(loss)(x))
    assert np.all(np.isfinite(g)) and np.all(np.abs(g) > 0), g


def test_torque_gain_is_the_base_model_driven_by_scaled_torques(setup):
    model, theta = setup
    inputs = _inputs()
    scaled = Inputs(0.0, inputs.dt, inputs.steer, 0.85 * inputs.torque_front, 0.85 * inputs.torque_rear)
    want, _ = _run(make_model(VEHICLE), theta, scaled, ())
    got, _ = _run(model, theta, inputs, _params({"torque_gain": TRUE["torque_gain"]}))
    np.testing.assert_allclose(np.asarray(got), np.asarray(want), rtol=1e-10, atol=1e-10)


def test_signal_delay_shifts_the_responses(setup):
    model, theta = setup
    inputs = _inputs()
    d = TRUE["signal_delay"]["delay"]
    base, _ = _run(make_model(VEHICLE), theta, inputs, ())
    got, _ = _run(model, theta, inputs, _params({"signal_delay": {"delay": d}}))
    k = int(round(d * RATE))
    for ch in ("ay", "yaw_rate", "ax"):
        b, g = np.asarray(base)[:, I[ch]], np.asarray(got)[:, I[ch]]
        err = np.abs(g[k + 100 :] - b[100:-k]).max()  # after the start transient
        assert err < 0.02 * np.abs(b).max(), ch
        assert np.abs(g - b).max() > 5 * err, ch  # and the shift is not nothing


def test_signal_delay_is_continuous_down_to_zero(setup):
    """Below the Padé floor a delay still shifts the responses by about d, and d → 0 is the base
    model: a fit can reach a car without latency."""
    model, theta = setup
    inputs = _inputs()
    base, _ = _run(make_model(VEHICLE), theta, inputs, ())
    base = np.asarray(base)
    t = np.arange(base.shape[0]) / RATE
    tiny, _ = _run(model, theta, inputs, _params({"signal_delay": {"delay": 1e-7}}))
    np.testing.assert_allclose(np.asarray(tiny), base, rtol=0, atol=1e-6 * np.abs(base).max())
    d = 0.004
    got, _ = _run(model, theta, inputs, _params({"signal_delay": {"delay": d}}))
    for ch in ("ay", "yaw_rate"):
        b, g = base[:, I[ch]], np.asarray(got)[:, I[ch]]
        shifted = np.interp(t - d, t, b)
        err = np.abs(g - shifted)[100:].max()
        assert err < 0.2 * np.abs(g - b)[100:].max(), ch


def test_sensor_scale_scales_only_the_imu(setup):
    model, theta = setup
    inputs = _inputs()
    base, _ = _run(make_model(VEHICLE), theta, inputs, ())
    got, _ = _run(model, theta, inputs, _params({"sensor_scale": TRUE["sensor_scale"]}))
    base, got = np.asarray(base), np.asarray(got)
    for ch, e in TRUE["sensor_scale"].items():
        np.testing.assert_allclose(got[:, I[ch]], (1 + e) * base[:, I[ch]], rtol=1e-12, atol=1e-12)
    for ch in ("omega_front", "omega_rear", "vx"):
        np.testing.assert_allclose(got[:, I[ch]], base[:, I[ch]], rtol=1e-12)


@pytest.mark.parametrize("name", NAMES)
def test_parameters_recovered_from_a_noise_free_recording(setup, name):
    """θ known; the effect's parameters fitted by the project's LM from the effect's start."""
    model, theta = setup
    inputs = _inputs(steer_amp=0.12 if name == "tyre_friction" else 0.04)
    truth, ok = _run(model, theta, inputs, _params({name: TRUE[name]}))
    assert ok
    from vdsbi.simulator.effects import EFFECTS

    start = jnp.asarray(EFFECTS[name].start, dtype=float)
    scale = jnp.asarray([1.0, 1.0, 0.01, 1.0, 1.0, 1.0])  # yaw rate in hundredths

    null = _params({})
    k = NAMES.index(name)

    def residual(p):
        params = null[:k] + (p,) + null[k + 1 :]
        return ((_run(model, theta, inputs, params)[0] - truth) / scale).reshape(-1)

    sol = levenberg_marquardt(residual, start, max_steps=40, rtol=1e-14)
    want = np.array(list(TRUE[name].values()))
    np.testing.assert_allclose(np.asarray(sol.z), want, rtol=1e-3, atol=1e-5)
