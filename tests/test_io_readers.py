"""Readers (CSV, Parquet, ROS2 bags in sqlite3 and MCAP) produce the same validated Recording."""

from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from vdsbi.io import InputError, build_recording, load_drive, read_recording, read_vehicle
from vdsbi.io._bag_writer import write_bag
from vdsbi.simulator import CHANNELS, Inputs

DATA = Path(__file__).parent / "data"
GOOD = DATA / "good"
REAL = Path(__file__).resolve().parents[2] / "shared" / "real"  # beside the checkout, where present


def smooth_frame(rate: float, duration: float = 3.0) -> pd.DataFrame:
    t = np.arange(int(round(duration * rate)) + 1) / rate
    vx = 10.0 + np.sin(np.pi * t)
    return pd.DataFrame(
        {
            "t": t,
            "steer": 0.03 * np.sin(2.0 * t),
            "torque_front": 400.0 + 300.0 * np.cos(np.pi * t),
            "torque_rear": np.zeros_like(t),
            "ax": np.pi * np.cos(np.pi * t),
            "vx": vx,
        }
    )


def test_csv_good_fixture():
    rec = read_recording(GOOD / "recording.csv")
    assert rec.rate == 200.0 and rec.original_rate == pytest.approx(200.0)
    assert rec.channel_names == CHANNELS  # extra column gnss_quality ignored
    assert rec.num_samples == 601 and rec.duration == pytest.approx(3.0)
    assert np.allclose(np.diff(rec.t), rec.dt)
    assert rec.warnings == []
    assert rec.measured(["vx", "ax"]).shape == (601, 2)
    inputs = rec.inputs()
    assert isinstance(inputs, Inputs) and inputs.dt == pytest.approx(0.005)
    assert np.allclose(np.asarray(inputs.steer), rec.steer)


@pytest.mark.parametrize("rate", [50.0, 100.0, 1000.0])
def test_other_uniform_rates_are_resampled(tmp_path, rate):
    path = tmp_path / "r.csv"
    smooth_frame(rate).to_csv(path, index=False, float_format="%.10g")
    rec = read_recording(path)
    assert rec.original_rate == pytest.approx(rate)
    assert rec.rate == 200.0 and np.allclose(np.diff(rec.t), 0.005)
    assert rec.channel_names == ("ax", "vx")  # absent channels are fine
    ref = smooth_frame(200.0)
    n = min(rec.num_samples, len(ref))
    # linear interpolation of a 0.5 Hz signal (and a box filter on downsampling) stays this close
    assert np.abs(rec.channels["vx"][:n] - ref.vx.to_numpy()[:n]).max() < 2e-3
    assert np.abs(rec.steer[:n] - ref.steer.to_numpy()[:n]).max() < 1e-4


def test_millisecond_timestamps_at_300_hz_pass(tmp_path):
    df = smooth_frame(300.0)
    df["t"] = df.t.round(3)  # written with ms precision: up to dt/6.7 off the grid
    path = tmp_path / "r.csv"
    df.to_csv(path, index=False)
    assert read_recording(path).original_rate == pytest.approx(300.0, rel=1e-3)


def test_irregular_tolerance_is_one_percent_or_half_ms(tmp_path):
    rng = np.random.default_rng(1)
    df = smooth_frame(100.0)
    ok = df.assign(t=df.t + rng.uniform(-0.03, 0.03, len(df)) * 0.01)  # 0.3 ms < 0.5 ms
    ok.to_csv(tmp_path / "ok.csv", index=False, float_format="%.10g")
    read_recording(tmp_path / "ok.csv")
    bad = df.assign(t=df.t + rng.uniform(-0.1, 0.1, len(df)) * 0.01)  # up to 1 ms
    bad.to_csv(tmp_path / "bad.csv", index=False, float_format="%.10g")
    with pytest.raises(InputError, match="bad.csv: t: irregular"):
        read_recording(tmp_path / "bad.csv")


def test_parquet_and_csv_round_trip(tmp_path):
    rec = read_recording(GOOD / "recording.csv")
    rec.to_parquet(tmp_path / "r.parquet")
    rec.to_csv(tmp_path / "r.csv")
    for p in ("r.parquet", "r.csv"):
        again = read_recording(tmp_path / p)
        assert again.channel_names == rec.channel_names
        for name in rec.channel_names:
            assert np.allclose(again.channels[name], rec.channels[name], rtol=1e-8, atol=1e-9)
        assert np.allclose(again.torque_front, rec.torque_front)


def test_slice():
    rec = read_recording(GOOD / "recording.csv")
    part = rec.slice(1.0, 2.0)
    assert part.num_samples == 201 and part.t[0] == pytest.approx(1.0)
    assert np.allclose(part.channels["ax"], rec.channels["ax"][200:401])
    part.channels["ax"][0] = 99.0
    assert rec.channels["ax"][200] != 99.0


def test_vehicle_json_and_yaml_agree():
    a, b = read_vehicle(GOOD / "vehicle.json"), read_vehicle(GOOD / "vehicle.yaml")
    assert a.to_dict() == b.to_dict()
    assert a.mass == 1500.0 and a.noise_std["ay"] == 0.05


@pytest.mark.parametrize("storage", ["sqlite3", "mcap"])
def test_bag_round_trip(tmp_path, storage):
    rec = read_recording(GOOD / "recording.csv", rate=100.0)
    bag = tmp_path / "bag"
    write_bag(rec, bag, storage=storage)
    for path in (bag, next(p for p in bag.iterdir() if p.suffix in (".db3", ".mcap"))):
        got = read_recording(path, rate=100.0)
        assert got.channel_names == CHANNELS
        assert got.num_samples == rec.num_samples
        for name in CHANNELS:  # Autoware reports are float32
            assert np.allclose(got.channels[name], rec.channels[name], rtol=1e-6, atol=1e-5)
        assert np.allclose(got.steer, rec.steer, atol=1e-7)
        assert np.allclose(got.torque_front, rec.torque_front)


def test_bag_topic_map_renames_scales_and_drops(tmp_path):
    rec = read_recording(GOOD / "recording.csv", rate=100.0)
    write_bag(rec, tmp_path / "bag", storage="mcap")
    (tmp_path / "map.yaml").write_text(
        "torque_rear: {topic: /vdsbi/torque_front, field: data, scale: 0.5}\n"
        "omega_rear: {topic: /vdsbi/wheel_speeds, field: 'data[0]'}\n"
        "vx: null\n"
    )
    got = read_recording(tmp_path / "bag", rate=100.0, topic_map=tmp_path / "map.yaml")
    assert "vx" not in got.channels
    assert np.allclose(got.torque_rear, 0.5 * rec.torque_front)
    assert np.allclose(got.channels["omega_rear"], rec.channels["omega_front"])


def test_bag_with_only_some_channels(tmp_path):
    rec = read_recording(GOOD / "recording.csv", rate=100.0)
    write_bag(rec, tmp_path / "bag", skip=("/vdsbi/wheel_speeds", "/vehicle/status/velocity_status"))
    got = read_recording(tmp_path / "bag", rate=100.0)
    assert got.channel_names == ("ax", "ay", "yaw_rate")


def test_constructor_validation_is_shared():
    cols = {c: v.to_numpy() for c, v in smooth_frame(200.0).items()}
    cols["steer"] = np.degrees(cols["steer"] * 30)
    with pytest.raises(InputError, match="^mem: steer: .*degrees"):
        build_recording(cols, "mem")


@pytest.mark.parametrize("name, rate", [("vw_gti_low_speed", 200.0), ("vw_gti_high_speed_2", 1000.0)])
def test_real_recordings_pass(name, rate):
    if not (REAL / name).exists():
        pytest.skip("real recordings not available")
    rec, vehicle = load_drive(REAL / name / "recording.csv", REAL / name / "vehicle.json")
    assert rec.original_rate == pytest.approx(rate)
    assert rec.channel_names == ("ax", "ay", "yaw_rate", "vx")
    assert vehicle.wheelbase == pytest.approx(2.631)
    # Both time bases are right now (high_speed_2 was re-converted at 1 kHz): no kinematics warning.
    assert rec.warnings == []


def test_stretched_time_base_is_flagged():
    # The earlier copy of vw_gti_high_speed_2 had its 1-kHz samples stamped at 5 ms: the
    # kinematics (d(vx)/dt against ax) must reveal that as a time-base warning naming ≈ 1 kHz.
    path = REAL / "vw_gti_high_speed_2" / "recording.csv"
    if not path.exists():
        pytest.skip("real recordings not available")
    frame = pd.read_csv(path)
    cols = {c: frame[c].to_numpy() for c in frame.columns}
    cols["t"] = cols["t"] * 5.0
    rec = build_recording(cols, "stretched")
    (warning,) = [w for w in rec.warnings if "time base" in w]
    rate = float(warning.split("true rate ")[1].split(" Hz")[0])
    assert rate == pytest.approx(1000.0, rel=0.05)
