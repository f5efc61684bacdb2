"""Bus messages as ROS 2 messages, and ROS 2 commands as bus messages (docs/ros2.md).

Frames (REP 103, REP 105): the world is ENU, frame :attr:`Converter.world_frame` (``map``);
glider ``<id>``'s body frame is ``glider_<id>`` (FLU); sonar ``<id>``'s frame at emission is
``sonar_<id>`` (x along the beam's axis). Every header stamp is sim time (``use_sim_time``).

- ``Odometry``: pose of ``glider_<id>`` in the world; twist in the body frame (REP 105), linear
  from airspeed along the heading plus ``vz``, angular the state's body rates.
- ``Imu``: orientation, body rates and specific force in the body frame (the change of the
  world velocity between two states of the glider, minus gravity); the first state of a glider
  has no acceleration (``linear_acceleration_covariance[0] = -1``, as ``sensor_msgs`` says).
- ``Image`` (the echo): ``32FC1``, one row per channel (ear), one column per sample, stamped at
  the ping's emission, frame ``sonar_<id>``; ``echo_info`` (``DiagnosticArray``, the same stamp)
  carries ``fs_hz`` and the rest of the echo's fields; ``PoseStamped`` the sonar's pose then.
- Commands: ``Float64MultiArray`` ``data = [bank_rad, airspeed_mps]`` (bank with the bus's sign).

The types published at state and echo rate (``Clock``, ``Odometry``, ``Imu``, ``Image``) are
returned serialised (:mod:`ros2_bridge.cdr`), the rest as rclpy messages; ``Publisher.publish``
takes either. A batch of states is prepared at once (:meth:`Converter.prepare`): attitudes,
body-frame velocities and the ``Odometry`` numbers of all of them in one pass of array algebra.
"""

from __future__ import annotations

import math
import operator
from typing import Any

import numpy as np
from builtin_interfaces.msg import Duration
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
from geometry_msgs.msg import Pose, PoseStamped, Vector3
from nav_msgs.msg import Odometry
from rosgraph_msgs.msg import Clock as RosClock
from sensor_msgs.msg import Image, Imu, PointCloud2, PointField
from std_msgs.msg import ColorRGBA, Float64MultiArray
from visualization_msgs.msg import Marker, MarkerArray

from hil_bridge.bus.messages import (
    Clock,
    Diagnostics,
    GliderCmd,
    GliderState,
    Message,
    PointCloud,
    SonarEcho,
    ThermalMarkers,
    state_quaternions,
)
from hil_bridge.recording.export.common import glider_velocities, sonar_pose, velocities_enu
from ros2_bridge import cdr
from ros2_bridge.cdr import MAX_TIME_NS
from sim_core.pose import quat_between, quat_conjugate, quat_rotate

__all__ = ["MAX_TIME_NS", "ROS_TYPES", "CommandError", "Converter", "G", "command_from_ros"]

#: standard gravity (m/s^2): specific force = acceleration + G up
G = 9.80665
#: ROS 2 type name -> class, for every type the bridge publishes or subscribes
ROS_TYPES: dict[str, type] = {
    "rosgraph_msgs/msg/Clock": RosClock,
    "nav_msgs/msg/Odometry": Odometry,
    "sensor_msgs/msg/Imu": Imu,
    "sensor_msgs/msg/Image": Image,
    "sensor_msgs/msg/PointCloud2": PointCloud2,
    "geometry_msgs/msg/PoseStamped": PoseStamped,
    "visualization_msgs/msg/MarkerArray": MarkerArray,
    "diagnostic_msgs/msg/DiagnosticArray": DiagnosticArray,
    "std_msgs/msg/Float64MultiArray": Float64MultiArray,
}
#: height of a thermal's cylinder and length of a beam's arrow (m)
THERMAL_HEIGHT_M = 200.0
BEAM_LENGTH_M = 3.0


class CommandError(ValueError):
    """A ROS 2 command the bus cannot carry (wrong length)."""


def command_from_ros(msg: Float64MultiArray, *, glider_id: int, stamp_ns: int,
                     step: int) -> GliderCmd:
    """The bus command of ``msg`` (``data = [bank_rad, airspeed_mps]``); ``CommandError``
    when ``data`` does not hold exactly two numbers. Non-finite values are passed on: the
    server rejects them and holds the last good command, as it does a CAN autopilot's."""
    data = list(msg.data)
    if len(data) != 2:
        raise CommandError(f"expected data = [bank_rad, airspeed_mps], got {len(data)} values")
    return GliderCmd(stamp_ns=stamp_ns, bank_cmd=float(data[0]), airspeed_cmd=float(data[1]),
                     glider_id=glider_id, step=step)


def _set_time(t: Any, ns: int) -> None:
    """``t`` (a ``Time``) := sim time ``ns``, clamped to ``[0, MAX_TIME_NS]``."""
    t.sec, t.nanosec = cdr.sec_nanosec(ns)


def _set_xyz(v: Any, x: float, y: float, z: float) -> None:
    v.x, v.y, v.z = float(x), float(y), float(z)


def _set_quat(o: Any, q: Any) -> None:
    o.w, o.x, o.y, o.z = float(q[0]), float(q[1]), float(q[2]), float(q[3])


def _finite(v: float) -> float:
    return float(v) if math.isfinite(v) else 0.0


def _pose(position: Any, q: Any) -> Pose:
    pose = Pose()
    _set_xyz(pose.position, *position)
    _set_quat(pose.orientation, q)
    return pose


#: the fields of a state the ``Odometry`` numbers come from, in the columns of one array
_KINEMATIC_FIELDS = operator.attrgetter("x", "y", "z", "qw", "qx", "qy", "qz", "heading",
                                        "airspeed", "vz", "roll_rate", "pitch_rate", "yaw_rate")


def _kinematics(states: list[GliderState]) -> dict[int, tuple[GliderState, Any, Any]]:
    """Per state (by ``id``): the state, its attitude (4,) and its ``Odometry`` row.

    The states' numbers go into one (K, 13) array at once: on the bridge's batches of one to
    nine states the frame algebra's cost is numpy's per call, not per state."""
    a = np.array([_KINEMATIC_FIELDS(st) for st in states], dtype=np.float64).reshape(-1, 13)
    q = a[:, 3:7]
    if not np.isfinite(q).all():  # a publisher that gave no attitude: the flight model's
        q = state_quaternions(states)
    body_v = quat_rotate(quat_conjugate(q), velocities_enu(a[:, 7], a[:, 8], a[:, 9]))
    rates = a[:, 10:13]
    rows = cdr.odometry_rows(a[:, 0:3], q, body_v, np.where(np.isfinite(rates), rates, 0.0))
    return {id(st): (st, q[k], rows[k]) for k, st in enumerate(states)}


class Converter:
    """Bus → ROS 2 conversions for one bridge (module docstring). ``convert(ros_type, ident,
    msg, ros_topic)`` returns the ROS 2 message (or its serialised bytes), or None when ``msg``
    does not carry what the type needs (an echo whose pose is unknown, for its pose)."""

    def __init__(self, world_frame: str = "map") -> None:
        self.world_frame = world_frame
        self._last_v: dict[str, tuple[int, Any]] = {}
        self._kinematics: dict[int, tuple[GliderState, Any, Any]] = {}

    def prepare(self, states: list[GliderState]) -> None:
        """Compute the attitudes, and the ``Odometry`` numbers (pose, body-frame twist), of K
        states at once (the frame algebra is vectorised; per state it would cost more than the
        rest of a conversion). Until the next call, converting one of them uses these."""
        self._kinematics = _kinematics(states)

    def _kinematics_of(self, st: GliderState) -> tuple[Any, Any]:
        """The attitude (4,) and ``Odometry`` row of ``st`` (from :meth:`prepare`, or computed
        now, and kept nowhere, for a state it was not given: another thread may be converting
        a prepared batch)."""
        kin = self._kinematics.get(id(st))
        if kin is None or kin[0] is not st:
            kin = _kinematics([st])[id(st)]
        return kin[1], kin[2]

    def convert(self, ros_type: str, ident: str, msg: Message, ros_topic: str) -> Any:
        if isinstance(msg, GliderState):
            return self._state(ros_type, ident or str(msg.glider_id), msg, ros_topic)
        if isinstance(msg, SonarEcho):
            return self._echo(ros_type, ident or str(msg.sonar_id), msg)
        if isinstance(msg, Clock) and ros_type == "rosgraph_msgs/msg/Clock":
            return cdr.clock(msg.stamp_ns)
        if isinstance(msg, PointCloud) and ros_type == "sensor_msgs/msg/PointCloud2":
            return self._cloud(msg)
        if isinstance(msg, ThermalMarkers) and ros_type == "visualization_msgs/msg/MarkerArray":
            return self._thermals(msg)
        if isinstance(msg, Diagnostics) and ros_type == "diagnostic_msgs/msg/DiagnosticArray":
            status = DiagnosticStatus(level=DiagnosticStatus.OK, name=msg.node,
                                      hardware_id=msg.node, message="counters")
            status.values = [KeyValue(key=k, value=repr(v)) for k, v in msg.counters.items()]
            array = DiagnosticArray(status=[status])
            _set_time(array.header.stamp, msg.stamp_ns)
            return array
        raise TypeError(f"no conversion of {type(msg).TYPE} to {ros_type}")

    # ------------------------------------------------------------------ states

    def _state(self, ros_type: str, gid: str, st: GliderState, ros_topic: str) -> Any:
        q, row = self._kinematics_of(st)
        if ros_type == "nav_msgs/msg/Odometry":
            return cdr.odometry(st.stamp_ns, self.world_frame, f"glider_{gid}", row)
        if ros_type == "sensor_msgs/msg/Imu":
            return self._imu(gid, st, q, ros_topic)
        if ros_type == "geometry_msgs/msg/PoseStamped":
            pose = PoseStamped(pose=_pose((st.x, st.y, st.z), q))
            _set_time(pose.header.stamp, st.stamp_ns)
            pose.header.frame_id = self.world_frame
            return pose
        if ros_type == "visualization_msgs/msg/MarkerArray":
            marker = self._marker("gliders", int(gid), Marker.ARROW, st.stamp_ns,
                                  _pose((st.x, st.y, st.z), q), (3.0, 0.6, 0.6),
                                  (0.1, 0.5, 0.9, 1.0) if st.alive else (0.5, 0.5, 0.5, 0.6))
            return MarkerArray(markers=[marker])
        raise TypeError(f"no conversion of {GliderState.TYPE} to {ros_type}")

    def _imu(self, gid: str, st: GliderState, q: Any, ros_topic: str) -> bytes:
        v = glider_velocities([st])[0]
        key = ros_topic + "#" + gid
        last = self._last_v.get(key)
        self._last_v[key] = (st.stamp_ns, v)
        known = last is not None and st.stamp_ns > last[0]
        specific_force = np.zeros(3)
        if known and last is not None:
            accel = (v - last[1]) / ((st.stamp_ns - last[0]) * 1e-9)
            accel[2] += G
            specific_force = quat_rotate(quat_conjugate(q), accel)
        rates = [_finite(st.roll_rate), _finite(st.pitch_rate), _finite(st.yaw_rate)]
        return cdr.imu(st.stamp_ns, f"glider_{gid}", q, rates, specific_force,
                       acceleration_known=known)

    # ------------------------------------------------------------------ echoes

    def _echo(self, ros_type: str, sid: str, echo: SonarEcho) -> Any:
        emit_ns = echo.emit_ns if echo.emit_ns > 0 else echo.stamp_ns
        if ros_type == "sensor_msgs/msg/Image":
            return cdr.image(emit_ns, f"sonar_{sid}", np.atleast_2d(echo.samples))
        if ros_type == "diagnostic_msgs/msg/DiagnosticArray":
            samples = np.atleast_2d(echo.samples)
            values = {"fs_hz": echo.fs, "ping_seq": echo.ping_seq,
                      "channels": samples.shape[0], "samples": samples.shape[1],
                      "emit_ns": emit_ns, "stamp_ns": echo.stamp_ns,
                      "leaves_in_beam": echo.leaves_in_beam, "dropped": echo.dropped,
                      "fidelity": echo.fidelity, "error_bound": echo.error_bound,
                      "compute_ns": echo.compute_ns}
            status = DiagnosticStatus(level=DiagnosticStatus.OK, name=f"sonar {sid} echo",
                                      hardware_id=f"sonar_{sid}", message="echo")
            status.values = [KeyValue(key=k, value=str(v)) for k, v in values.items()]
            array = DiagnosticArray(status=[status])
            _set_time(array.header.stamp, emit_ns)
            return array
        pose = sonar_pose(echo, None, None)
        if pose is None:
            return None
        if ros_type == "geometry_msgs/msg/PoseStamped":
            out = PoseStamped(pose=_pose(pose.position, pose.orientation))
            _set_time(out.header.stamp, emit_ns)
            out.header.frame_id = self.world_frame
            return out
        if ros_type == "visualization_msgs/msg/MarkerArray":
            q = quat_between([1.0, 0.0, 0.0], pose.boresight)
            marker = self._marker("beams", int(sid), Marker.ARROW, emit_ns,
                                  _pose(pose.position, q), (BEAM_LENGTH_M, 0.05, 0.05),
                                  (0.2, 0.9, 0.3, 0.8))
            return MarkerArray(markers=[marker])
        raise TypeError(f"no conversion of {SonarEcho.TYPE} to {ros_type}")

    # ------------------------------------------------------------------ world

    def _cloud(self, pc: PointCloud) -> PointCloud2:
        n = pc.points.shape[0]
        packed = np.zeros((n, 4), dtype="<f4")
        packed[:, :3] = pc.points
        if pc.intensity.size:
            packed[:, 3] = pc.intensity
        fields = [PointField(name=name, offset=4 * i, datatype=PointField.FLOAT32, count=1)
                  for i, name in enumerate(("x", "y", "z", "intensity"))]
        cloud = PointCloud2(height=1, width=n, fields=fields, is_bigendian=False, point_step=16,
                            row_step=16 * n, is_dense=True)
        _set_time(cloud.header.stamp, pc.stamp_ns)
        cloud.header.frame_id = self.world_frame
        cloud.data = packed.tobytes()
        return cloud

    def _thermals(self, th: ThermalMarkers) -> MarkerArray:
        markers = []
        for k in range(len(th.x)):
            d = 2.0 * float(th.radius[k])
            marker = self._marker("thermals", k, Marker.CYLINDER, th.stamp_ns,
                                  _pose((th.x[k], th.y[k], THERMAL_HEIGHT_M / 2),
                                        (1.0, 0.0, 0.0, 0.0)),
                                  (d, d, THERMAL_HEIGHT_M), (1.0, 0.55, 0.0, 0.25))
            marker.text = f"w_max {float(th.w_max[k]):.2f} m/s"
            markers.append(marker)
        return MarkerArray(markers=markers)

    def _marker(self, ns: str, ident: int, kind: int, stamp_ns: int, pose: Pose,
                scale: tuple[float, float, float], rgba: tuple[float, ...]) -> Marker:
        marker = Marker(ns=ns, id=ident, type=kind, action=Marker.ADD, pose=pose,
                        scale=Vector3(x=scale[0], y=scale[1], z=scale[2]),
                        color=ColorRGBA(r=rgba[0], g=rgba[1], b=rgba[2], a=rgba[3]),
                        lifetime=Duration(sec=0, nanosec=0), frame_locked=False)
        _set_time(marker.header.stamp, stamp_ns)
        marker.header.frame_id = self.world_frame
        return marker
