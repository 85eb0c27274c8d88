"""One entry point for user recordings, and the recording/vehicle cross-checks."""

from __future__ import annotations

import os
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import numpy as np

from ..simulator import Vehicle
from ._bag import is_bag, read_bag
from ._consistency import steer_problems
from ._csv import read_csv
from ._errors import InputError
from ._parquet import read_parquet
from ._recording import Recording
from ._vehicle_file import read_vehicle

#: vx / (omega·R) outside this band means a unit mistake (slip and radius errors stay well
#: inside: a 10 % radius error and 20 % slip give 0.75–1.25).
SPEED_RATIO_BAND = (0.5, 2.0)


def read_recording(
    path: str | os.PathLike,
    *,
    rate: float = 200.0,
    topic_map: str | os.PathLike | Mapping[str, Any] | None = None,
) -> Recording:
    """Read a recording (.csv, .parquet, or a ROS2 bag) and resample it to `rate` Hz.

    Args:
        path: a .csv or .parquet file per the recording contract, or a ROS2 bag (a directory
            with metadata.yaml, or a .db3 / .mcap file).
        rate: model rate, Hz.
        topic_map: bags only: column -> {topic, field, scale} overrides (mapping or YAML file).

    Raises:
        InputError: one line naming the file, the column and what was expected.
    """
    source = str(path)
    p = Path(path)
    if not p.exists():
        raise InputError(source, "file", "does not exist")
    if is_bag(p):
        return read_bag(p, rate=rate, topic_map=topic_map)
    if p.is_dir():
        raise InputError(source, "file", "is a directory without metadata.yaml; expected a file or ROS2 bag")
    suffix = p.suffix.lower()
    if suffix == ".csv":
        return read_csv(p, rate=rate)
    if suffix in (".parquet", ".pq"):
        return read_parquet(p, rate=rate)
    raise InputError(source, "file", f"unknown extension '{p.suffix}'; expected .csv, .parquet, .db3, .mcap")


def check_against_vehicle(rec: Recording, vehicle: Vehicle, *, min_speed: float = 3.0) -> None:
    """Cross-check wheel speeds against vx with the vehicle's wheel radius, and the steer
    against the yaw rate with its wheelbase (`steer_problems`: a warning is added to
    `rec.warnings`).

    Raises:
        InputError: the median of vx / (omega·R) over samples with vx > `min_speed` is outside
            `SPEED_RATIO_BAND` (≈ 3.6: vx in km/h; ≈ 0.1: omega in rpm; ≈ 0.017: in deg/s).
    """
    _check_wheel_speeds(rec, vehicle, min_speed)
    speed = rec.speed(vehicle.wheel_radius)
    if speed is not None:
        rec.warnings.extend(w for w in steer_problems(rec, vehicle.wheelbase, speed) if w not in rec.warnings)


def _check_wheel_speeds(rec: Recording, vehicle: Vehicle, min_speed: float) -> None:
    if "vx" not in rec.channels:
        return
    vx = rec.channels["vx"]
    moving = vx > min_speed
    if moving.sum() < rec.rate:  # under a second of driving: nothing to compare
        return
    for name in ("omega_front", "omega_rear"):
        if name not in rec.channels:
            continue
        wheel = rec.channels[name][moving] * vehicle.wheel_radius
        ratio = float(np.median(vx[moving] / np.where(np.abs(wheel) > 1e-6, wheel, np.nan)))
        lo, hi = SPEED_RATIO_BAND
        if not lo <= ratio <= hi:
            if 3.0 <= ratio <= 4.3:
                what = f"vx is {ratio:.2f} × {name}·R: looks like km/h; expected m/s"
                raise InputError(rec.source, "vx", what)
            if 0.07 <= ratio <= 0.14:
                hint = "looks like rpm"
            elif 0.012 <= ratio <= 0.025:
                hint = "looks like deg/s"
            else:
                hint = "check units and wheel_radius"
            raise InputError(
                rec.source,
                name,
                f"vx is {ratio:.3g} × {name}·R (R = {vehicle.wheel_radius:g} m) where ≈ 1 is expected: "
                f"{hint}; expected rad/s",
            )


def load_drive(
    recording: str | os.PathLike,
    vehicle: str | os.PathLike,
    *,
    rate: float = 200.0,
    topic_map: str | os.PathLike | Mapping[str, Any] | None = None,
) -> tuple[Recording, Vehicle]:
    """Read and cross-check a recording and its vehicle file: the reading path every CLI command uses."""
    veh = read_vehicle(vehicle)
    rec = read_recording(recording, rate=rate, topic_map=topic_map)
    check_against_vehicle(rec, veh)
    return rec, veh
