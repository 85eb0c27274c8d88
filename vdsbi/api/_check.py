"""`check`: read and validate a recording with its vehicle file, and summarise what was found."""

from __future__ import annotations

import dataclasses
import json
import os
from pathlib import Path
from typing import Any

import numpy as np

from ..io import Recording, estimate_noise_std, find_segments, kinematic_slopes, load_drive, steer_response
from ..simulator import Vehicle


@dataclasses.dataclass
class CheckResult:
    """A recording read as `identify` reads it, its vehicle, and `summary` (summary.json:
    duration, rates, channels, speed range, usable and rejected segments, noise estimate,
    kinematics, warnings)."""

    rec: Recording
    vehicle: Vehicle
    summary: dict[str, Any]

    def save(self, out: str | os.PathLike) -> None:
        """The resampled recording.csv and summary.json into the directory `out`."""
        out = Path(out)
        self.rec.to_csv(out / "recording.csv")
        (out / "summary.json").write_text(json.dumps(self.summary, indent=2) + "\n")


def check(
    recording: str | os.PathLike,
    vehicle: str | os.PathLike,
    *,
    rate: float = 200.0,
    topic_map: str | os.PathLike | None = None,
) -> CheckResult:
    """Read `recording` (.csv, .parquet or ROS2 bag) and `vehicle`, cross-check them, summarise.

    Raises:
        InputError: the first problem found, in one line naming file and field.
    """
    rec, veh = load_drive(recording, vehicle, rate=rate, topic_map=topic_map)
    segs = find_segments(rec, wheel_radius=veh.wheel_radius)
    usable = [(s.t0, s.t1) for s in segs if s.usable]
    speed = rec.speed(veh.wheel_radius)
    summary = {
        "source": rec.source,
        "duration_s": rec.duration,
        "original_rate_hz": rec.original_rate,
        "rate_hz": rec.rate,
        "samples": rec.num_samples,
        "channels": list(rec.channel_names),
        "speed_range_mps": None if speed is None else [float(np.min(speed)), float(np.max(speed))],
        "usable_segments": [[round(a, 3), round(b, 3)] for a, b in usable],
        "rejected_segments": [[round(s.t0, 3), round(s.t1, 3), s.reason] for s in segs if not s.usable],
        "noise_std_estimate": estimate_noise_std(rec, segments=usable or None),
        "kinematics": kinematics(rec, veh),
        "warnings": list(rec.warnings),
    }
    return CheckResult(rec, veh, summary)


def kinematics(rec: Recording, vehicle: Vehicle) -> dict[str, float]:
    """The kinematic slopes the reading checks (`kinematic_slopes`), and the yaw rate's response
    to the steer (`steer_response`): its gain over v·δ/L (1/(1 + K·v²/L) for an understeer
    gradient K) and the lag, s, at which it follows the steer best (actuator and tyre lag)."""
    out = dict(kinematic_slopes(rec))
    speed = rec.speed(vehicle.wheel_radius)
    found = None if speed is None else steer_response(rec, vehicle.wheelbase, speed)
    if found is not None:
        out |= {"yaw_rate~v*steer/L": found[0], "steer_correlation": found[1], "steer_lag_s": found[2]}
    return out
