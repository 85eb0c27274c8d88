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


def test_every_window_the_cut_makes_fits_its_longest_window(tmp_path):
    # the cut moves window edges to quiet moments, past the nominal `max_window`: the fleet pads
    # every window to `longest_window`, so none may exceed it
    from vdsbi.fleet._manifest import read_manifest
    from vdsbi.fleet._simulated import simulated_fleet
    from vdsbi.io import load_drive
    from vdsbi.problem import ProblemSettings, make_problem

    (drive, *_) = read_manifest(simulated_fleet(tmp_path, cars=1, drives=1, duration=40.0, changes=()))
    rec, veh = load_drive(drive.recording, drive.vehicle)
    beyond, ratios = 0, []
    for max_window in (2.0, 3.0, 5.0):
        settings = ProblemSettings(max_window=max_window, held_out=0.0, longitudinal="speed")
        lengths = [w.t1 - w.t0 for w in make_problem(rec, veh, settings).windows]
        beyond += sum(x > max_window + 1e-9 for x in lengths)
        ratios += [x / settings.longest_window for x in lengths]
    assert beyond > 0  # the property is exercised
    assert max(ratios) <= 1.0 + 1e-9
