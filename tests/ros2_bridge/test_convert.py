"""Bus messages as ROS 2 messages (ros2_bridge.convert): closed forms for the frames (REP 103/105),
layouts a plain ROS 2 node decodes without echoloop, and commands in. Only the message classes
are used here (no rclpy context: the live bridge is tested in processes of its own); the types
the bridge serialises itself are decoded with rosbags (test_cdr.py holds those encodings to
rosbags' own)."""

from __future__ import annotations

import math
from typing import Any

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

pytest.importorskip("nav_msgs", reason="the 'ros2' extra is not installed")

from std_msgs.msg import Float64MultiArray

from hil_bridge.bus.messages import (
    Clock,
    Diagnostics,
    GliderState,
    PointCloud,
    SonarEcho,
    ThermalMarkers,
)
from hil_bridge.recording.export.ros2 import typestore
from ros2_bridge.convert import (
    MAX_TIME_NS,
    CommandError,
    Converter,
    G,
    command_from_ros,
)
from sim_core.pose import quat_from_euler


def _state(stamp_ns: int, *, heading: float, airspeed: float, vz: float = 0.0,
           roll: float = 0.0, pitch: float = 0.0) -> GliderState:
    q = quat_from_euler(roll, pitch, heading)
    return GliderState(stamp_ns=stamp_ns, x=1.0, y=2.0, z=30.0, heading=heading, bank=-roll,
                       airspeed=airspeed, vz=vz, glider_id=4, qw=q[0], qx=q[1], qy=q[2],
                       qz=q[3], roll_rate=0.01, pitch_rate=0.02, yaw_rate=0.03)


def _ros(data: bytes, type_name: str) -> Any:
    """A message the converter returned serialised, decoded."""
    assert isinstance(data, bytes)
    return typestore().deserialize_cdr(data, type_name)


def test_odometry_pose_in_the_world_and_twist_in_the_body_frame() -> None:
    st_ = _state(1_500_000_000, heading=math.pi / 2, airspeed=10.0, vz=-1.0)
    odom = _ros(Converter().convert("nav_msgs/msg/Odometry", "4", st_, "/glider_4/odom"),
                "nav_msgs/msg/Odometry")
    assert (odom.header.stamp.sec, odom.header.stamp.nanosec) == (1, 500_000_000)
    assert (odom.header.frame_id, odom.child_frame_id) == ("map", "glider_4")
    p, q = odom.pose.pose.position, odom.pose.pose.orientation
    assert (p.x, p.y, p.z) == (1.0, 2.0, 30.0)
    assert (q.w, q.x, q.y, q.z) == (st_.qw, st_.qx, st_.qy, st_.qz)
    v = odom.twist.twist.linear  # flying north (ENU +y) at 10 m/s, sinking 1 m/s: body x, z
    np.testing.assert_allclose([v.x, v.y, v.z], [10.0, 0.0, -1.0], atol=1e-12)
    w = odom.twist.twist.angular
    assert (w.x, w.y, w.z) == (0.01, 0.02, 0.03)


def test_imu_specific_force_is_gravity_up_in_steady_flight_plus_the_acceleration() -> None:
    conv = Converter()

    def imu(state: GliderState) -> Any:
        return _ros(conv.convert("sensor_msgs/msg/Imu", "4", state, "/glider_4/imu"),
                    "sensor_msgs/msg/Imu")

    first = imu(_state(0, heading=0.0, airspeed=10.0))
    assert first.linear_acceleration_covariance[0] == -1.0  # no acceleration known yet
    steady = imu(_state(100_000_000, heading=0.0, airspeed=10.0))
    a = steady.linear_acceleration
    np.testing.assert_allclose([a.x, a.y, a.z], [0.0, 0.0, G], atol=1e-9)
    assert steady.linear_acceleration_covariance[0] == 0.0
    faster = imu(_state(600_000_000, heading=0.0, airspeed=11.0))
    a = faster.linear_acceleration  # +1 m/s in 0.5 s along the body's x
    np.testing.assert_allclose([a.x, a.y, a.z], [2.0, 0.0, G], atol=1e-9)
    assert faster.header.frame_id == "glider_4"


def _echo(**changes: object) -> SonarEcho:
    fields: dict[str, object] = {
        "stamp_ns": 2_000_000_000, "ping_seq": 7, "fs": 400_000.0,
        "samples": np.arange(10, dtype=np.float32).reshape(2, 5) / 7, "leaves_in_beam": 12,
        "fidelity": "fast", "sonar_id": 3, "position": np.array([1.0, 2.0, 3.0]),
        "orientation": np.array([1.0, 0.0, 0.0, 0.0]), "boresight": np.array([0.0, 1.0, 0.0]),
        "emit_ns": 1_990_000_000}
    fields.update(changes)
    return SonarEcho(**fields)  # type: ignore[arg-type]


def test_an_echo_is_an_image_any_node_decodes_stamped_at_emission() -> None:
    echo = _echo()
    image = _ros(Converter().convert("sensor_msgs/msg/Image", "3", echo, "/sonar_3/echo"),
                 "sensor_msgs/msg/Image")
    assert (image.height, image.width, image.encoding, image.step) == (2, 5, "32FC1", 20)
    assert image.header.frame_id == "sonar_3"
    assert image.header.stamp.sec * 10**9 + image.header.stamp.nanosec == echo.emit_ns
    samples = np.frombuffer(image.data.tobytes(), dtype="<f4").reshape(image.height, image.width)
    np.testing.assert_array_equal(samples, echo.samples)
    old = _ros(Converter().convert("sensor_msgs/msg/Image", "3", _echo(emit_ns=0), "/s"),
               "sensor_msgs/msg/Image")
    assert old.header.stamp.sec == 2  # no emission given: the echo's stamp


def test_echo_info_carries_the_sample_rate_and_the_pose_is_the_emission_pose() -> None:
    conv = Converter()
    info = conv.convert("diagnostic_msgs/msg/DiagnosticArray", "3", _echo(), "/sonar_3/echo_info")
    values = {kv.key: kv.value for kv in info.status[0].values}
    assert float(values["fs_hz"]) == 400_000.0 and values["ping_seq"] == "7"
    assert (values["channels"], values["samples"]) == ("2", "5")
    pose = conv.convert("geometry_msgs/msg/PoseStamped", "3", _echo(), "/sonar_3/pose")
    p, q = pose.pose.position, pose.pose.orientation
    assert (p.x, p.y, p.z) == (1.0, 2.0, 3.0)
    # sonar x along the boresight (world +y): a quarter turn about z
    np.testing.assert_allclose([q.w, q.x, q.y, q.z], [math.sqrt(0.5), 0, 0, math.sqrt(0.5)],
                               atol=1e-12)
    unknown = _echo(position=np.full(3, np.nan))
    assert conv.convert("geometry_msgs/msg/PoseStamped", "3", unknown, "/sonar_3/pose") is None


def test_world_messages() -> None:
    conv = Converter("world")
    pts = np.array([[0, 1, 2], [3, 4, 5]], dtype=np.float32)
    cloud = conv.convert("sensor_msgs/msg/PointCloud2", "",
                         PointCloud(stamp_ns=5, points=pts,
                                    intensity=np.array([0.1, 0.2], np.float32)), "/forest/points")
    packed = np.frombuffer(bytes(cloud.data), dtype="<f4").reshape(cloud.width, 4)
    np.testing.assert_array_equal(packed[:, :3], pts)
    assert [f.name for f in cloud.fields] == ["x", "y", "z", "intensity"]
    assert cloud.header.frame_id == "world"
    th = ThermalMarkers(stamp_ns=0, x=np.array([10.0, 20.0]), y=np.array([0.0, 5.0]),
                        radius=np.array([30.0, 40.0]), w_max=np.array([2.0, 3.0]))
    markers = conv.convert("visualization_msgs/msg/MarkerArray", "", th, "/thermals").markers
    assert [(m.pose.position.x, m.scale.x) for m in markers] == [(10.0, 60.0), (20.0, 80.0)]
    diag = conv.convert("diagnostic_msgs/msg/DiagnosticArray", "",
                        Diagnostics(stamp_ns=0, node="server", counters={"ticks": 3}),
                        "/diagnostics")
    assert diag.status[0].name == "server"
    assert [(kv.key, kv.value) for kv in diag.status[0].values] == [("ticks", "3")]
    clock = _ros(conv.convert("rosgraph_msgs/msg/Clock", "", Clock(stamp_ns=3_000_000_007),
                              "/clock"), "rosgraph_msgs/msg/Clock")
    assert (clock.clock.sec, clock.clock.nanosec) == (3, 7)


@given(st.integers(min_value=0, max_value=2**63 - 1))
def test_every_stamp_survives_as_ros_time(ns: int) -> None:
    """Up to the 68 years a ROS 2 ``Time`` holds (int32 seconds); later ones are clamped."""
    clock = _ros(Converter().convert("rosgraph_msgs/msg/Clock", "", Clock(stamp_ns=ns), "/clock"),
                 "rosgraph_msgs/msg/Clock")
    assert 0 <= clock.clock.nanosec < 10**9 and clock.clock.sec <= 2**31 - 1
    assert clock.clock.sec * 10**9 + clock.clock.nanosec == min(ns, MAX_TIME_NS)


def test_commands_in() -> None:
    cmd = command_from_ros(Float64MultiArray(data=[0.2, 9.5]), glider_id=3, stamp_ns=40, step=2)
    assert (cmd.bank_cmd, cmd.airspeed_cmd, cmd.glider_id, cmd.stamp_ns, cmd.step) == (
        0.2, 9.5, 3, 40, 2)
    nan = command_from_ros(Float64MultiArray(data=[math.nan, 9.5]), glider_id=3, stamp_ns=0,
                           step=0)
    assert math.isnan(nan.bank_cmd)  # passed on: the server rejects it and holds, and counts
    with pytest.raises(CommandError, match="got 3 values"):
        command_from_ros(Float64MultiArray(data=[0.1, 9.0, 1.0]), glider_id=3, stamp_ns=0,
                         step=0)
