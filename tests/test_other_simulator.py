"""The other simulator's race car (experiments/other_simulator.py): its magic-formula tyres have
the cornering stiffness they are given, so in small slip angles it is the linear car, and at
large ones it saturates below the linear car's force."""

import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "experiments"))

import linear_baseline  # noqa: E402
import other_simulator  # noqa: E402

CAR = linear_baseline.Car(850.0, 1.25, 1.8, 1100.0)
T = np.arange(0.0, 6.0, 0.002)
VX = np.full(T.size, 20.0)


def _steer(amplitude):
    return amplitude * np.sin(2 * np.pi * 0.4 * T) * np.clip(T, 0, 1)


def test_small_slip_is_the_linear_car():
    r, ay = other_simulator.magic_formula_drive(CAR, 110e3, 150e3, T, VX, _steer(0.002))
    r_lin, ay_lin = linear_baseline.simulate(CAR, 110e3, 150e3, T, VX, _steer(0.002), 0.0)
    assert np.abs(ay - ay_lin).max() < 0.01 * np.abs(ay_lin).max()
    assert np.abs(r - r_lin).max() < 0.01 * np.abs(r_lin).max()


def test_large_slip_saturates_near_the_grip():
    _, ay = other_simulator.magic_formula_drive(CAR, 110e3, 150e3, T, VX, _steer(0.2))
    _, ay_lin = linear_baseline.simulate(CAR, 110e3, 150e3, T, VX, _steer(0.2), 0.0)
    peak = np.abs(ay).max()
    assert peak < 0.8 * np.abs(ay_lin).max()
    assert 1.2 * 9.81 < peak <= other_simulator.MAGIC["mu"] * 9.81 * 1.001


def test_first_order_lag_is_exact_on_a_ramp():
    # τ·δ̇ = t − δ from δ(0) = 0: δ = t − τ·(1 − exp(−t/τ)); the input is linear between samples.
    t = np.arange(0.0, 2.0, 0.01)
    delta = other_simulator.first_order_lag(t, t.copy(), 0.2)
    assert np.allclose(delta, t - 0.2 * (1 - np.exp(-t / 0.2)), atol=1e-12)


def test_first_order_lag_drive_names_the_steering_lag(tmp_path):
    c = other_simulator.CASES["linear car @ 25 Hz, 0.2 s lag"]
    truth = other_simulator.write_drive(
        tmp_path, 25.0, 0.2, c.car, c.cf, c.cr, c.seed, 8.0, lag_kind="first_order"
    )
    assert truth["steering_lag.tau"] == 0.2 and "signal_delay.delay" not in truth
    delayed = other_simulator.write_drive(tmp_path / "delay", 25.0, 0.2, c.car, c.cf, c.cr, c.seed, 8.0)
    assert delayed["signal_delay.delay"] == 0.2


def test_downforce_loads_the_axles_with_speed_squared():
    aero = other_simulator.Aero(coef=0.9, balance_front=0.42)
    weight = CAR.mass * 9.81
    static = other_simulator.axle_loads(CAR, 0.0)
    at_50 = other_simulator.axle_loads(CAR, 50.0, aero=aero)
    at_25 = other_simulator.axle_loads(CAR, 25.0, aero=aero)
    added = [a - s for a, s in zip(at_50, static)]
    assert np.isclose(sum(added), 0.9 * weight) and np.isclose(added[0], 0.42 * 0.9 * weight)
    assert np.isclose(sum(at_25) - weight, 0.25 * 0.9 * weight)


def test_downforce_raises_the_grip_at_speed():
    t, aero = T[:1500], other_simulator.Aero(coef=0.9, balance_front=0.42)
    vx, steer = np.full(t.size, 40.0), 0.1 * np.clip(t, 0, 1)
    _, plain = other_simulator.magic_formula_drive(CAR, 110e3, 150e3, t, vx, steer, mu=1.25)
    _, loaded = other_simulator.magic_formula_drive(CAR, 110e3, 150e3, t, vx, steer, mu=1.25, aero=aero)
    limit = 1.25 * 9.81 * (1 + 0.9 * (40.0 / 50.0) ** 2)
    assert np.abs(plain).max() <= 1.25 * 9.81 * 1.001
    assert 1.15 * np.abs(plain).max() < np.abs(loaded).max() <= limit * 1.001


def test_magic_formula_slip_inverts_the_tyre():
    load, force = 3000.0, np.linspace(-3500.0, 3500.0, 15)
    alpha = other_simulator.magic_formula_slip(force, 110e3, load, 1.25)
    assert np.allclose(other_simulator.magic_formula_force(alpha, 110e3, load, 1.25), force, rtol=1e-9)


def test_the_downforce_lap_corners_harder_after_the_fit_part():
    cut = 0.7 * other_simulator.LAP_SECONDS
    fit = [abs(g) for t0, t1, g, _ in other_simulator.LAP_CORNERS if t1 <= cut]
    held = [abs(g) for t0, t1, g, _ in other_simulator.LAP_CORNERS if t0 >= cut]
    assert fit and held and max(fit) <= 1.2 < 1.4 < max(held)
