"""The signs of steer, ay and yaw_rate checked against each other when a recording is read (the
one the other two outvote is named), and the steer's scale against the yaw rate with the
vehicle's wheelbase (`steer_response`, `check_against_vehicle`): a steering-wheel angle is warned
about; a consistent steer (lagged or not) and a straight drive pass silently."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from vdsbi.io import InputError, build_recording, read_vehicle
from vdsbi.io._consistency import steer_response
from vdsbi.io._drive import check_against_vehicle

GOOD = Path(__file__).parent / "data" / "good"
L = 2.7


def drive(
    steer_gain: float = 1.0,
    lag: float = 0.0,
    amplitude: float = 0.03,
    rate: float = 100.0,
    flip: tuple[str, ...] = (),
):
    """20 s at about 15 m/s whose yaw rate is 0.7·v·δ/L (an understeering car), `lag` s after
    the steer; the steer column is `steer_gain` × the road-wheel angle; the columns `flip`
    have their sign reversed."""
    t = np.arange(int(20 * rate) + 1) / rate
    vx = 15.0 + np.sin(0.3 * t)
    delta = lambda s: amplitude * np.sin(1.3 * s) + 0.5 * amplitude * np.sin(0.4 * s + 1.0)
    r = 0.7 * vx * delta(t - lag) / L
    rng = np.random.default_rng(0)
    cols = {
        "t": t,
        "steer": steer_gain * delta(t),
        "ax": np.gradient(vx, t) + 0.05 * rng.standard_normal(t.size),
        "ay": vx * r + 0.05 * rng.standard_normal(t.size),
        "yaw_rate": r + 0.003 * rng.standard_normal(t.size),
        "vx": vx,
    }
    return build_recording({k: -x if k in flip else x for k, x in cols.items()}, "drive.csv")


@pytest.mark.parametrize("lag", [0.0, 0.2])
def test_response_gain_and_lag_are_recovered(lag):
    gain, corr, found = steer_response(drive(lag=lag), L, drive(lag=lag).channels["vx"])
    assert gain == pytest.approx(0.7, rel=0.1)
    assert corr > 0.95
    assert found == pytest.approx(lag, abs=0.03)


def test_a_consistent_drive_passes_silently():
    rec = drive(lag=0.2)
    check_against_vehicle(rec, read_vehicle(GOOD / "vehicle.json"))
    assert not any("steer" in w for w in rec.warnings)


@pytest.mark.parametrize("column", ["steer", "ay", "yaw_rate"])
def test_a_reversed_sign_is_refused_naming_its_column(column):
    with pytest.raises(InputError, match=rf"drive.csv: {column}: .*negate {column}"):
        drive(flip=(column,))


def test_a_steering_wheel_angle_is_warned_about():
    rec = drive(steer_gain=15.0)
    check_against_vehicle(rec, read_vehicle(GOOD / "vehicle.json"))
    assert any("steering-wheel angle" in w for w in rec.warnings), rec.warnings


def test_a_straight_drive_says_nothing():
    """No steering to speak of: the yaw rate is noise, the correlation low, the sign untold."""
    rec = drive(amplitude=1e-5, flip=("steer",))
    check_against_vehicle(rec, read_vehicle(GOOD / "vehicle.json"))
    assert not any("steer" in w for w in rec.warnings)


def test_counter_steering_for_part_of_a_drive_is_not_a_reversed_sign():
    """A drive counter-steered for most of it (the yaw rate against the steer, as in a long
    drift) correlates negatively but loosely: read without an error."""
    rec = drive()
    t = rec.t
    steer = np.where(t < 0.77 * t[-1], -1.0, 1.0) * rec.steer
    cols = {"t": t, "steer": steer, **rec.channels}
    again = build_recording(cols, "drift.csv")
    gain, corr, _ = steer_response(again, L, again.channels["vx"])
    assert gain < 0 and -0.8 < corr < -0.6  # negative, but looser than a reversed sign gives
