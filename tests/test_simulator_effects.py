"""Physics effects: each moves the channels its physics says, leaves the others alone, and at its
null parameters reproduces the base model exactly; a new effect plugs in with one line.

All effect runs use one model with all ten effects enabled (so one compilation), switching an
effect on by giving it non-null parameters."""

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import pytest

from vdsbi.simulator import (
    CHANNELS,
    GRAVITY,
    PARAM_NAMES,
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
from vdsbi.simulator.effects import (
    EFFECTS,
    AbstractEffect,
    EffectSettings,
    Param,
    effect_params_from,
    register_effect,
)
from vdsbi.simulator.solvers import Solver

VEHICLE = default_vehicle()
NAMES = (*tuple(EFFECTS)[:10], "steer_offset")  # (a test below may register more)
SOLVER = Solver(dt=0.005)
V0 = 12.0
RATE = 200.0
I = {c: k for k, c in enumerate(CHANNELS)}

ACTIVE = {
    "aero_drag": {"CdA": 0.7},
    "rolling_resistance": {"c_rr": 0.015},
    "road_grade": {"grade": 0.04},
    "road_bank": {"bank": 0.04},
    "steer_offset": {"offset": 0.004},
    "steering_lag": {"tau": 0.1},
    "torque_lag": {"tau": 0.2},
    "imu_lever_arm": {"dx": 0.6, "dy": 0.25},
    "imu_misalignment": {"roll": 0.03, "yaw": 0.02},
    "sensor_bias": {"ax": 0.2, "ay": -0.15, "yaw_rate": 0.01},
    "wheel_radius_error": {"rel_error": 0.03},
}


def test_built_in_effects_carry_consistent_metadata():
    assert set(NAMES) == set(ACTIVE)
    for cls in EFFECTS.values():
        n = len(cls.param_names)
        assert len(cls.units) == len(cls.null) == len(cls.typical) == n and cls.description
        # discovery's fit box contains the typical range, and the start lies inside it
        assert len(cls.bounds) == len(cls.start) == n
        for (lo, hi), (a, b), x0 in zip(cls.bounds, cls.typical, cls.start):
            assert lo <= a <= b <= hi and lo < x0 < hi


@eqx.filter_jit
def _solve(model, theta, inputs, params):
    return solve(model, theta, inputs, jnp.asarray(V0, theta.dtype), params, SOLVER)


def smooth_profile(duration=5.0):
    """Smooth steer and drive torque: lags of these have closed forms."""
    t = np.arange(int(round(duration * RATE)) + 1) / RATE
    return Inputs(0.0, 1 / RATE, STEER_A * np.sin(W_S * t), TQ_0 + TQ_A * np.sin(W_T * t), 0 * t)


STEER_A, W_S = 0.03, 2 * np.pi / 2.0
TQ_0, TQ_A, W_T = 300.0, 200.0, 2 * np.pi / 1.5


def lagged_sine(amplitude, w, tau, t):
    """First-order lag (time constant tau) of amplitude·sin(w·t), started at rest at t = 0."""
    wt = w * tau
    return amplitude / (1 + wt**2) * (np.sin(w * t) - wt * np.cos(w * t) + wt * np.exp(-t / tau))


@pytest.fixture(scope="module")
def runs():
    """{(effect or 'base', maneuver): readings (T, 6)} in float64."""
    with jax.enable_x64(True):
        theta = jnp.array([SEED_TRUE_THETA[n] for n in PARAM_NAMES])
        seed = seed_profile()
        maneuvers = {
            "seed": seed,
            "straight": Inputs(seed.t0, seed.dt, 0 * seed.steer, seed.torque_front, seed.torque_rear),
            "smooth": smooth_profile(),
        }
        t = np.asarray(maneuvers["smooth"].ts)
        tau_s, tau_t = ACTIVE["steering_lag"]["tau"], ACTIVE["torque_lag"]["tau"]
        s = maneuvers["smooth"]
        maneuvers["smooth_steer_lagged"] = Inputs(
            0.0, s.dt, lagged_sine(STEER_A, W_S, tau_s, t), s.torque_front, s.torque_rear
        )
        maneuvers["smooth_torque_lagged"] = Inputs(
            0.0, s.dt, s.steer, TQ_0 + lagged_sine(TQ_A, W_T, tau_t, t), s.torque_rear
        )
        offset = ACTIVE["steer_offset"]["offset"]
        maneuvers["smooth_steer_offset"] = Inputs(0.0, s.dt, s.steer + offset, s.torque_front, s.torque_rear)
        all_model = make_model(VEHICLE, NAMES)
        _, null = effect_params_from(NAMES)
        out = {}
        for m_name, inputs in maneuvers.items():
            ys, ok = _solve(make_model(VEHICLE), theta, inputs, ())
            assert bool(ok)
            out["base", m_name] = np.asarray(ys)
            ys, ok = _solve(all_model, theta, inputs, null)
            assert bool(ok)
            out["null", m_name] = np.asarray(ys)
            if m_name.startswith("smooth_"):
                continue
            for name in NAMES:
                _, params = effect_params_from(NAMES, {name: ACTIVE[name]})
                ys, ok = _solve(all_model, theta, inputs, params)
                assert bool(ok), name
                out[name, m_name] = np.asarray(ys)
        return out


def test_null_parameters_reproduce_base_model(runs):
    for m in ("seed", "straight", "smooth"):
        np.testing.assert_allclose(runs["null", m], runs["base", m], rtol=1e-13, atol=1e-13)


def test_each_effect_changes_something(runs):
    for name in NAMES:
        for m in ("seed", "smooth"):
            assert np.abs(runs[name, m] - runs["base", m]).max() > 1e-3, (name, m)


def unchanged(runs, name, maneuver, channels, rtol=1e-12):
    for c in channels:
        np.testing.assert_allclose(
            runs[name, maneuver][:, I[c]], runs["base", maneuver][:, I[c]], rtol=rtol, atol=1e-12, err_msg=c
        )


def test_straight_line_effects_stay_longitudinal(runs):
    for name in ("aero_drag", "rolling_resistance", "road_grade", "torque_lag", "wheel_radius_error"):
        ys = runs[name, "straight"]
        assert np.all(ys[:, I["ay"]] == 0) and np.all(ys[:, I["yaw_rate"]] == 0), name


def specific_vs_kinematic(ys):
    """Mean of (d vx/dt − ax) over the run: the gravity share that the accelerometer misses."""
    dvx = np.gradient(ys[:, I["vx"]], 1 / RATE)
    return (dvx - ys[:, I["ax"]])[5:-5].mean()


def test_drag_and_rolling_resistance_are_felt_by_the_accelerometer(runs):
    base = runs["base", "straight"]
    ys = runs["aero_drag", "straight"]
    vx = ys[:, I["vx"]]
    drag = -0.5 * AIR_DENSITY * ACTIVE["aero_drag"]["CdA"] * vx * np.abs(vx) / VEHICLE.mass
    d_ax = ys[:, I["ax"]] - base[:, I["ax"]]
    # ax carries the drag (up to the wheels' inertia share, I_w/R² ≈ 1.3 % per axle)
    assert abs(d_ax.mean() - drag.mean()) < 0.05 * abs(drag.mean())
    assert abs(specific_vs_kinematic(ys)) < 1e-3  # and what ax reads is what moves the car
    ys = runs["rolling_resistance", "straight"]
    d_ax = ys[:, I["ax"]] - base[:, I["ax"]]
    expected = -ACTIVE["rolling_resistance"]["c_rr"] * GRAVITY
    assert abs(d_ax.mean() - expected) < 0.05 * abs(expected)
    assert abs(specific_vs_kinematic(ys)) < 1e-3


def test_road_grade_moves_the_car_but_not_the_accelerometer(runs):
    base, ys = runs["base", "straight"], runs["road_grade", "straight"]
    g_x = -GRAVITY * np.sin(ACTIVE["road_grade"]["grade"])
    assert abs(specific_vs_kinematic(base)) < 1e-3
    # ax − d(vx)/dt = g·sin(grade): the accelerometer misses the gravity share ...
    assert abs(specific_vs_kinematic(ys) - g_x) < 0.01 * abs(g_x)
    # ... and so does d(ω·R)/dt − ax with the wheel speeds (R_eff at static load; slip and load
    # transfer make it differ from vx sample by sample, but not the grade's mean shift)
    r_rear = VEHICLE.wheel_radius - VEHICLE.mass * GRAVITY * 1.5 / 2.7 / (3 * VEHICLE.tire_vertical_stiffness)
    shift = [
        (np.gradient(a[:, I["omega_rear"]] * r_rear, 1 / RATE) - a[:, I["ax"]])[5:-5].mean()
        for a in (base, ys)
    ]
    assert abs(shift[1] - shift[0] - g_x) < 0.05 * abs(g_x)
    # while ax itself changes little (wheel inertia only) and the car slows
    assert abs((ys[:, I["ax"]] - base[:, I["ax"]]).mean()) < 0.05 * abs(g_x)
    assert ys[-1, I["vx"]] < base[-1, I["vx"]] + 0.9 * g_x * 5.0


def test_road_bank_shows_as_lateral_tire_force(runs):
    base, ys = runs["base", "straight"], runs["road_bank", "straight"]
    g_y = GRAVITY * np.sin(ACTIVE["road_bank"]["bank"])
    ay = ys[:, I["ay"]]
    # The tires hold the car against the downhill pull: ay reads towards the high side.
    assert 0.5 * g_y < ay[-200:].mean() < 1.5 * g_y
    unchanged(runs, "road_bank", "straight", ["ax", "omega_front", "omega_rear", "vx"], rtol=2e-2)
    assert np.abs(base[:, I["ay"]]).max() == 0


def test_lags_equal_base_model_driven_by_lagged_inputs(runs):
    for name, lagged in (("steering_lag", "smooth_steer_lagged"), ("torque_lag", "smooth_torque_lagged")):
        ys, ref = runs[name, "smooth"], runs["base", lagged]
        err = np.abs(ys - ref).max(0) / np.abs(ref).max(0)
        assert np.all(err < 1e-3), (name, dict(zip(CHANNELS, err)))
        # and the lag is visible against the unlagged base
        assert np.abs(ys - runs["base", "smooth"]).max() > 30 * np.abs(ys - ref).max()


def test_steer_offset_is_the_base_model_steered_by_the_offset_more(runs):
    np.testing.assert_allclose(
        runs["steer_offset", "smooth"], runs["base", "smooth_steer_offset"], rtol=1e-12, atol=1e-12
    )
    # a straight drive turns
    assert np.abs(runs["steer_offset", "straight"][:, I["yaw_rate"]]).max() > 1e-3


def test_imu_lever_arm_adds_rigid_body_terms(runs):
    dx, dy = ACTIVE["imu_lever_arm"]["dx"], ACTIVE["imu_lever_arm"]["dy"]
    base, ys = runs["base", "seed"], runs["imu_lever_arm", "seed"]
    unchanged(runs, "imu_lever_arm", "seed", ["yaw_rate", "omega_front", "omega_rear", "vx"])
    r = base[:, I["yaw_rate"]]
    d_ay = ys[:, I["ay"]] - base[:, I["ay"]]
    d_ax = ys[:, I["ax"]] - base[:, I["ax"]]
    # centripetal part, exactly: dx·Δax + dy·Δay = −(dx² + dy²)·r²
    np.testing.assert_allclose(dx * d_ax + dy * d_ay, -(dx**2 + dy**2) * r**2, rtol=1e-9, atol=1e-12)
    # tangential part: Δay = dx·ṙ − dy·r² (ṙ by finite differences of the yaw rate)
    r_dot = np.gradient(r, 1 / RATE)
    scale = dx * np.abs(r_dot).max()
    assert np.abs(d_ay - (dx * r_dot - dy * r**2))[2:-2].max() < 0.05 * scale
    assert np.abs(d_ax - (-dy * r_dot - dx * r**2))[2:-2].max() < 0.05 * scale


def test_imu_misalignment_rotates_the_accelerometer(runs):
    roll, yaw = ACTIVE["imu_misalignment"]["roll"], ACTIVE["imu_misalignment"]["yaw"]
    base, ys = runs["base", "seed"], runs["imu_misalignment", "seed"]
    unchanged(runs, "imu_misalignment", "seed", ["yaw_rate", "omega_front", "omega_rear", "vx"])
    ax, ay = base[:, I["ax"]], base[:, I["ay"]]
    c, s = np.cos(yaw), np.sin(yaw)
    np.testing.assert_allclose(ys[:, I["ax"]], c * ax + s * ay, rtol=1e-12, atol=1e-12)
    expected_ay = np.cos(roll) * (-s * ax + c * ay) + GRAVITY * np.sin(roll)
    np.testing.assert_allclose(ys[:, I["ay"]], expected_ay, rtol=1e-12, atol=1e-12)


def test_sensor_bias_shifts_only_imu_channels(runs):
    bias = ACTIVE["sensor_bias"]
    base, ys = runs["base", "seed"], runs["sensor_bias", "seed"]
    for c in ("ax", "ay", "yaw_rate"):
        np.testing.assert_allclose(ys[:, I[c]] - base[:, I[c]], bias[c], rtol=1e-9)
    unchanged(runs, "sensor_bias", "seed", ["omega_front", "omega_rear", "vx"])


def test_imu_effects_leave_wheels_and_speed_alone(runs):
    for name in ("imu_lever_arm", "imu_misalignment", "sensor_bias"):
        for m in ("seed", "straight"):
            unchanged(runs, name, m, ["omega_front", "omega_rear", "vx"])


def test_wheel_radius_error_scales_wheel_speeds(runs):
    e = ACTIVE["wheel_radius_error"]["rel_error"]
    base, ys = runs["base", "smooth"], runs["wheel_radius_error", "smooth"]
    for c in ("omega_front", "omega_rear"):
        # per unit of forward speed (a larger wheel also changes the speed a torque gives)
        ratio = (ys[:, I[c]] / ys[:, I["vx"]]) / (base[:, I[c]] / base[:, I["vx"]])
        # 1/(1+e) up to R_eff's load deflection (R_f·e vs (R_f − F_z/3C_vert)·e: ≈ 6e-4) and
        # the drive slip, which changes with the force a torque gives on a larger wheel
        assert np.abs(ratio * (1 + e) - 1).max() < 5e-3, c
    # same torque on a larger wheel: less force, so the driven ax shrinks by about 1/(1+e) too
    big = np.abs(base[:, I["ax"]]) > 0.5
    ratio = np.median(ys[big, I["ax"]] / base[big, I["ax"]])
    np.testing.assert_allclose(ratio, 1 / (1 + e), rtol=0.01)


def test_a_new_effect_takes_one_class_and_one_line(x64):
    class TowForce(AbstractEffect):
        """A constant rearward pull on the body, e.g. a trailer (felt by the accelerometer)."""

        name = "test_tow_force"
        params = (Param("force", "N", null=0.0, typical=(0.0, 2000.0), bounds=(0.0, 5000.0), start=100.0),)
        description = "constant rearward pull"

        def body_force(self, p, ctx):
            return -p[0], jnp.zeros_like(p[0])

    try:
        register_effect(TowForce)  # the one line
        seed = seed_profile(2.0)
        straight = Inputs(seed.t0, seed.dt, 0 * seed.steer, seed.torque_front, seed.torque_rear)
        theta = np.array([SEED_TRUE_THETA[n] for n in PARAM_NAMES])
        base, _ = simulate(theta, straight, VEHICLE, v0=V0, solver=SOLVER)
        ys, ok = simulate(
            theta,
            straight,
            VEHICLE,
            v0=V0,
            effects=EffectSettings(enabled=["test_tow_force"], params={"test_tow_force": {"force": 450.0}}),
            solver=SOLVER,
        )
        assert ok
        d_ax = ys[:, I["ax"]] - base[:, I["ax"]]
        assert abs(d_ax.mean() + 450.0 / VEHICLE.mass) < 0.05 * 450.0 / VEHICLE.mass
        attrs = {a: getattr(TowForce, a) for a in ("name", "params")}
        clash = type("Clash", (AbstractEffect,), {**attrs, "description": "same name"})
        with pytest.raises(ValueError, match="already registered"):
            register_effect(clash)
        # the records are checked when the class is defined: a start on the edge of the fit box,
        # a typical range outside it, a repeated name
        force = TowForce.params[0]
        for bad, match in (
            (force._replace(start=0.0), "strictly inside"),
            (force._replace(typical=(0.0, 6000.0)), "typical range"),
        ):
            with pytest.raises(ValueError, match=match):
                type("Edge", (AbstractEffect,), {"name": "edge", "params": (bad,), "description": "x"})
        with pytest.raises(ValueError, match="repeat"):
            type("Twice", (AbstractEffect,), {"name": "twice", "params": (force, force), "description": "x"})
        # and the registry wants every attribute: no description
        partial = type("Partial", (AbstractEffect,), {**attrs, "name": "partial"})
        with pytest.raises(ValueError, match="description"):
            register_effect(partial)
        # the columns every consumer reads come from the records
        columns = (TowForce.param_names, TowForce.units, TowForce.bounds)
        assert columns == (("force",), ("N",), ((0.0, 5000.0),))
        assert "edge" not in EFFECTS and "partial" not in EFFECTS
    finally:
        EFFECTS.pop("test_tow_force", None)
    with pytest.raises(ValueError, match="test_tow_force"):
        make_model(VEHICLE, ["test_tow_force"])


def test_every_effect_runs_a_float64_fit_on_float32_inputs_without_casting_warnings():
    """A float64 likelihood fit drives inputs stored in float32: an effect that writes its float64
    parameters into them must say how (JAX warns of an unsafe cast, and means to make it an error)."""
    import warnings

    inputs = seed_profile(1.0, 100.0, maneuver=SeedManeuver(steer_amplitude=0.04), t0=0.2)
    inputs = jax.tree.map(lambda a: jnp.asarray(a, jnp.float32) if isinstance(a, jax.Array) else a, inputs)
    with jax.enable_x64(True), warnings.catch_warnings():
        warnings.simplefilter("error", FutureWarning)
        theta = jnp.asarray(theta_from_dict(SEED_TRUE_THETA), jnp.float64)
        for name, effect in EFFECTS.items():
            typical = {name: {p: float(hi) for p, (_, hi) in zip(effect.param_names, effect.typical)}}
            effects = EffectSettings(enabled=[name], params=typical)
            ys, ok = simulate(theta, inputs, default_vehicle(), v0=10.0, effects=effects)
            assert ok and np.isfinite(np.asarray(ys)).all(), name
