"""A recording as a ROS 2 bag: one MCAP file (profile ``ros2``, CDR messages, ``ros2msg``
schemas) that ``ros2 bag info/play`` and Foxglove open natively (``bag export IN --ros2 OUT``).

- ``/clock`` → ``rosgraph_msgs/msg/Clock``;
- ``/glider/<id>/state`` → ``nav_msgs/msg/Odometry``: header stamp = sim time, frame ``map``,
  child ``glider_<id>``, twist in the child frame; the same poses on ``/tf``
  (``tf2_msgs/msg/TFMessage``, ``map`` → ``glider_<id>``);
- ``/forest/points`` → ``sensor_msgs/msg/PointCloud2`` (float32 x, y, z, intensity = leaf
  radius m), latched;
- ``/thermals`` → ``visualization_msgs/msg/MarkerArray`` (a cylinder per thermal, 200 m tall),
  latched;
- ``/sonar/<id>/echo`` → ``echoloop_msgs/msg/SonarEcho`` (samples, the sonar pose at emission);
- ``/sonar/<id>/ping`` → ``echoloop_msgs/msg/SonarPing``;
- ``/glider/<id>/cmd`` → ``echoloop_msgs/msg/GliderCmd``.

Headers carry sim time (so play with ``--clock``/``use_sim_time``); the MCAP ``log_time`` is
the recorded receive time, ``publish_time`` the sim stamp. The ``echoloop_msgs`` definitions
ship in ``hil_bridge/recording/export/msg`` and are embedded in the file, like every other schema.
Other topics (neighbours, diagnostics, acks) are counted as skipped. Attitudes: see
:mod:`hil_bridge.recording.export.common`.
"""

from __future__ import annotations

import os
from pathlib import Path
from typing import Any

import numpy as np
from mcap.writer import CompressionType, Writer

from hil_bridge.bus.messages import (
    Clock,
    GliderCmd,
    GliderState,
    PointCloud,
    SonarEcho,
    SonarPing,
    ThermalMarkers,
    state_quaternions,
)
from hil_bridge.outputs import atomic_output
from hil_bridge.recording.export.cdr import encoder, msgdef
from hil_bridge.recording.export.common import (
    STATE_TOPIC,
    ExportCounts,
    batches,
    decoded,
    glider_velocities,
    mount_id,
    sonar_pose,
)
from sim_core.pose import quat_conjugate, quat_rotate

__all__ = ["FRAME", "export_ros2"]

FRAME = "map"
THERMAL_HEIGHT_M = 200.0
_LATCHED_QOS = (
    "- history: 3\n  depth: 0\n  reliability: 1\n  durability: 1\n"
    "  deadline:\n    sec: 2147483647\n    nsec: 4294967295\n"
    "  lifespan:\n    sec: 2147483647\n    nsec: 4294967295\n  liveliness: 1\n"
    "  liveliness_lease_duration:\n    sec: 2147483647\n    nsec: 4294967295\n"
    "  avoid_ros_namespace_conventions: false\n"
)
_VOLATILE_QOS = _LATCHED_QOS.replace("durability: 1", "durability: 2")


def _time(ns: int) -> dict[str, int]:
    return {"sec": ns // 1_000_000_000, "nanosec": ns % 1_000_000_000}


def _header(ns: int, frame: str = FRAME) -> dict[str, Any]:
    return {"stamp": _time(ns), "frame_id": frame}


def _quat(q: Any) -> dict[str, float]:
    return {"w": float(q[0]), "x": float(q[1]), "y": float(q[2]), "z": float(q[3])}


def _xyz(v: Any) -> dict[str, float]:
    return {"x": float(v[0]), "y": float(v[1]), "z": float(v[2])}


class _Bag:
    """An MCAP writer with one schema per type and one channel per topic."""

    def __init__(self, stream: Any) -> None:
        self.writer = Writer(stream, chunk_size=1024 * 1024, compression=CompressionType.ZSTD)
        self.writer.start(profile="ros2", library="echoloop hil_bridge.recording.export.ros2")
        self.schemas: dict[str, int] = {}
        self.channels: dict[str, tuple[int, Any]] = {}

    def write(self, topic: str, type_name: str, message: dict[str, Any], log_time: int,
              stamp_ns: int, latched: bool = False) -> None:
        entry = self.channels.get(topic)
        if entry is None:
            sid = self.schemas.get(type_name)
            if sid is None:
                sid = self.writer.register_schema(type_name, "ros2msg",
                                                  msgdef(type_name).encode())
                self.schemas[type_name] = sid
            cid = self.writer.register_channel(
                topic, "cdr", sid,
                {"offered_qos_profiles": _LATCHED_QOS if latched else _VOLATILE_QOS})
            entry = self.channels[topic] = (cid, encoder(type_name))
        cid, encode = entry
        self.writer.add_message(cid, log_time=log_time, data=encode(message),
                                publish_time=max(0, stamp_ns))


def _odometry(gid: int, st: GliderState, q: Any, body_v: Any) -> dict[str, Any]:
    rates = [getattr(st, k, 0.0) for k in ("roll_rate", "pitch_rate", "yaw_rate")]
    return {
        "header": _header(st.stamp_ns), "child_frame_id": f"glider_{gid}",
        "pose": {"pose": {"position": _xyz((st.x, st.y, st.z)), "orientation": _quat(q)}},
        "twist": {"twist": {"linear": _xyz(body_v), "angular": _xyz(rates)}},
    }


def _point_cloud(pc: PointCloud) -> dict[str, Any]:
    n = pc.points.shape[0]
    packed = np.zeros((n, 4), dtype="<f4")
    packed[:, :3] = pc.points
    if pc.intensity.size:
        packed[:, 3] = pc.intensity
    fields = [{"name": name, "offset": 4 * i, "datatype": 7, "count": 1}
              for i, name in enumerate(("x", "y", "z", "intensity"))]
    return {"header": _header(pc.stamp_ns), "height": 1, "width": n, "fields": fields,
            "is_bigendian": False, "point_step": 16, "row_step": 16 * n,
            "data": packed.tobytes(), "is_dense": True}


def _thermal_markers(th: ThermalMarkers) -> dict[str, Any]:
    markers = []
    for k in range(len(th.x)):
        d = 2.0 * float(th.radius[k])
        markers.append({
            "header": _header(th.stamp_ns), "ns": "thermals", "id": k, "type": 3, "action": 0,
            "pose": {"position": _xyz((th.x[k], th.y[k], THERMAL_HEIGHT_M / 2)),
                     "orientation": {"w": 1.0}},
            "scale": _xyz((d, d, THERMAL_HEIGHT_M)),
            "color": {"r": 1.0, "g": 0.55, "b": 0.0, "a": 0.25},
            "text": f"w_max {float(th.w_max[k]):.2f} m/s",
        })
    return {"markers": markers}


def _sonar_echo(echo: SonarEcho, pose: Any) -> dict[str, Any]:
    samples = np.atleast_2d(echo.samples)
    out: dict[str, Any] = {
        "header": _header(echo.stamp_ns), "sonar_id": echo.sonar_id, "ping_seq": echo.ping_seq,
        "fs": echo.fs, "channels": samples.shape[0], "n_samples": samples.shape[1],
        "samples": samples, "leaves_in_beam": echo.leaves_in_beam, "dropped": echo.dropped,
        "fidelity": echo.fidelity, "error_bound": echo.error_bound,
        "compute_ns": echo.compute_ns, "pose_known": pose is not None,
    }
    if pose is not None:
        out["sonar_pose"] = {"position": _xyz(pose.position),
                             "orientation": _quat(pose.orientation)}
        out["boresight"] = _xyz(pose.boresight)
    return out


def export_ros2(src: str | os.PathLike[str], dst: str | os.PathLike[str], *,
                overwrite: bool = False) -> ExportCounts:
    """Write the ROS 2 bag ``dst`` from the recording ``src`` (module docstring)."""
    counts = ExportCounts()
    last_state: dict[int, Any] = {}
    pings: dict[tuple[int, int], Any] = {}
    with atomic_output(Path(dst), overwrite=overwrite, inputs=[src]) as tmp, \
            open(tmp, "wb") as fh:
        bag = _Bag(fh)
        for batch in batches(decoded(src, counts)):
            states = [d.msg for d in batch if isinstance(d.msg, GliderState)]
            quats = state_quaternions(states)
            body_v = quat_rotate(quat_conjugate(quats), glider_velocities(states))
            k = 0
            for d in batch:
                if isinstance(d.msg, GliderState):
                    _write_state(bag, d, quats[k], body_v[k], last_state)
                    counts.written += 2
                    k += 1
                elif _write_other(bag, d, last_state, pings):
                    counts.written += 1
                else:
                    counts.skip(f"no ROS 2 type for {d.raw.header.type}")
        bag.writer.finish()
    return counts


def _write_state(bag: _Bag, d: Any, q: Any, body_v: Any, last_state: dict[int, Any]) -> None:
    msg, log_t, topic = d.msg, d.raw.log_time, d.topic
    hit = STATE_TOPIC.match(topic)
    gid = int(hit.group(1)) if hit else msg.glider_id
    last_state[gid] = msg
    bag.write(topic, "nav_msgs/msg/Odometry", _odometry(gid, msg, q, body_v), log_t,
              msg.stamp_ns)
    bag.write("/tf", "tf2_msgs/msg/TFMessage", {"transforms": [{
        "header": _header(msg.stamp_ns), "child_frame_id": f"glider_{gid}",
        "transform": {"translation": _xyz((msg.x, msg.y, msg.z)), "rotation": _quat(q)}}]},
        log_t, msg.stamp_ns)


def _write_other(bag: _Bag, d: Any, last_state: dict[int, Any],
                 pings: dict[tuple[int, int], Any]) -> bool:
    """Write one non-state message; False when it has no ROS 2 type here."""
    msg, log_t, topic = d.msg, d.raw.log_time, d.topic
    if isinstance(msg, Clock):
        bag.write(topic, "rosgraph_msgs/msg/Clock", {"clock": _time(msg.stamp_ns)},
                  log_t, msg.stamp_ns)
    elif isinstance(msg, PointCloud):
        bag.write(topic, "sensor_msgs/msg/PointCloud2", _point_cloud(msg), log_t,
                  msg.stamp_ns, latched=True)
    elif isinstance(msg, ThermalMarkers):
        bag.write(topic, "visualization_msgs/msg/MarkerArray", _thermal_markers(msg),
                  log_t, msg.stamp_ns, latched=True)
    elif isinstance(msg, SonarPing):
        pings[(msg.sonar_id, msg.ping_seq)] = msg
        bag.write(topic, "echoloop_msgs/msg/SonarPing", {
            "header": _header(msg.stamp_ns), "sonar_id": msg.sonar_id,
            "ping_seq": msg.ping_seq, "az": msg.az, "el": msg.el,
            "beamwidth": msg.beamwidth, "encoding": msg.encoding}, log_t, msg.stamp_ns)
    elif isinstance(msg, SonarEcho):
        mount = mount_id(d.raw.header.frame_id)
        pose = sonar_pose(msg, pings.get((msg.sonar_id, msg.ping_seq)),
                          None if mount is None else last_state.get(mount))
        bag.write(topic, "echoloop_msgs/msg/SonarEcho", _sonar_echo(msg, pose), log_t,
                  msg.stamp_ns)
    elif isinstance(msg, GliderCmd):
        bag.write(topic, "echoloop_msgs/msg/GliderCmd", {
            "header": _header(msg.stamp_ns), "glider_id": msg.glider_id,
            "bank_cmd": msg.bank_cmd, "airspeed_cmd": msg.airspeed_cmd,
            "step": msg.step}, log_t, msg.stamp_ns)
    else:
        return False
    return True
