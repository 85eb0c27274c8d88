"""A fleet drive that logs wheel torques is read following its measured speed (the platform's
estimator does); one without a measured speed is read torque-driven (and goes to identify)."""

from pathlib import Path

import numpy as np
import pandas as pd

from vdsbi.fleet._platform import drive_problem

GOOD = Path(__file__).parent / "data" / "good"


def test_a_torque_drive_with_a_measured_speed_is_answered_following_it(tmp_path):
    problem = drive_problem(GOOD / "recording.csv", GOOD / "vehicle.json")
    assert problem.longitudinal == "speed"
    assert not problem.held.any()  # all of it fitted


def test_a_torque_drive_without_a_measured_speed_is_read_torque_driven(tmp_path):
    # a steady turn at 10 m/s: its speed is estimated from ay ≈ vx·r, but nothing measures it
    t = np.arange(0.0, 12.0, 0.01)
    r = np.full_like(t, 0.11)
    cols = {"t": t, "steer": np.full_like(t, 0.03), "torque_front": np.full_like(t, 60.0)}
    cols |= {"torque_rear": np.zeros_like(t), "ax": np.zeros_like(t), "ay": 10.0 * r, "yaw_rate": r}
    pd.DataFrame(cols).to_csv(tmp_path / "no_speed.csv", index=False)
    assert drive_problem(tmp_path / "no_speed.csv", GOOD / "vehicle.json").longitudinal == "torque"
