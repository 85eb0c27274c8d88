"""Regenerate tests/data/good/ and tests/data/bad/ (with bad/manifest.json).

Run from the repository root:  .venv/bin/python tests/data/make_bad_inputs.py

Every bad input is the good drive (or vehicle) with one thing wrong. The manifest maps each file
to the field its error must name and to its role: the bad file is the recording, the vehicle file
or the topic map (the others are then the good ones).
"""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import numpy as np
import pandas as pd

HERE = Path(__file__).parent
GOOD, BAD = HERE / "good", HERE / "bad"
RATE, DURATION, R = 200.0, 3.0, 0.31

VEHICLE = {
    "mass": 1500.0,
    "wheelbase": 2.7,
    "wheel_radius": R,
    "wheel_inertia": 1.8,
    "tire_vertical_stiffness": 4.0e5,
    "friction": 0.9,
    "relaxation_length": 0.3,
    "noise_std": {"ax": 0.05, "ay": 0.05, "yaw_rate": 0.002},
    "comment": "extra keys are accepted silently",
}


def good_frame(rate: float = RATE, duration: float = DURATION, v0: float = 10.0) -> pd.DataFrame:
    """A kinematically consistent drive: vx = v0 + sin(πt), ax = d(vx)/dt, ay = vx·r."""
    t = np.arange(int(round(duration * rate)) + 1) / rate
    vx = v0 + np.sin(np.pi * t)
    r = 0.1 * np.sin(2.0 * t)
    return pd.DataFrame(
        {
            "t": t,
            "steer": 0.03 * np.sin(2.0 * t),
            "torque_front": 400.0 + 300.0 * np.cos(np.pi * t),
            "torque_rear": -50.0 * (1 + np.cos(np.pi * t)),
            "ax": np.pi * np.cos(np.pi * t),
            "ay": vx * r,
            "yaw_rate": r,
            "omega_front": vx / R * 1.01,
            "omega_rear": vx / R,
            "vx": vx,
            "gnss_quality": 4,  # extra column: accepted silently
        }
    )


def csv(df: pd.DataFrame, name: str) -> None:
    df.to_csv(BAD / name, index=False, float_format="%.7g")


def write_recordings(m: dict) -> None:
    g = good_frame()

    def bad(name: str, field: str, df: pd.DataFrame | None = None, text: str | None = None, contains=""):
        if text is not None:
            (BAD / name).write_text(text)
        else:
            csv(df, name)
        m[name] = {"field": field, "role": "recording", "contains": contains}

    bad("missing_steer.csv", "steer", g.drop(columns="steer"))
    bad("misspelled_torque_front.csv", "torque_front", g.rename(columns={"torque_front": "torque_frnt"}))
    # Torques are optional, but a pair; without them a speed (vx or wheel speeds) is required.
    bad("torque_rear_without_front.csv", "torque_front", g.drop(columns="torque_front"), contains="pair")
    no_speed = g.drop(columns=["torque_front", "torque_rear", "vx", "omega_front", "omega_rear"])
    bad("no_torques_no_speed.csv", "vx", no_speed, contains="follows the measured speed")
    bad("wrong_case_steer.csv", "steer", g.rename(columns={"steer": "Steer"}))
    bad("missing_t.csv", "t", g.rename(columns={"t": "time"}))
    one = g[["t", "steer", "torque_front", "torque_rear", "ax"]]
    bad("one_measured_channel.csv", "measured channels", one)
    bad("misspelled_channels.csv", "measured channels", one.assign(yawrate=g.yaw_rate))
    df = g.copy()
    df.loc[100, "ay"] = np.nan
    bad("nan_in_ay.csv", "ay", df)
    df = g.copy()
    df.loc[250, "yaw_rate"] = np.inf
    bad("inf_in_yaw_rate.csv", "yaw_rate", df)
    lines = (g.to_csv(index=False, float_format="%.7g")).splitlines()
    cells = lines[51].split(",")
    cells[4] = ""  # ax
    lines[51] = ",".join(cells)
    bad("empty_cell_ax.csv", "ax", text="\n".join(lines) + "\n")
    cells = lines[31].split(",")
    cells[3] = "n/a"  # torque_rear
    lines2 = list(lines)
    lines2[31] = ",".join(cells)
    bad("non_numeric_torque_rear.csv", "torque_rear", text="\n".join(lines2) + "\n")
    bad("empty.csv", "header", text="")
    bad("header_only.csv", "t", text=lines[0] + "\n")
    bad("one_row.csv", "t", g.iloc[:1])
    bad("too_short.csv", "t", g.iloc[:100])
    df = g.copy()
    df.loc[[200, 201], "t"] = df.loc[[201, 200], "t"].to_numpy()
    bad("t_not_monotonic.csv", "t", df)
    df = g.copy()
    df.loc[300, "t"] = df.loc[299, "t"]
    bad("t_duplicated.csv", "t", df)
    rng = np.random.default_rng(0)
    df = g.copy()
    df["t"] = df["t"] + rng.uniform(-0.3, 0.3, len(df)) / RATE
    bad("t_irregular.csv", "t", df)
    bad("t_gap.csv", "t", g.drop(index=range(300, 310)))
    bad("t_in_milliseconds.csv", "t", g.assign(t=g.t * 1000))
    bad("steer_in_degrees.csv", "steer", g.assign(steer=np.degrees(g.steer * 30)))
    bad("steer_sign_reversed.csv", "steer", g.assign(steer=-g.steer), contains="reversed")
    bad("ay_sign_reversed.csv", "ay", g.assign(ay=-g.ay), contains="opposite signs")
    bad("yaw_rate_sign_reversed.csv", "yaw_rate", g.assign(yaw_rate=-g.yaw_rate), contains="opposite signs")
    fast = good_frame(v0=30.0)  # 108 km/h
    bad(
        "vx_in_kmh_highway.csv",
        "vx",
        fast.assign(vx=fast.vx * 3.6).drop(columns=["omega_front", "omega_rear"]),
    )
    bad("vx_in_kmh_city.csv", "vx", g.assign(vx=g.vx * 3.6).drop(columns=["omega_front", "omega_rear"]))
    bad("vx_in_kmh_vs_wheels.csv", "vx", g.assign(vx=g.vx * 3.6).drop(columns=["ax"]))
    bad("yaw_rate_in_deg_per_s.csv", "yaw_rate", g.assign(yaw_rate=np.degrees(g.yaw_rate * 6)))
    bad("yaw_rate_in_deg_per_s_small.csv", "yaw_rate", g.assign(yaw_rate=np.degrees(g.yaw_rate)))
    bad("ax_in_mm_per_s2.csv", "ax", g.assign(ax=g.ax * 1000))
    f15 = good_frame(v0=15.0)
    bad("omega_front_in_rpm.csv", "omega_front", f15.assign(omega_front=f15.omega_front * 60 / (2 * np.pi)))
    bad("omega_rear_in_rpm_slow.csv", "omega_rear", g.assign(omega_rear=g.omega_rear * 60 / (2 * np.pi)))
    bad("omega_rear_negative.csv", "omega_rear", g.assign(omega_rear=-g.omega_rear))
    bad("torque_front_in_ncm.csv", "torque_front", g.assign(torque_front=g.torque_front * 100))
    bad("semicolon_separated.csv", "t", text=g.to_csv(index=False, sep=";"), contains="comma")
    bad("no_header_row.csv", "header", text="\n".join(lines[1:]) + "\n")
    bad("duplicated_column_ax.csv", "ax", text="\n".join(ln + "," + ln.split(",")[4] for ln in lines) + "\n")
    bad("ragged_rows.csv", "rows", text="\n".join(lines[:40] + [lines[40] + ",1,2,3"] + lines[41:]) + "\n")
    (BAD / "not_a_parquet.parquet").write_bytes(b"PAR1 this is not really parquet")
    m["not_a_parquet.parquet"] = {"field": "file", "role": "recording", "contains": "Parquet"}
    g.drop(columns="torque_rear").to_parquet(BAD / "parquet_missing_torque_rear.parquet", index=False)
    m["parquet_missing_torque_rear.parquet"] = {"field": "torque_rear", "role": "recording"}
    g.assign(ay=g.ay.astype(str)).assign(ay=lambda d: d.ay.where(d.index != 7, "x")).to_parquet(
        BAD / "parquet_text_ay.parquet", index=False
    )
    m["parquet_text_ay.parquet"] = {"field": "ay", "role": "recording"}
    (BAD / "recording.xlsx").write_bytes(b"PK\x03\x04 not supported")
    m["recording.xlsx"] = {"field": "file", "role": "recording", "contains": "extension"}


def write_vehicles(m: dict) -> None:
    def bad(name: str, field: str, data=None, text: str | None = None, contains=""):
        if text is None:
            text = json.dumps(data, indent=2) if name.endswith(".json") else _yaml(data)
        (BAD / name).write_text(text)
        m[name] = {"field": field, "role": "vehicle", "contains": contains}

    v = {k: val for k, val in VEHICLE.items()}
    bad("vehicle_missing_mass.json", "mass", {k: x for k, x in v.items() if k != "mass"})
    bad("vehicle_mass_is_string.json", "mass", {**v, "mass": "1500"})
    bad("vehicle_negative_mass.json", "mass", {**v, "mass": -1500.0})
    bad("vehicle_wheelbase_is_list.yaml", "wheelbase", {**v, "wheelbase": [2.7]})
    bad("vehicle_wheelbase_in_mm.yaml", "wheelbase", {**v, "wheelbase": 2700})
    bad("vehicle_friction_is_text.yaml", "friction", {**v, "friction": "dry"})
    bad("vehicle_prior_l_f_outside_wheelbase.json", "prior.l_f", {**v, "prior": {"l_f": [1.0, 3.0]}})
    bad("vehicle_prior_unknown_param.json", "prior.l_front", {**v, "prior": {"l_front": [1.0, 1.5]}})
    bad("vehicle_prior_reversed.yaml", "prior.C_alpha_f", {**v, "prior": {"C_alpha_f": [9e4, 3e4]}})
    bad("vehicle_negative_noise.json", "noise_std.ax", {**v, "noise_std": {"ax": -0.1}})
    bad(
        "vehicle_syntax_error.json",
        "file",
        contains="line 3",
        text='{\n  "mass": 1500,\n  "wheelbase" 2.7\n}\n',
    )
    bad(
        "vehicle_syntax_error.yaml",
        "file",
        contains="line 3",
        text="mass: 1500\nwheelbase: [2.7\nfriction: 0.9\n",
    )
    bad("vehicle_top_level_list.yaml", "file", contains="mapping", text="- mass: 1500\n- wheelbase: 2.7\n")
    bad("vehicle_empty.json", "file", contains="empty", text="")
    bad("vehicle.txt", "file", contains="extension", text=json.dumps(v))


def _yaml(data) -> str:
    import yaml

    return yaml.safe_dump(data, sort_keys=False)


def write_topic_maps(m: dict) -> None:
    (BAD / "topic_map_unknown_column.yaml").write_text("stear:\n  topic: /steer\n  field: data\n")
    m["topic_map_unknown_column.yaml"] = {"field": "stear", "role": "topic_map"}
    (BAD / "topic_map_bad_field.yaml").write_text(
        "ax:\n  topic: /sensing/imu/imu_data\n  field: linear acceleration.x\n"
    )
    m["topic_map_bad_field.yaml"] = {"field": "ax", "role": "topic_map"}
    (BAD / "topic_map_wrong_field.yaml").write_text(
        "torque_front:\n  topic: /vdsbi/torque_front\n  field: value\n"
    )
    m["topic_map_wrong_field.yaml"] = {"field": "torque_front", "role": "topic_map"}
    (BAD / "topic_map_missing_topic.yaml").write_text("steer:\n  topic: /my_car/steering\n  field: data\n")
    m["topic_map_missing_topic.yaml"] = {"field": "steer", "role": "topic_map"}


def write_bags(m: dict) -> None:
    from vdsbi.io import build_recording
    from vdsbi.io._bag_writer import write_bag

    g = good_frame(rate=50.0, duration=2.0)
    rec = build_recording({c: g[c].to_numpy() for c in g.columns}, "good", rate=50.0)
    tmp = BAD / "_tmp"
    shutil.rmtree(tmp, ignore_errors=True)
    tmp.mkdir()
    for storage, ext in (("sqlite3", "db3"), ("mcap", "mcap")):
        write_bag(rec, tmp / storage, storage=storage)
        data = (tmp / storage / f"{storage}.{ext}").read_bytes()
        name = f"truncated.{ext}"
        (BAD / name).write_bytes(data[: len(data) // 3])
        m[name] = {"field": "bag", "role": "recording", "contains": "truncated"}
    name = "bag_without_needed_topics"
    write_bag(
        rec,
        BAD / name,
        storage="mcap",
        skip=("/vehicle/status/steering_status", "/vdsbi/torque_front", "/vdsbi/torque_rear"),
    )
    m[name] = {"field": "steer", "role": "recording"}
    name = "bag_one_torque_topic"
    write_bag(rec, BAD / name, storage="mcap", skip=("/vdsbi/torque_rear",))
    m[name] = {"field": "torque_rear", "role": "recording", "contains": "pair"}
    name = "bag_without_torques_or_speed"
    speeds = ("/vehicle/status/velocity_status", "/vdsbi/wheel_speeds")
    write_bag(rec, BAD / name, storage="mcap", skip=("/vdsbi/torque_front", "/vdsbi/torque_rear", *speeds))
    m[name] = {"field": "vx", "role": "recording", "contains": "follows the measured speed"}
    gap = build_recording(
        {c: g[c].to_numpy() for c in g.columns if c not in ("omega_front", "omega_rear")}, "x", rate=50.0
    )
    keep = (gap.t < 0.8) | (gap.t > 1.3)
    gap.t = gap.t[keep]
    gap.steer, gap.torque_front, gap.torque_rear = (
        gap.steer[keep],
        gap.torque_front[keep],
        gap.torque_rear[keep],
    )
    gap.channels = {k: x[keep] for k, x in gap.channels.items()}
    write_bag(gap, BAD / "bag_with_gap.mcap", storage="mcap")
    m["bag_with_gap.mcap"] = {"field": "steer", "role": "recording"}
    shutil.rmtree(tmp)


def main() -> None:
    shutil.rmtree(BAD, ignore_errors=True)
    BAD.mkdir(parents=True)
    GOOD.mkdir(exist_ok=True)
    good_frame().to_csv(GOOD / "recording.csv", index=False, float_format="%.7g")
    (GOOD / "vehicle.json").write_text(json.dumps(VEHICLE, indent=2) + "\n")
    (GOOD / "vehicle.yaml").write_text(_yaml(VEHICLE))
    m: dict = {}
    write_recordings(m)
    write_vehicles(m)
    write_topic_maps(m)
    write_bags(m)
    (BAD / "manifest.json").write_text(json.dumps(dict(sorted(m.items())), indent=1) + "\n")
    print(f"{len(m)} bad inputs in {BAD}")


if __name__ == "__main__":
    main()
