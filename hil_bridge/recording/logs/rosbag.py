"""ROS 2 bags (a bag directory, a ``.mcap`` or a ``.db3`` file) through rosbags.

Pose topics: ``nav_msgs/msg/Odometry`` (speed = |twist.linear|), ``geometry_msgs/msg/PoseStamped``
and ``geometry_msgs/msg/PoseWithCovarianceStamped``; positions and orientations are taken as
REP 103 (world ENU, body FLU), as ROS publishes them. Time: ``header.stamp``, or the bag's
receive time where a stamp is zero. ``topic`` names the pose topic when the bag has several.
Bags without embedded message definitions are decoded with the ROS 2 type store the ROS 2 export
writes (:data:`hil_bridge.recording.export.ros2.STORE`, Jazzy; the pose types are the same in
rosbags' Humble, Jazzy, Kilted and Lyrical stores).
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from hil_bridge.recording.logs.track import NoPoseError, PoseLog, describe

__all__ = ["POSE_TYPES", "read_ros2_bag"]

POSE_TYPES = (
    "nav_msgs/msg/Odometry",
    "geometry_msgs/msg/PoseStamped",
    "geometry_msgs/msg/PoseWithCovarianceStamped",
)


def _pose_of(msg: Any, msgtype: str) -> Any:
    if msgtype == "geometry_msgs/msg/PoseStamped":
        return msg.pose
    return msg.pose.pose


def read_ros2_bag(
    path: Path, *, vehicle_id: int | None = None, topic: str | None = None
) -> PoseLog:
    """The poses on one topic of a ROS 2 bag (module docstring). Whatever the bag's bytes, it
    fails with one ``ValueError`` naming the file (rosbags, on a corrupt MCAP, can also raise
    ``TypeError``, ``OverflowError`` or ``MemoryError``)."""
    from rosbags.highlevel import AnyReader, AnyReaderError
    from rosbags.typesys import get_typestore

    from hil_bridge.recording.export.ros2 import STORE

    unreadable = (AnyReaderError, OSError, ValueError, KeyError, TypeError, OverflowError,
                  MemoryError)
    try:
        reader = AnyReader([path], default_typestore=get_typestore(STORE))
        reader.open()
    except unreadable as exc:
        raise ValueError(f"{path}: cannot read ROS 2 bag ({type(exc).__name__}: {exc})") from None
    try:
        return _poses(reader, path, vehicle_id, topic)
    except unreadable as exc:
        if str(exc).startswith(f"{path}: "):
            raise  # one of ours, already one line naming the file
        raise ValueError(f"{path}: cannot read ROS 2 bag ({type(exc).__name__}: {exc})") from None
    finally:
        reader.close()


def _poses(reader: Any, path: Path, vehicle_id: int | None, topic: str | None) -> PoseLog:
    """The poses of ``topic`` (or the bag's one pose topic) of an open ``reader``."""
    from rosbags.highlevel import AnyReaderError

    found = {f"{c.topic} [{c.msgtype}]": c.msgcount for c in reader.connections}
    poses = sorted({c.topic for c in reader.connections
                    if c.msgtype in POSE_TYPES and c.msgcount})
    if not poses:
        raise NoPoseError(f"{path}: ROS 2 bag without a pose topic (one of {list(POSE_TYPES)});"
                          f" it holds {describe(found)}")
    if topic is None:
        if len(poses) > 1:
            raise ValueError(f"{path}: holds pose topics {poses}; choose one with --topic")
        topic = poses[0]
    elif topic not in poses:
        raise NoPoseError(f"{path}: topic {topic!r} holds no pose; pose topics: {poses}; "
                          f"the bag holds {describe(found)}")
    conns = [c for c in reader.connections if c.topic == topic]
    msgtype = conns[0].msgtype
    rows: list[tuple[float, ...]] = []
    for conn, log_ns, raw in reader.messages(connections=conns):
        try:
            msg: Any = reader.deserialize(raw, conn.msgtype)
        except (AnyReaderError, ValueError, IndexError) as exc:
            raise ValueError(f"{path}: undecodable {conn.msgtype} on {topic} "
                             f"({exc})") from None
        stamp_ns = msg.header.stamp.sec * 1_000_000_000 + msg.header.stamp.nanosec
        pose = _pose_of(msg, msgtype)
        p, q = pose.position, pose.orientation
        speed = np.nan
        if msgtype == "nav_msgs/msg/Odometry":
            v = msg.twist.twist.linear
            speed = float(np.sqrt(v.x * v.x + v.y * v.y + v.z * v.z))
        rows.append(((stamp_ns or log_ns) * 1e-9, p.x, p.y, p.z, q.w, q.x, q.y, q.z, speed))
    if not rows:
        raise NoPoseError(f"{path}: topic {topic!r} has no messages")
    a = np.asarray(rows, dtype=np.float64)
    log = PoseLog(format="ROS 2 bag", source=f"{topic} [{msgtype}]", t=a[:, 0],
                  position=a[:, 1:4], frame="enu", att_t=a[:, 0], att_q=a[:, 4:8],
                  att_source=f"{topic} orientation", vehicle_id=vehicle_id)
    if msgtype == "nav_msgs/msg/Odometry":
        log.speed = a[:, 8]
    return log
