"""A fleet drive that logs wheel torques is read following its measured speed (the platform's
estimator does); one without a measured speed is read torque-driven (and goes to identify)."""

from pathlib import Path

import numpy as np
import pandas as pd
import pytest

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


def test_an_escalated_torque_drive_is_identified_as_the_fleet_read_it(tmp_path, monkeypatch):
    # A drive whose logged torques are commanded, not applied, may not move the model as the car
    # moved: identify must follow the measured speed, as the drive's amortized answer did.
    from vdsbi import api
    from vdsbi.fleet._drive import Escalation, _identify
    from vdsbi.fleet._manifest import Drive

    seen = {}

    def fake_identify(recording, vehicle, options, **kw):
        seen["longitudinal"] = options.drive.longitudinal
        raise RuntimeError("stop here")

    monkeypatch.setattr(api, "identify", fake_identify)
    drive = Drive("car", "r", GOOD / "recording.csv", GOOD / "vehicle.json", "0", 0.0, 2)
    with pytest.raises(RuntimeError, match="stop here"):
        _identify(drive, None, tmp_path, Escalation(), "check failed", {}, None)
    assert seen["longitudinal"] == "speed"
