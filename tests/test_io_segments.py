"""Usable-segment selection and sensor-noise estimation."""

from pathlib import Path

import numpy as np
import pytest

from vdsbi.io import SegmentRules, build_recording, estimate_noise_std, find_segments, read_recording
from vdsbi.io._segments import usable_segments

REAL = Path(__file__).resolve().parents[2] / "shared" / "real"  # beside the checkout, where present


def drive(noise: float = 0.0, seed: int = 0):
    """0–5 s at rest, 5–25 s at 10 m/s with steering, 25–40 s steady cruise."""
    rate = 200.0
    t = np.arange(int(40 * rate) + 1) / rate
    vx = np.where(t < 5, 0.0, 10.0)
    steer = np.where((t >= 5) & (t < 25), 0.03 * np.sin(2 * t), 0.0)
    rng = np.random.default_rng(seed)
    ay = vx * 10.0 * steer / 2.7 + noise * rng.standard_normal(t.shape)
    cols = {"t": t, "steer": steer, "torque_front": np.full_like(t, 200.0), "torque_rear": 0 * t}
    cols.update(ay=ay, vx=vx)
    return build_recording(cols, "synthetic")


def test_segments_cover_the_drive_with_reasons():
    segs = find_segments(drive())
    assert segs[0].t0 == 0.0 and segs[-1].t1 == 40.0
    for a, b in zip(segs, segs[1:]):
        assert b.t0 == pytest.approx(a.t1 + 0.005)
    usable = [(s.t0, s.t1) for s in segs if s.usable]
    assert len(usable) == 1
    t0, t1 = usable[0]
    assert 5.0 <= t0 < 5.6 and 24.0 < t1 <= 26.0
    reasons = [s.reason for s in segs if not s.usable]
    # Rest is too slow; the steady cruise is straight (ay 0 while the torque is constant).
    assert any("speed below 5" in r for r in reasons) and any(
        r.startswith("straight: |ay| rms 0.0") for r in reasons
    )


def test_segments_split_and_min_duration():
    whole = usable_segments(drive())
    pieces = usable_segments(drive(), rules=SegmentRules(max_duration=5.0))
    span = whole[0][1] - whole[0][0]
    assert len(pieces) == int(np.ceil(span / 5.0)) > 1
    assert pieces[0][0] == whole[0][0] and pieces[-1][1] == pytest.approx(whole[0][1])
    assert all(b - a <= 5.0 for a, b in pieces)
    assert usable_segments(drive(), min_duration=30.0) == []


@pytest.mark.parametrize("sigma", [0.05, 0.5])
def test_noise_std_recovers_white_noise(sigma):
    rec = drive(noise=sigma)
    est = estimate_noise_std(rec, segments=usable_segments(rec))
    assert est["ay"] == pytest.approx(sigma, rel=0.1)
    assert est["vx"] < 1e-9


@pytest.mark.parametrize(
    "name, min_usable",
    [("vw_gti_low_speed", 20.0), ("vw_gti_high_speed_2", 80.0)],
)
def test_real_recordings_segments_and_noise(name, min_usable):
    if not (REAL / name).exists():
        pytest.skip("real recordings not available")
    rec = read_recording(REAL / name / "recording.csv")
    segs = usable_segments(rec)
    assert sum(b - a for a, b in segs) > min_usable
    assert all(rec.channels["vx"][(rec.t >= a) & (rec.t <= b)].mean() > 5.0 for a, b in segs)
    noise = estimate_noise_std(rec, segments=segs)
    assert noise["ay"] > 1.0  # an IMU carries several m/s² of vibration
    assert noise["yaw_rate"] < 0.05 and noise["vx"] < 0.05
