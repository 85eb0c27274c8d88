"""Recordings without wheel torques: the contract's optional torque pair and the speed-driven inputs."""

from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from vdsbi.io import (
    InputError,
    build_recording,
    estimate_noise_std,
    find_segments,
    load_drive,
    read_recording,
)
from vdsbi.io._bag_writer import write_bag
from vdsbi.io._recording import speed_slope
from vdsbi.io._segments import usable_segments
from vdsbi.simulator import Inputs

DATA = Path(__file__).parent / "data"
GOOD = DATA / "good"
REAL = Path(__file__).resolve().parents[2] / "shared" / "real"  # beside the checkout, where present
R = 0.31  # wheel radius of the good fixture


def good(drop=("torque_front", "torque_rear")) -> pd.DataFrame:
    return pd.read_csv(GOOD / "recording.csv").drop(columns=list(drop))


def columns(df: pd.DataFrame) -> dict[str, np.ndarray]:
    return {c: df[c].to_numpy() for c in df.columns}


def test_csv_without_torques_reads_and_drives_by_speed(tmp_path):
    good().to_csv(tmp_path / "r.csv", index=False)
    rec = read_recording(tmp_path / "r.csv")
    assert not rec.has_torques and rec.torque_front is None and rec.torque_rear is None
    assert rec.warnings == []
    inputs = rec.inputs()  # default: speed mode, as there are no torques
    assert isinstance(inputs, Inputs)
    assert np.allclose(np.asarray(inputs.speed), rec.channels["vx"])
    assert np.allclose(np.asarray(inputs.accel), rec.channels["ax"])
    assert np.all(np.asarray(inputs.torque_front) == 0) and np.all(np.asarray(inputs.torque_rear) == 0)
    assert np.allclose(np.asarray(inputs.steer), rec.steer)
    assert float(inputs.t0) == rec.t[0] and inputs.dt == pytest.approx(rec.dt)
    assert rec.inputs(longitudinal="speed").speed.shape == (rec.num_samples,)
    with pytest.raises(InputError, match=r"r\.csv: torque_front: no torque columns.*longitudinal='speed'"):
        rec.inputs(longitudinal="torque")
    with pytest.raises(ValueError, match="longitudinal must be one of"):
        rec.inputs(longitudinal="torques")


def test_without_torques_slice_and_writers_keep_no_torques(tmp_path):
    rec = read_recording(GOOD / "recording.csv")
    bare = build_recording(columns(good()), "bare")
    part = bare.slice(1.0, 2.0)
    assert not part.has_torques and part.num_samples == 201
    assert list(bare.to_frame().columns) == ["t", "steer", *rec.channel_names]
    for name in ("r.csv", "r.parquet"):
        getattr(bare, "to_" + name.split(".")[1])(tmp_path / name)
        again = read_recording(tmp_path / name)
        assert not again.has_torques and again.channel_names == rec.channel_names
        assert np.allclose(again.channels["vx"], rec.channels["vx"])


def test_with_torques_default_is_torque_mode_and_speed_mode_is_available():
    rec = read_recording(GOOD / "recording.csv")
    assert rec.has_torques
    torque = rec.inputs()
    assert torque.speed is None and torque.accel is None
    assert np.allclose(np.asarray(torque.torque_front), rec.torque_front)
    speed = rec.inputs(longitudinal="speed")
    assert np.allclose(np.asarray(speed.torque_front), rec.torque_front)  # recorded torques kept
    assert np.allclose(np.asarray(speed.torque_rear), rec.torque_rear)
    assert np.allclose(np.asarray(speed.speed), rec.channels["vx"])
    assert np.allclose(np.asarray(speed.accel), rec.channels["ax"])


def test_speed_from_wheel_speeds_and_accel_from_its_slope():
    df = good(drop=("torque_front", "torque_rear", "vx", "ax"))
    rec = build_recording(columns(df), "wheels")
    inputs = rec.inputs(wheel_radius=R)
    wheels = 0.5 * (rec.channels["omega_front"] + rec.channels["omega_rear"]) * R
    assert np.allclose(np.asarray(inputs.speed), wheels)
    # The fixture's speed is mean(1.01, 1)·(10 + sin πt): the slope is 1.005·π cos πt.
    true = 1.005 * np.pi * np.cos(np.pi * rec.t)
    inner = slice(40, -40)  # 0.2 s from the ends
    assert np.abs(np.asarray(inputs.accel) - true)[inner].max() < 0.05  # of an amplitude of 3.2
    assert np.abs(np.asarray(inputs.accel) - true).max() < 0.2
    with pytest.raises(InputError, match="wheels: vx: no vx channel.*wheel_radius"):
        rec.inputs()


def test_speed_slope_smooths_quantised_speed():
    dt = 0.005
    t = np.arange(0, 4, dt)
    v = np.round(10 + 2 * np.sin(t), 2)  # speed logged in cm/s steps
    slope = speed_slope(v, dt)
    assert np.abs(slope - 2 * np.cos(t))[40:-40].max() < 0.1  # np.gradient: up to 2 m/s²
    assert speed_slope(v[:3], dt).shape == (3,)


@pytest.mark.parametrize("kept, missing", [("torque_front", "torque_rear"), ("torque_rear", "torque_front")])
def test_one_torque_without_the_other_names_the_missing_one(kept, missing):
    df = good(drop=(missing,))
    with pytest.raises(InputError, match=f"^mem: {missing}: missing column: {kept} is given") as err:
        build_recording(columns(df), "mem")
    assert "misspelled" not in str(err.value)  # the other torque is no misspelling of it


def test_misspelled_torque_keeps_its_hint():
    df = pd.read_csv(GOOD / "recording.csv").rename(columns={"torque_front": "torque_frnt"})
    with pytest.raises(InputError, match=r"^mem: torque_front: .*found 'torque_frnt': misspelled\?"):
        build_recording(columns(df), "mem")


def test_both_torques_misspelled_reads_without_them_and_warns():
    df = pd.read_csv(GOOD / "recording.csv").rename(
        columns={"torque_front": "torque_frnt", "torque_rear": "Torque_Rear"}
    )
    rec = build_recording(columns(df), "mem")
    assert not rec.has_torques
    (warning,) = rec.warnings
    assert "'torque_frnt' for 'torque_front'" in warning and "'Torque_Rear' for 'torque_rear'" in warning


def test_no_torques_and_no_speed_is_an_error():
    df = good(drop=("torque_front", "torque_rear", "vx", "omega_front", "omega_rear"))
    with pytest.raises(InputError, match="^drive.csv: vx: no torque columns") as err:
        build_recording(columns(df), "drive.csv")
    assert "longitudinal motion follows the measured speed" in str(err.value)
    assert "omega_front" in str(err.value)
    misspelled = columns(df.assign(v_x=1.0))
    with pytest.raises(InputError, match=r"'v_x' for 'vx': misspelled\?"):
        build_recording(misspelled, "drive.csv")
    # With torques the same channels suffice.
    build_recording(
        columns(pd.read_csv(GOOD / "recording.csv").drop(columns=["vx", "omega_front", "omega_rear"])), "x"
    )


def test_still_two_measured_channels_without_torques():
    df = good()[["t", "steer", "vx"]]
    with pytest.raises(InputError, match="^mem: measured channels: .*at least 2"):
        build_recording(columns(df), "mem")


def drive_frame(rate: float, duration: float = 10.0) -> pd.DataFrame:
    """A smooth torque-free drive (content up to 0.5 Hz), sampled at `rate`."""
    t = np.arange(int(round(duration * rate)) + 1) / rate
    vx = 15.0 + 2.0 * np.sin(0.5 * np.pi * t)
    r = 0.15 * np.sin(0.8 * t)
    return pd.DataFrame(
        {
            "t": t,
            "steer": 0.04 * np.sin(0.8 * t),
            "ax": np.pi * np.cos(0.5 * np.pi * t),
            "ay": vx * r,
            "yaw_rate": r,
            "vx": vx,
        }
    )


def test_25_hz_and_1_khz_read_to_the_same_200_hz_channels(tmp_path):
    recs = {}
    for rate in (25.0, 1000.0):
        drive_frame(rate).to_csv(tmp_path / f"r{rate:g}.csv", index=False, float_format="%.10g")
        recs[rate] = read_recording(tmp_path / f"r{rate:g}.csv")
    slow, fast = recs[25.0], recs[1000.0]
    assert slow.original_rate == pytest.approx(25.0) and fast.original_rate == pytest.approx(1000.0)
    assert slow.rate == fast.rate == 200.0
    assert not slow.has_torques and not fast.has_torques
    assert slow.num_samples == fast.num_samples == 2001
    assert np.allclose(slow.t, fast.t)
    assert np.abs(slow.steer - fast.steer).max() < 1e-4
    for name, amplitude in (("ax", np.pi), ("ay", 2.6), ("yaw_rate", 0.15), ("vx", 2.0)):
        assert np.abs(slow.channels[name] - fast.channels[name]).max() < 3e-3 * amplitude, name
    a, b = slow.inputs(), fast.inputs()
    assert np.abs(np.asarray(a.speed) - np.asarray(b.speed)).max() < 6e-3
    assert np.abs(np.asarray(a.accel) - np.asarray(b.accel)).max() < 1e-2


def test_20_hz_is_accepted_and_10_hz_read_with_a_warning(tmp_path):
    drive_frame(20.0).to_csv(tmp_path / "r.csv", index=False, float_format="%.10g")
    rec = read_recording(tmp_path / "r.csv")
    assert rec.original_rate == pytest.approx(20.0) and not any("Hz" in w for w in rec.warnings)
    drive_frame(10.0, 30.0).to_csv(tmp_path / "slow.csv", index=False, float_format="%.10g")
    slow = read_recording(tmp_path / "slow.csv")
    assert slow.original_rate == pytest.approx(10.0) and slow.rate == 200.0
    assert any("10 Hz is below 20 Hz" in w for w in slow.warnings)


@pytest.mark.parametrize("rate", [10.0, 25.0, 50.0])
def test_noise_of_a_slow_log_is_its_model_rate_equivalent(rate):
    # White noise σ on samples at `rate` has the low-frequency density of white noise
    # σ·sqrt(200/rate) at the model rate; the estimate must say so (interpolation hides it).
    rng = np.random.default_rng(int(rate))
    frame = drive_frame(rate, 120.0)
    sigma = {"ay": 0.1, "yaw_rate": 0.003}
    for c, s in sigma.items():
        frame[c] += rng.normal(0.0, s, len(frame))
    est = estimate_noise_std(build_recording(dict(frame.items()), "slow.csv"))
    for c, s in sigma.items():
        assert est[c] == pytest.approx(s * np.sqrt(200.0 / rate), rel=0.2), c


@pytest.mark.parametrize("name", ["vw_gti_low_speed", "vw_gti_high_speed_2"])
def test_real_drives_with_and_without_torque_columns(name):
    if not (REAL / name).exists():
        pytest.skip("real recordings not available")
    rec, _ = load_drive(REAL / name / "recording.csv", REAL / name / "vehicle.json")
    assert rec.has_torques and rec.inputs().speed is None
    frame = pd.read_csv(REAL / name / "recording.csv").drop(columns=["torque_front", "torque_rear"])
    bare = build_recording(columns(frame), name)
    assert not bare.has_torques and bare.warnings == []
    assert bare.channel_names == rec.channel_names == ("ax", "ay", "yaw_rate", "vx")
    assert bare.num_samples == rec.num_samples
    for c in rec.channel_names:
        assert np.array_equal(bare.channels[c], rec.channels[c])
    inputs = bare.inputs()  # float32 unless x64 is on
    assert np.allclose(np.asarray(inputs.speed), rec.channels["vx"], rtol=1e-6, atol=1e-6)
    assert np.allclose(np.asarray(inputs.accel), rec.channels["ax"], rtol=1e-6, atol=1e-6)
    # The drive's usable stretches come from the steering alone now; they stay most of the drive.
    with_torques = sum(b - a for a, b in usable_segments(rec))
    without = sum(b - a for a, b in usable_segments(bare))
    assert 0.6 * with_torques < without <= with_torques + 1e-9


# ROS 2 bags


@pytest.mark.parametrize("storage", ["sqlite3", "mcap"])
def test_bag_without_torque_topics_round_trips(tmp_path, storage):
    rec = build_recording(columns(good()), "bare", rate=100.0)
    write_bag(rec, tmp_path / "bag", storage=storage)
    got = read_recording(tmp_path / "bag", rate=100.0)
    assert not got.has_torques
    assert got.channel_names == rec.channel_names and got.num_samples == rec.num_samples
    for name in rec.channel_names:
        assert np.allclose(got.channels[name], rec.channels[name], rtol=1e-6, atol=1e-5)
    assert np.allclose(np.asarray(got.inputs().speed), rec.channels["vx"], atol=1e-5)


def test_bag_with_one_torque_topic_names_the_missing_one(tmp_path):
    rec = read_recording(GOOD / "recording.csv", rate=100.0)
    write_bag(rec, tmp_path / "bag", skip=("/vdsbi/torque_rear",))
    with pytest.raises(
        InputError, match="bag: torque_rear: topic '/vdsbi/torque_rear' is not in the bag"
    ) as e:
        read_recording(tmp_path / "bag", rate=100.0)
    assert "torque_front is read from topic '/vdsbi/torque_front'" in str(e.value)
    assert "come as a pair" in str(e.value)


def test_bag_topic_map_nulls_torques(tmp_path):
    rec = read_recording(GOOD / "recording.csv", rate=100.0)
    write_bag(rec, tmp_path / "bag")
    (tmp_path / "both.yaml").write_text("torque_front: null\ntorque_rear: null\n")
    got = read_recording(tmp_path / "bag", rate=100.0, topic_map=tmp_path / "both.yaml")
    assert not got.has_torques and got.channel_names == rec.channel_names
    (tmp_path / "one.yaml").write_text("torque_rear: null\n")
    with pytest.raises(InputError, match="torque_rear: is set to null in the topic map, but torque_front"):
        read_recording(tmp_path / "bag", rate=100.0, topic_map=tmp_path / "one.yaml")


def test_bag_explicitly_mapped_torque_topic_must_exist(tmp_path):
    rec = build_recording(columns(good()), "bare", rate=100.0)
    write_bag(rec, tmp_path / "bag")
    (tmp_path / "map.yaml").write_text("torque_front: {topic: /my_car/torque_front, field: data}\n")
    with pytest.raises(
        InputError,
        match=r"torque_front: topic '/my_car/torque_front' \(from topic map .*map\.yaml\) not in bag",
    ):
        read_recording(tmp_path / "bag", rate=100.0, topic_map=tmp_path / "map.yaml")


def test_bag_without_torques_or_speed_is_an_error(tmp_path):
    rec = build_recording(columns(good()), "bare", rate=100.0)
    write_bag(rec, tmp_path / "bag", skip=("/vdsbi/wheel_speeds", "/vehicle/status/velocity_status"))
    with pytest.raises(
        InputError, match="bag: vx: no torque topics, so the longitudinal motion follows"
    ) as e:
        read_recording(tmp_path / "bag", rate=100.0)
    assert "'/vehicle/status/velocity_status'" in str(e.value) and "--topic-map" in str(e.value)


# Segments


def drive(torque: np.ndarray | None, rate: float = 200.0):
    """0–5 s at rest, 5–25 s at 10 m/s with steering, 25–40 s straight at 10 m/s."""
    t = np.arange(int(40 * rate) + 1) / rate
    vx = np.where(t < 5, 0.0, 10.0)
    steer = np.where((t >= 5) & (t < 25), 0.03 * np.sin(2 * t), 0.0)
    cols = {"t": t, "steer": steer, "ay": vx * 10.0 * steer / 2.7, "vx": vx}
    if torque is not None:
        cols.update(torque_front=torque(t), torque_rear=0 * t)
    return build_recording(cols, "synthetic")


def test_segments_without_torques_judge_the_lateral_dynamics_alone():
    pulsed = lambda t: np.where(t >= 25, 300.0 * np.sin(3 * t), 200.0)  # noqa: E731
    with_torque = find_segments(drive(pulsed))
    without = find_segments(drive(None))
    # Throttle pulses excite 25–40 s with torques; without, that stretch is straight driving.
    assert [(s.usable) for s in with_torque] == [False, True]
    assert with_torque[1].t1 == 40.0 and with_torque[1].t0 == pytest.approx(without[1].t0)
    assert [s.usable for s in without] == [False, True, False]
    assert without[2].reason.startswith("straight: |ay| rms 0.0")
    assert 24.0 < without[1].t1 <= 26.0
    steady = find_segments(drive(lambda t: np.full_like(t, 200.0)))
    assert steady[2].reason.startswith("straight: ") and "torque std up to 0 N·m" in steady[2].reason
    assert usable_segments(drive(None)) == [(s.t0, s.t1) for s in steady if s.usable]
