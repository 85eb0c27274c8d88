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
