"""Accuracy and physics of the base model: reference agreement, convergence order, the default
float32 path against the sensor noise, steady cornering, mirror symmetry."""

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import pytest

from vdsbi.simulator import (
    CHANNELS,
    GRAVITY,
    NOMINAL_THETA,
    PARAM_NAMES,
    SEED_TRUE_THETA,
    Inputs,
    default_vehicle,
    make_model,
    seed_profile,
    solve,
)
from vdsbi.simulator._profiles import constant_profile
from vdsbi.simulator.measurement import SEED_RELATIVE_NOISE
from vdsbi.simulator.solvers import RK4, Solver

VEHICLE = default_vehicle()
MODEL = make_model(VEHICLE)
V0 = 10.5
#: Every float64 run lasts 5 s at 200 Hz, so runs with the same solver share one compilation.
DURATION = 5.0
REFERENCE = Solver(dt=None, rtol=1e-11, atol=1e-11)
#: Fine fixed step of the float64 comparison: 16 RK4 steps per 200 Hz sample.
FINE_DT = 0.0003125


def theta_of(d):
    return jnp.array([d[n] for n in PARAM_NAMES])


@eqx.filter_jit
def _solve(theta, inputs, v0, solver):
    return solve(MODEL, theta, inputs, v0, (), solver)


def run(theta, inputs, solver=Solver(), v0=V0):
    ys, ok = _solve(theta, inputs, jnp.asarray(v0, dtype=theta.dtype), solver)
    assert bool(ok)
    return np.asarray(ys)


def smooth_profile(duration=DURATION, rate=200.0):
    """Inputs without kinks (drive torque only, no slip sign changes): for convergence order."""
    t = np.arange(int(round(duration * rate)) + 1) / rate
    steer = 0.03 * np.sin(2 * np.pi * t / 2.0)
    tf = 300.0 + 200.0 * np.sin(2 * np.pi * t / 1.5)
    return Inputs(0.0, 1.0 / rate, steer, tf, np.zeros_like(t))


@pytest.fixture(scope="module")
def seed_runs():
    """float64 adaptive reference and fine fixed step; float32 default step (seed maneuver)."""
    with jax.enable_x64(True):
        inputs = seed_profile()
        theta = theta_of(SEED_TRUE_THETA)
        ref = run(theta, inputs, REFERENCE)
        fine = run(theta, inputs, Solver(dt=FINE_DT))
    default = run(theta_of(SEED_TRUE_THETA).astype(jnp.float32), seed_profile())
    return ref, fine, default


def test_float64_fixed_step_matches_adaptive_reference(seed_runs):
    ref, fine, _ = seed_runs
    rel = np.abs(fine - ref).max(0) / np.abs(ref).max(0)
    assert np.all(rel < 1e-6), dict(zip(CHANNELS, rel))


@pytest.mark.parametrize("unroll", [False, True])
def test_rk4_is_fourth_order(x64, unroll):
    inputs = smooth_profile()
    theta = theta_of(SEED_TRUE_THETA)
    ref = run(theta, inputs, REFERENCE)
    solvers = [RK4(dt, unroll=unroll) for dt in (0.005, 0.0025, 0.00125)]
    errs = [np.abs(run(theta, inputs, solver) - ref).max(0) for solver in solvers]
    for coarse, fine in zip(errs, errs[1:]):
        ratio = coarse / fine
        # Halving h divides a 4th-order global error by 2^4 = 16.
        assert np.all((ratio > 13) & (ratio < 19)), dict(zip(CHANNELS, ratio))


@pytest.mark.parametrize("dt", [0.005, 0.0025])
def test_rk4_layouts_agree(x64, dt):
    """The stage loop and the written-out stages are one method: the same steps to rounding."""
    inputs, theta = seed_profile(), theta_of(SEED_TRUE_THETA)
    rolled, unrolled = (run(theta, inputs, RK4(dt, unroll=u)) for u in (False, True))
    np.testing.assert_allclose(rolled, unrolled, rtol=1e-12, atol=1e-12 * np.abs(unrolled).max())
    assert RK4(dt).batched() == RK4(dt, unroll=True)


def test_default_float32_within_tenth_of_sensor_noise(seed_runs):
    ref, _, default = seed_runs
    assert default.dtype == np.float32
    rms = np.sqrt((ref**2).mean(0))
    noise_std = np.array([SEED_RELATIVE_NOISE[c] for c in CHANNELS]) * rms
    err = np.abs(default - ref).max(0)
    assert np.all(err < 0.1 * noise_std), dict(zip(CHANNELS, err / noise_std))


def understeer_gradient(theta):
    l_f, _, _, _, caf, car = (float(x) for x in theta)
    L, m = VEHICLE.wheelbase, VEHICLE.mass
    l_r = L - l_f
    return m * (l_r * car - l_f * caf) / (L * caf * car)


@pytest.mark.parametrize(
    "theta_dict,speed", [(NOMINAL_THETA, 20.0), (SEED_TRUE_THETA, 15.0)], ids=["understeer", "oversteer"]
)
def test_steady_cornering_yaw_rate(x64, theta_dict, speed):
    theta = theta_of(theta_dict)
    delta = 0.004  # rad: a ≈ 0.7–1.6 m/s² turn, well inside the tires' linear range
    # No torque: the only drag is F_yf·sin δ, so speed falls < 0.1 % over the run; the formula
    # is checked against the instantaneous Vx (the vx channel).
    ys = run(theta, constant_profile(DURATION, steer=delta), Solver(dt=0.005), v0=speed)
    last = ys[-100:]  # the final 0.5 s, after the yaw transient
    vx, r = last[:, 5], last[:, 2]
    K = understeer_gradient(theta)
    expected = vx * delta / (VEHICLE.wheelbase + K * vx**2)
    assert abs(K * speed**2) > 0.3  # the understeer term matters at this speed
    np.testing.assert_allclose(r, expected, rtol=0.02)
    # and the turn is steady: yaw rate settled, lateral acceleration = V·r
    assert np.ptp(r) < 1e-3 * abs(r.mean())
    np.testing.assert_allclose(last[:, 1], vx * r, rtol=0.01)


def test_mirror_symmetry_and_zero_steer(x64):
    theta = theta_of(SEED_TRUE_THETA)
    inputs = seed_profile(DURATION)
    left = run(theta, inputs, Solver(dt=0.005))
    mirrored = Inputs(inputs.t0, inputs.dt, -inputs.steer, inputs.torque_front, inputs.torque_rear)
    right = run(theta, mirrored, Solver(dt=0.005))
    i = {c: k for k, c in enumerate(CHANNELS)}
    assert np.abs(left[:, i["ay"]]).max() > 1.0  # a real manoeuvre
    for c in ("ay", "yaw_rate"):
        np.testing.assert_allclose(right[:, i[c]], -left[:, i[c]], rtol=1e-12, atol=1e-14)
    for c in ("ax", "omega_front", "omega_rear", "vx"):
        np.testing.assert_allclose(right[:, i[c]], left[:, i[c]], rtol=1e-12, atol=1e-14)
    straight = Inputs(inputs.t0, inputs.dt, 0 * inputs.steer, inputs.torque_front, inputs.torque_rear)
    ys = run(theta, straight, Solver(dt=0.005))
    assert np.all(ys[:, i["ay"]] == 0) and np.all(ys[:, i["yaw_rate"]] == 0)
    assert np.abs(ys[:, i["ax"]]).max() > 0.5 * GRAVITY * 0.1  # while ax is driven
