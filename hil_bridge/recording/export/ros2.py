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

Types come from one ROS 2 distribution, :data:`DISTRO` (Jazzy Jalisco): the type store rosbags
ships for it (``Stores.ROS2_JAZZY``), which serialises every message (CDR, little-endian) and
gives every schema (its ``generate_msgdef`` text: the type, then each dependency after a line of
80 ``=`` and ``MSG: pkg/Type``, as rosbag2 embeds it). Jazzy is the ROS 2 LTS release of
Ubuntu 24.04 (May 2024), supported to May 2029 (REP 2000); the standard types used here have
the same fields in rosbags' Humble, Jazzy, Kilted and Lyrical stores (only constants differ).
echoloop's own types (``echoloop_msgs``) are ``.msg`` files in
``hil_bridge/recording/export/msg/echoloop_msgs/msg``, registered into that store
(:func:`typestore`).

Headers carry sim time (so play with ``--clock``/``use_sim_time``); the MCAP ``log_time`` is
the recorded receive time, ``publish_time`` the sim stamp. Other topics (neighbours,
diagnostics, acks) are counted as skipped. Attitudes: see
:mod:`hil_bridge.recording.export.common`.
"""

from __future__ import annotations

import os
from functools import cache
from pathlib import Path
from typing import Any

import numpy as np
from mcap.writer import CompressionType, Writer
from rosbags.typesys import Stores, get_types_from_msg, get_typestore
from rosbags.typesys.store import Typestore

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

__all__ = ["DISTRO", "FRAME", "STORE", "export_ros2", "typestore"]

#: the ROS 2 distribution whose types the bag holds (module docstring), and its rosbags store
#: (also the one :mod:`hil_bridge.recording.logs.rosbag` reads bags without definitions with)
DISTRO = "jazzy"
STORE = Stores.ROS2_JAZZY
MSG_DIR = Path(__file__).with_name("msg")
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


@cache
def typestore() -> Typestore:
    """The :data:`DISTRO` type store with ``echoloop_msgs`` registered (built once)."""
    store = get_typestore(STORE)
    types = {}
    for path in sorted((MSG_DIR / "echoloop_msgs" / "msg").glob("*.msg")):
        types.update(get_types_from_msg(path.read_text(encoding="utf-8"),
                                        f"echoloop_msgs/msg/{path.stem}"))
    store.register(types)
    return store


def _new(type_name: str) -> Any:
    """The message class of ``type_name`` in :func:`typestore`."""
    return typestore().types[type_name]


def _time(ns: int) -> Any:
    return _new("builtin_interfaces/msg/Time")(sec=ns // 1_000_000_000,
                                               nanosec=ns % 1_000_000_000)


def _header(ns: int, frame: str = FRAME) -> Any:
    return _new("std_msgs/msg/Header")(stamp=_time(ns), frame_id=frame)


def _quat(q: Any) -> Any:
    return _new("geometry_msgs/msg/Quaternion")(x=float(q[1]), y=float(q[2]), z=float(q[3]),
                                                w=float(q[0]))


def _xyz(kind: str, v: Any) -> Any:
    """A ``geometry_msgs/msg/<kind>`` (``Point`` or ``Vector3``) of ``v`` (3,)."""
    return _new(f"geometry_msgs/msg/{kind}")(x=float(v[0]), y=float(v[1]), z=float(v[2]))


def _pose(position: Any, q: Any) -> Any:
    return _new("geometry_msgs/msg/Pose")(position=_xyz("Point", position), orientation=_quat(q))


class _Bag:
    """An MCAP writer with one schema per type and one channel per topic; messages are
    serialised by :func:`typestore` and each schema is its definition."""

    def __init__(self, stream: Any) -> None:
        self.store = typestore()
        self.writer = Writer(stream, chunk_size=1024 * 1024, compression=CompressionType.ZSTD)
        self.writer.start(profile="ros2", library="echoloop hil_bridge.recording.export.ros2")
        self.schemas: dict[str, int] = {}
        self.channels: dict[str, int] = {}

    def write(self, topic: str, type_name: str, message: Any, log_time: int, stamp_ns: int,
              latched: bool = False) -> None:
        cid = self.channels.get(topic)
        if cid is None:
            sid = self.schemas.get(type_name)
            if sid is None:
                text, _ = self.store.generate_msgdef(type_name, ros_version=2)
                sid = self.schemas[type_name] = self.writer.register_schema(
                    type_name, "ros2msg", text.encode())
            cid = self.channels[topic] = self.writer.register_channel(
                topic, "cdr", sid,
                {"offered_qos_profiles": _LATCHED_QOS if latched else _VOLATILE_QOS})
        data = self.store.serialize_cdr(message, type_name, little_endian=True)
        self.writer.add_message(cid, log_time=log_time, data=bytes(data),
                                publish_time=max(0, stamp_ns))


def _odometry(gid: int, st: GliderState, q: Any, body_v: Any) -> Any:
    rates = [getattr(st, k, 0.0) for k in ("roll_rate", "pitch_rate", "yaw_rate")]
    return _new("nav_msgs/msg/Odometry")(
        header=_header(st.stamp_ns), child_frame_id=f"glider_{gid}",
        pose=_new("geometry_msgs/msg/PoseWithCovariance")(
            pose=_pose((st.x, st.y, st.z), q), covariance=np.zeros(36)),
        twist=_new("geometry_msgs/msg/TwistWithCovariance")(
            twist=_new("geometry_msgs/msg/Twist")(linear=_xyz("Vector3", body_v),
                                                  angular=_xyz("Vector3", rates)),
            covariance=np.zeros(36)),
    )


def _transforms(gid: int, st: GliderState, q: Any) -> Any:
    transform = _new("geometry_msgs/msg/Transform")(
        translation=_xyz("Vector3", (st.x, st.y, st.z)), rotation=_quat(q))
    return _new("tf2_msgs/msg/TFMessage")(transforms=[
        _new("geometry_msgs/msg/TransformStamped")(
            header=_header(st.stamp_ns), child_frame_id=f"glider_{gid}", transform=transform)])


def _point_cloud(pc: PointCloud) -> Any:
    n = pc.points.shape[0]
    packed = np.zeros((n, 4), dtype="<f4")
    packed[:, :3] = pc.points
    if pc.intensity.size:
        packed[:, 3] = pc.intensity
    field = _new("sensor_msgs/msg/PointField")
    fields = [field(name=name, offset=4 * i, datatype=field.FLOAT32, count=1)
              for i, name in enumerate(("x", "y", "z", "intensity"))]
    return _new("sensor_msgs/msg/PointCloud2")(
        header=_header(pc.stamp_ns), height=1, width=n, fields=fields, is_bigendian=False,
        point_step=16, row_step=16 * n, data=packed.reshape(-1).view(np.uint8), is_dense=True)


def _thermal_markers(th: ThermalMarkers) -> Any:
    marker = _new("visualization_msgs/msg/Marker")
    empty = np.zeros(0, dtype=np.uint8)
    texture = _new("sensor_msgs/msg/CompressedImage")(header=_header(0, ""), format="",
                                                      data=empty)
    mesh = _new("visualization_msgs/msg/MeshFile")(filename="", data=empty)
    color = _new("std_msgs/msg/ColorRGBA")(r=1.0, g=0.55, b=0.0, a=0.25)
    markers = []
    for k in range(len(th.x)):
        d = 2.0 * float(th.radius[k])
        markers.append(marker(
            header=_header(th.stamp_ns), ns="thermals", id=k, type=marker.CYLINDER,
            action=marker.ADD, pose=_pose((th.x[k], th.y[k], THERMAL_HEIGHT_M / 2),
                                          (1.0, 0.0, 0.0, 0.0)),
            scale=_xyz("Vector3", (d, d, THERMAL_HEIGHT_M)), color=color,
            lifetime=_new("builtin_interfaces/msg/Duration")(sec=0, nanosec=0),
            frame_locked=False, points=[], colors=[], texture_resource="", texture=texture,
            uv_coordinates=[], text=f"w_max {float(th.w_max[k]):.2f} m/s", mesh_resource="",
            mesh_file=mesh, mesh_use_embedded_materials=False,
        ))
    return _new("visualization_msgs/msg/MarkerArray")(markers=markers)


def _sonar_echo(echo: SonarEcho, pose: Any) -> Any:
    """An ``echoloop_msgs/msg/SonarEcho``; an echo nothing locates has ``pose_known`` false
    and a zero position, identity orientation and zero boresight."""
    samples = np.atleast_2d(echo.samples)
    if pose is None:
        sonar, bore = _pose((0.0, 0.0, 0.0), (1.0, 0.0, 0.0, 0.0)), (0.0, 0.0, 0.0)
    else:
        sonar, bore = _pose(pose.position, pose.orientation), pose.boresight
    return _new("echoloop_msgs/msg/SonarEcho")(
        header=_header(echo.stamp_ns), sonar_id=echo.sonar_id, ping_seq=echo.ping_seq,
        fs=echo.fs, channels=samples.shape[0], n_samples=samples.shape[1],
        samples=np.ascontiguousarray(samples, dtype=np.float32).reshape(-1),
        leaves_in_beam=echo.leaves_in_beam, dropped=echo.dropped, fidelity=echo.fidelity,
        error_bound=echo.error_bound, compute_ns=echo.compute_ns, pose_known=pose is not None,
        sonar_pose=sonar, boresight=_xyz("Vector3", bore),
    )


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
    bag.write("/tf", "tf2_msgs/msg/TFMessage", _transforms(gid, msg, q), log_t, msg.stamp_ns)


def _write_other(bag: _Bag, d: Any, last_state: dict[int, Any],
                 pings: dict[tuple[int, int], Any]) -> bool:
    """Write one non-state message; False when it has no ROS 2 type here."""
    msg, log_t, topic = d.msg, d.raw.log_time, d.topic
    if isinstance(msg, Clock):
        bag.write(topic, "rosgraph_msgs/msg/Clock",
                  _new("rosgraph_msgs/msg/Clock")(clock=_time(msg.stamp_ns)), log_t,
                  msg.stamp_ns)
    elif isinstance(msg, PointCloud):
        bag.write(topic, "sensor_msgs/msg/PointCloud2", _point_cloud(msg), log_t,
                  msg.stamp_ns, latched=True)
    elif isinstance(msg, ThermalMarkers):
        bag.write(topic, "visualization_msgs/msg/MarkerArray", _thermal_markers(msg),
                  log_t, msg.stamp_ns, latched=True)
    elif isinstance(msg, SonarPing):
        pings[(msg.sonar_id, msg.ping_seq)] = msg
        bag.write(topic, "echoloop_msgs/msg/SonarPing", _new("echoloop_msgs/msg/SonarPing")(
            header=_header(msg.stamp_ns), sonar_id=msg.sonar_id, ping_seq=msg.ping_seq,
            az=msg.az, el=msg.el, beamwidth=msg.beamwidth, encoding=msg.encoding),
            log_t, msg.stamp_ns)
    elif isinstance(msg, SonarEcho):
        mount = mount_id(d.raw.header.frame_id)
        pose = sonar_pose(msg, pings.get((msg.sonar_id, msg.ping_seq)),
                          None if mount is None else last_state.get(mount))
        bag.write(topic, "echoloop_msgs/msg/SonarEcho", _sonar_echo(msg, pose), log_t,
                  msg.stamp_ns)
    elif isinstance(msg, GliderCmd):
        bag.write(topic, "echoloop_msgs/msg/GliderCmd", _new("echoloop_msgs/msg/GliderCmd")(
            header=_header(msg.stamp_ns), glider_id=msg.glider_id, bank_cmd=msg.bank_cmd,
            airspeed_cmd=msg.airspeed_cmd, step=msg.step), log_t, msg.stamp_ns)
    else:
        return False
    return True
