"""`vdsbi check REC --vehicle V`: read, validate and summarise a recording."""

from __future__ import annotations

import argparse

from .. import api
from ..io import output_dir
from ..simulator import CHANNELS


def add_parser(subparsers) -> argparse.ArgumentParser:
    p = subparsers.add_parser(
        "check",
        help="validate a recording and its vehicle file, and summarise them",
        description="Read REC (.csv, .parquet or a ROS2 bag) and the vehicle file as `identify` "
        "would, report what was found, and stop at the first problem with a one-line error.",
    )
    p.add_argument("recording", metavar="REC", help="recording: .csv, .parquet or ROS2 bag")
    p.add_argument("--vehicle", required=True, metavar="V", help="vehicle constants (.json or .yaml)")
    p.add_argument("--topic-map", metavar="YAML", help="bags: column -> {topic, field, scale}")
    p.add_argument("--rate", type=float, default=200.0, help="model rate, Hz (default 200)")
    p.add_argument("--out", metavar="DIR", help="also write the resampled recording.csv and summary.json")
    return p


def run(args) -> int:
    res = api.check(args.recording, args.vehicle, rate=args.rate, topic_map=args.topic_map)
    s = res.summary
    missing = [c for c in CHANNELS if c not in s["channels"]]
    print(f"{s['source']}: OK")
    print(f"  duration   {s['duration_s']:.2f} s, {s['samples']} samples")
    print(f"  rate       {s['original_rate_hz']:.4g} Hz in file -> {s['rate_hz']:.4g} Hz model rate")
    absent = f" (absent: {', '.join(missing)})" if missing else ""
    print(f"  channels   {', '.join(s['channels'])}{absent}")
    if s["speed_range_mps"]:
        lo, hi = s["speed_range_mps"]
        print(f"  speed      {lo:.2f} .. {hi:.2f} m/s")
    total = sum(b - a for a, b in s["usable_segments"])
    print(f"  usable     {len(s['usable_segments'])} segment(s), {total:.1f} s:")
    for a, b in s["usable_segments"]:
        print(f"             {a:8.2f} .. {b:8.2f} s")
    noise = ", ".join(f"{k} {v:.3g}" for k, v in s["noise_std_estimate"].items())
    print(f"  noise std  {noise} (estimated; vehicle noise_std: {dict(res.vehicle.noise_std) or 'none'})")
    if s["kinematics"]:
        print(f"  kinematics {_kinematics(s['kinematics'])}")
    for w in s["warnings"]:
        print(f"  warning: {w}")
    if args.out:
        with output_dir(args.out, overwrite=True) as d:
            res.save(d)
        print(f"wrote {args.out}/recording.csv, summary.json")
    return 0


def _kinematics(k: dict) -> str:
    """The kinematic slopes in one line (≈ 1 each where units and signs agree)."""
    parts = []
    if "dvx/dt~ax" in k:
        parts.append(f"d(vx)/dt = {k['dvx/dt~ax']:.2f} × ax")
    if "ay~vx*yaw_rate steady" in k:
        parts.append(f"ay = {k['ay~vx*yaw_rate steady']:.2f} × vx·yaw_rate turning steadily")
    if "yaw_rate~v*steer/L" in k:
        lag = k["steer_lag_s"]
        parts.append(
            f"yaw_rate = {k['yaw_rate~v*steer/L']:.2f} × v·steer/L, {lag:.2f} s after the steer "
            f"(correlation {k['steer_correlation']:.2f})"
        )
    return "; ".join(parts)
