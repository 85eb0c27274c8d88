"""ROS2 bag reader (sqlite3 and MCAP, through `rosbags`) with a topic map."""

from __future__ import annotations

import dataclasses
import os
import re
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import numpy as np

from ..simulator import CHANNELS, INPUTS
from ._contract import build_recording
from ._errors import InputError
from ._recording import SPEED_CHANNELS, TORQUES, Recording

#: Autoware message definitions (autoware_vehicle_msgs), not in rosbags' built-in typestores.
AUTOWARE_MSGS: dict[str, str] = {
    "autoware_vehicle_msgs/msg/VelocityReport": (
        "std_msgs/Header header\n"
        "float32 longitudinal_velocity\n"
        "float32 lateral_velocity\n"
        "float32 heading_rate\n"
    ),
    "autoware_vehicle_msgs/msg/SteeringReport": (
        "builtin_interfaces/Time stamp\nfloat32 steering_tire_angle\n"
    ),
}


@dataclasses.dataclass(frozen=True)
class TopicField:
    """Where one contract column lives in a bag.

    Attributes:
        topic: ROS topic name.
        field: dotted path into the message, with optional list index (``"data[1]"``).
        scale: factor to SI units (e.g. 0.10472 for rpm -> rad/s).
        origin: the topic-map file that set it ("" for the defaults), named in errors.
    """

    topic: str
    field: str
    scale: float = 1.0
    origin: str = ""

    def describe(self) -> str:
        where = f" (from topic map {self.origin})" if self.origin else ""
        return f"topic '{self.topic}'{where}"


#: Autoware defaults for IMU, speed and steering; vdsbi's own defaults for the rest
#: (std_msgs/Float64 per axle torque, std_msgs/Float64MultiArray [front, rear] wheel speeds).
DEFAULT_TOPIC_MAP: dict[str, TopicField] = {
    "steer": TopicField("/vehicle/status/steering_status", "steering_tire_angle"),
    "torque_front": TopicField("/vdsbi/torque_front", "data"),
    "torque_rear": TopicField("/vdsbi/torque_rear", "data"),
    "ax": TopicField("/sensing/imu/imu_data", "linear_acceleration.x"),
    "ay": TopicField("/sensing/imu/imu_data", "linear_acceleration.y"),
    "yaw_rate": TopicField("/sensing/imu/imu_data", "angular_velocity.z"),
    "omega_front": TopicField("/vdsbi/wheel_speeds", "data[0]"),
    "omega_rear": TopicField("/vdsbi/wheel_speeds", "data[1]"),
    "vx": TopicField("/vehicle/status/velocity_status", "longitudinal_velocity"),
}

#: Largest accepted gap between two messages of one topic, s: longer gaps cannot be bridged by
#: linear interpolation without inventing dynamics.
MAX_TOPIC_GAP = 0.1

_FIELD_RE = re.compile(r"^[A-Za-z_]\w*(\[\d+\])?(\.[A-Za-z_]\w*(\[\d+\])?)*$")


def autoware_typestore():
    """rosbags' ROS2 Humble typestore plus the Autoware vehicle messages."""
    from rosbags.typesys import Stores, get_types_from_msg, get_typestore

    store = get_typestore(Stores.ROS2_HUMBLE)
    types: dict[str, Any] = {}
    for name, text in AUTOWARE_MSGS.items():
        types.update(get_types_from_msg(text, name))
    store.register(types)
    return store


def load_topic_map(
    spec: str | os.PathLike | Mapping[str, Any] | None, source: str = "topic map"
) -> dict[str, TopicField]:
    """Defaults updated by a mapping (or a YAML/JSON file) ``column: {topic, field[, scale]}``.

    A column mapped to ``null`` is not read (the torques only as a pair: both ``null`` reads a
    bag without torques). A column mapped here must be in the bag; the default torque and
    measured-channel topics may be absent. Unknown column names are rejected, since a typo
    would otherwise silently fall back to the default topic.

    Raises:
        InputError: naming the file and the column key.
    """
    out = dict(DEFAULT_TOPIC_MAP)
    if spec is None:
        return out
    if not isinstance(spec, Mapping):
        source = str(spec)
        import yaml

        try:
            with open(spec, encoding="utf-8") as f:
                spec = yaml.safe_load(f)
        except FileNotFoundError:
            raise InputError(source, "file", "does not exist") from None
        except (OSError, UnicodeDecodeError, yaml.YAMLError) as err:
            msg = " ".join(str(err).split())
            raise InputError(source, "file", f"cannot parse as YAML ({msg})") from None
        if spec is None:
            return out
    if not isinstance(spec, Mapping):
        raise InputError(source, "file", "expected a mapping column -> {topic, field}")
    known = (*INPUTS, *CHANNELS)
    for key, value in spec.items():
        if key not in known:
            raise InputError(source, str(key), f"unknown column; expected one of {list(known)}")
        if value is None:
            out.pop(key, None)
            continue
        if not isinstance(value, Mapping) or not isinstance(value.get("topic"), str):
            expected = "expected {topic: str, field: str, scale: number}"
            raise InputError(source, key, f"{expected}, got {value!r}")
        field = value.get("field", "data")
        if not isinstance(field, str) or not _FIELD_RE.match(field):
            raise InputError(source, key, f"field {field!r} is not a dotted path like 'twist.linear.x'")
        scale = value.get("scale", 1.0)
        if isinstance(scale, bool) or not isinstance(scale, (int, float)) or not np.isfinite(scale):
            raise InputError(source, key, f"scale must be a finite number, got {scale!r}")
        out[key] = TopicField(value["topic"], field, float(scale), origin=source)
    return out


def _get(msg: Any, path: str) -> float:
    obj = msg
    for part in path.split("."):
        m = re.match(r"^(\w+)(?:\[(\d+)\])?$", part)
        assert m is not None
        obj = getattr(obj, m.group(1))
        if m.group(2) is not None:
            obj = obj[int(m.group(2))]
    return float(obj)


def is_bag(path: str | os.PathLike) -> bool:
    p = Path(path)
    return (p.is_dir() and (p / "metadata.yaml").exists()) or p.suffix in (".db3", ".mcap")


def read_bag_columns(
    path: str | os.PathLike, topic_map: Mapping[str, TopicField], *, rate: float
) -> dict[str, np.ndarray]:
    """Read mapped fields and interpolate them onto a common uniform grid at `rate`.

    Message times are the bag's receive (log) time stamps. The grid spans the interval all
    mapped topics cover. `steer` is required. The torques are optional but a pair: a default
    torque topic that is absent (or silent) means no torque column; one named in a topic map
    must be there. Without torques a speed (vx or wheel speeds) is required.

    Raises:
        InputError: naming the bag, the column and its topic (and the topic map that set it).
    """
    from rosbags.highlevel import AnyReader

    source = str(path)
    try:
        with AnyReader([Path(path)], default_typestore=autoware_typestore()) as reader:
            wanted = _wanted_topics(source, {c.topic: c for c in reader.connections}, topic_map)
            series = _read_series(source, reader, wanted)
    except InputError:
        raise
    except Exception as err:  # rosbags, sqlite3, mcap and struct errors on corrupt files
        msg = " ".join(str(err).split()) or type(err).__name__
        raise InputError(
            source, "bag", f"cannot read ROS2 bag ({type(err).__name__}: {msg}); truncated or corrupt?"
        ) from None
    present = {c: s for c, s in series.items() if len(s[0]) > 0}
    _check_present(source, topic_map, series, present)
    return _resample(source, topic_map, present, rate)


def _wanted_topics(source: str, topics: dict, topic_map: Mapping[str, TopicField]) -> dict:
    """``{topic: [(column, field), ...]}`` for the mapped columns whose topic the bag has; a
    missing topic is an error for `steer` and for topics named explicitly."""
    wanted: dict[str, list[tuple[str, TopicField]]] = {}
    for col in (*INPUTS, *CHANNELS):
        spec = topic_map.get(col)
        if spec is None:
            continue
        if spec.topic not in topics:
            if col == "steer" or spec.origin:  # required, or asked for explicitly
                have = ", ".join(sorted(topics)) or "none"
                raise InputError(
                    source,
                    col,
                    f"{spec.describe()} not in bag (topics: {have}); map it with --topic-map",
                )
            continue  # a measured channel or the torque pair may be absent
        wanted.setdefault(spec.topic, []).append((col, spec))
    return wanted


def _read_series(source: str, reader, wanted: dict) -> dict[str, tuple[list[int], list[float]]]:
    """Per wanted column, its messages' receive stamps (ns) and scaled field values."""
    mapped = {col for cols in wanted.values() for col, _ in cols}
    series: dict[str, tuple[list[int], list[float]]] = {
        col: ([], []) for col in (*INPUTS, *CHANNELS) if col in mapped
    }
    topics = {c.topic: c for c in reader.connections}
    for conn, stamp, raw in reader.messages(connections=[topics[tp] for tp in wanted]):
        msg = reader.deserialize(raw, conn.msgtype)
        for col, spec in wanted[conn.topic]:
            try:
                value = _get(msg, spec.field) * spec.scale
            except (AttributeError, IndexError, TypeError, ValueError):
                raise InputError(
                    source,
                    col,
                    f"{spec.describe()} ({conn.msgtype}) has no numeric field '{spec.field}'",
                ) from None
            series[col][0].append(stamp)
            series[col][1].append(value)
    return series


def _check_present(source: str, topic_map, series: dict, present: dict) -> None:
    """Steering and explicitly mapped inputs have messages; the torques come as a pair; without
    torques a speed channel is there."""
    for col in INPUTS:
        if col in series and col not in present and (col == "steer" or topic_map[col].origin):
            raise InputError(source, col, f"{topic_map[col].describe()} has no messages")
    _check_torque_pair(source, topic_map, series, present)
    if not any(c in present for c in (*TORQUES, *SPEED_CHANNELS)):
        wanted = [f"{c} ({topic_map[c].describe()})" for c in SPEED_CHANNELS if topic_map.get(c)]
        raise InputError(
            source,
            "vx",
            "no torque topics, so the longitudinal motion follows the measured speed: expected "
            + (" or ".join(wanted) if wanted else "vx or the wheel speeds")
            + " with messages; map it with --topic-map",
        )


def _resample(source: str, topic_map, present: dict, rate: float) -> dict[str, np.ndarray]:
    """Every column interpolated onto the uniform grid at ``rate`` over the span all cover;
    a gap longer than `MAX_TOPIC_GAP` inside it is an error."""
    t0 = max(min(s[0]) for s in present.values()) * 1e-9
    t1 = min(max(s[0]) for s in present.values()) * 1e-9
    if not t1 > t0:
        raise InputError(source, "t", "the mapped topics do not overlap in time")
    grid = t0 + np.arange(int(np.floor((t1 - t0) * rate + 1e-9)) + 1) / rate
    out: dict[str, np.ndarray] = {"t": grid - grid[0]}
    for col, (stamps, values) in present.items():
        ts = np.asarray(stamps, dtype=np.int64)
        order = np.argsort(ts, kind="stable")
        ts, vs = ts[order] * 1e-9, np.asarray(values, dtype=float)[order]
        keep = np.r_[True, np.diff(ts) > 0]  # a repeated stamp keeps its first message
        ts, vs = ts[keep], vs[keep]
        inside = (ts >= t0 - MAX_TOPIC_GAP) & (ts <= t1 + MAX_TOPIC_GAP)
        gaps = np.diff(ts[inside])
        if gaps.size and gaps.max() > MAX_TOPIC_GAP:
            i = int(np.argmax(gaps))
            raise InputError(
                source,
                col,
                f"{topic_map[col].describe()} has a {gaps[i]:.3g} s gap at t = "
                f"{ts[inside][i] - t0:.3f} s; expected messages at least every {MAX_TOPIC_GAP:g} s",
            )
        out[col] = np.interp(grid, ts, vs)
    return out


def _check_torque_pair(
    source: str,
    topic_map: Mapping[str, TopicField],
    series: Mapping[str, tuple[list[int], list[float]]],
    present: Mapping[str, object],
) -> None:
    """Raise if exactly one of the axle torques was read, naming the one missing and why."""
    got = [c for c in TORQUES if c in present]
    if len(got) != 1:
        return
    (col,) = [c for c in TORQUES if c not in present]
    other = f"{got[0]} is read from {topic_map[got[0]].describe()}"
    spec = topic_map.get(col)
    if spec is None:
        why = "is set to null in the topic map"
    elif col in series:
        why = f"{spec.describe()} has no messages"
    else:
        why = f"{spec.describe()} is not in the bag"
    raise InputError(
        source,
        col,
        f"{why}, but {other}: the axle torques come as a pair; map both with --topic-map, "
        "or set both to null",
    )


def read_bag(
    path: str | os.PathLike,
    *,
    rate: float = 200.0,
    topic_map: str | os.PathLike | Mapping[str, Any] | None = None,
) -> Recording:
    """Read a ROS2 bag (directory with metadata.yaml, or a .db3/.mcap file) into a Recording."""
    tm = load_topic_map(topic_map)
    columns = read_bag_columns(path, tm, rate=rate)
    return build_recording(columns, path, rate=rate)
