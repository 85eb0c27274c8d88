"""`vdsbi check REC --vehicle V`: read, validate and summarise a recording."""

from __future__ import annotations

import argparse
import json

import numpy as np

from ..simulator._vehicle import CHANNELS


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


def summarise(rec, vehicle) -> dict:
    from ..io import estimate_noise_std, find_segments

    segs = find_segments(rec, wheel_radius=vehicle.wheel_radius)
    usable = [(s.t0, s.t1) for s in segs if s.usable]
    speed = rec.speed(vehicle.wheel_radius)
    return {
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
        "warnings": list(rec.warnings),
    }


def run(args) -> int:
    from ..io import load_drive
    from ._output import output_dir

    rec, vehicle = load_drive(args.recording, args.vehicle, rate=args.rate, topic_map=args.topic_map)
    s = summarise(rec, vehicle)
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
    print(f"  noise std  {noise} (estimated; vehicle noise_std: {dict(vehicle.noise_std) or 'none'})")
    for w in s["warnings"]:
        print(f"  warning: {w}")
    if args.out:
        with output_dir(args.out, overwrite=True) as d:
            rec.to_csv(d / "recording.csv")
            (d / "summary.json").write_text(json.dumps(s, indent=2) + "\n")
        print(f"wrote {args.out}/recording.csv, summary.json")
    return 0
