"""ROS2 bag writer for tests and demos: a `Recording` under the default topic map."""

from __future__ import annotations

import os
from typing import Literal

import numpy as np

from ._bag import autoware_typestore
from ._recording import Recording


def write_bag(
    rec: Recording,
    path: str | os.PathLike,
    *,
    storage: Literal["sqlite3", "mcap"] = "sqlite3",
    start_ns: int = 1_700_000_000 * 10**9,
    skip: tuple[str, ...] = (),
) -> None:
    """Write a Recording as a ROS2 bag with the default topic map (for tests and demos).

    IMU (sensor_msgs/Imu), VelocityReport and SteeringReport (Autoware), one std_msgs/Float64
    per axle torque (none for a recording without torques) and a std_msgs/Float64MultiArray
    [front, rear] of wheel speeds; one message per sample per topic, log time = header time =
    `start_ns` + t.

    Args:
        rec: the recording.
        path: bag directory to create (must not exist).
        storage: "sqlite3" or "mcap".
        skip: topics to leave out.
    """
    if storage not in ("sqlite3", "mcap"):
        raise ValueError(f"storage must be 'sqlite3' or 'mcap', got {storage!r}")
    from rosbags.rosbag2 import StoragePlugin, Writer

    store = autoware_typestore()
    Time = store.types["builtin_interfaces/msg/Time"]
    ch = rec.channels
    plugin = {"sqlite3": StoragePlugin.SQLITE3, "mcap": StoragePlugin.MCAP}[storage]
    topics = {
        "/sensing/imu/imu_data": "sensor_msgs/msg/Imu",
        "/vehicle/status/velocity_status": "autoware_vehicle_msgs/msg/VelocityReport",
        "/vehicle/status/steering_status": "autoware_vehicle_msgs/msg/SteeringReport",
        "/vdsbi/torque_front": "std_msgs/msg/Float64",
        "/vdsbi/torque_rear": "std_msgs/msg/Float64",
        "/vdsbi/wheel_speeds": "std_msgs/msg/Float64MultiArray",
    }
    if "vx" not in ch:
        skip = (*skip, "/vehicle/status/velocity_status")
    if "omega_front" not in ch or "omega_rear" not in ch:
        skip = (*skip, "/vdsbi/wheel_speeds")
    if not rec.has_torques:
        skip = (*skip, "/vdsbi/torque_front", "/vdsbi/torque_rear")
    with Writer(path, version=9, storage_plugin=plugin) as writer:
        conns = {
            tp: writer.add_connection(tp, ty, typestore=store) for tp, ty in topics.items() if tp not in skip
        }
        for k in range(rec.num_samples):
            total = start_ns + int(round(float(rec.t[k] - rec.t[0]) * 1e9))
            tm = Time(sec=total // 10**9, nanosec=total % 10**9)
            for tp, msg in _sample_messages(store, rec, k, tm, conns).items():
                if tp in conns:
                    writer.write(conns[tp], total, store.serialize_cdr(msg, conns[tp].msgtype))


def _sample_messages(store, rec: Recording, k: int, tm, conns: dict) -> dict:
    """Sample ``k`` of ``rec`` as one message per topic (those in ``conns`` where optional)."""
    ns = store.types
    Vector3 = ns["geometry_msgs/msg/Vector3"]
    ch = rec.channels
    cov = np.zeros(9)

    def reading(name):
        return float(ch[name][k]) if name in ch else 0.0

    msgs = {
        "/sensing/imu/imu_data": ns["sensor_msgs/msg/Imu"](
            header=ns["std_msgs/msg/Header"](stamp=tm, frame_id="base_link"),
            orientation=ns["geometry_msgs/msg/Quaternion"](x=0.0, y=0.0, z=0.0, w=1.0),
            orientation_covariance=cov,
            angular_velocity=Vector3(x=0.0, y=0.0, z=reading("yaw_rate")),
            angular_velocity_covariance=cov,
            linear_acceleration=Vector3(x=reading("ax"), y=reading("ay"), z=9.81),
            linear_acceleration_covariance=cov,
        ),
        "/vehicle/status/steering_status": ns["autoware_vehicle_msgs/msg/SteeringReport"](
            stamp=tm, steering_tire_angle=float(rec.steer[k])
        ),
    }
    if rec.has_torques:
        msgs["/vdsbi/torque_front"] = ns["std_msgs/msg/Float64"](data=float(rec.torque_front[k]))
        msgs["/vdsbi/torque_rear"] = ns["std_msgs/msg/Float64"](data=float(rec.torque_rear[k]))
    if "/vehicle/status/velocity_status" in conns:
        msgs["/vehicle/status/velocity_status"] = ns["autoware_vehicle_msgs/msg/VelocityReport"](
            header=ns["std_msgs/msg/Header"](stamp=tm, frame_id="base_link"),
            longitudinal_velocity=float(ch["vx"][k]),
            lateral_velocity=0.0,
            heading_rate=0.0,
        )
    if "/vdsbi/wheel_speeds" in conns:
        msgs["/vdsbi/wheel_speeds"] = ns["std_msgs/msg/Float64MultiArray"](
            layout=ns["std_msgs/msg/MultiArrayLayout"](dim=[], data_offset=0),
            data=np.array([ch["omega_front"][k], ch["omega_rear"][k]], dtype=np.float64),
        )
    return msgs
