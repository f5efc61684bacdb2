"""The bridge's own CDR (ros2_bridge.cdr) against rosbags' serialiser, an independent
implementation of the same encoding: the same bytes for every message, and the fields decoded
back. Strings of every length move the doubles after them through every alignment."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

pytest.importorskip("nav_msgs", reason="the 'ros2' extra is not installed")

from hil_bridge.recording.export.ros2 import typestore
from ros2_bridge import cdr

FINITE = st.floats(allow_nan=False, allow_infinity=False, width=64)
NAMES = st.text(st.sampled_from("abcxyz_019"), min_size=0, max_size=13)
STAMPS = st.integers(min_value=0, max_value=cdr.MAX_TIME_NS)


def _vec(n: int) -> st.SearchStrategy[list[float]]:
    return st.lists(FINITE, min_size=n, max_size=n)


def _same_bytes(data: bytes, type_name: str) -> object:
    """``data`` decoded by rosbags, after checking that rosbags encodes it back to ``data``."""
    store = typestore()
    msg = store.deserialize_cdr(data, type_name)
    assert bytes(store.serialize_cdr(msg, type_name, little_endian=True)) == data
    return msg


@given(STAMPS, NAMES, NAMES, _vec(3), _vec(4), _vec(3), _vec(3))
def test_odometry(ns: int, frame: str, child: str, p: list[float], q: list[float],
                  v: list[float], w: list[float]) -> None:
    row = cdr.odometry_rows([p], [q], [v], [w])[0]
    msg = _same_bytes(cdr.odometry(ns, frame, child, row), "nav_msgs/msg/Odometry")
    assert msg.header.stamp.sec * 10**9 + msg.header.stamp.nanosec == ns  # type: ignore[attr-defined]
    assert (msg.header.frame_id, msg.child_frame_id) == (frame, child)  # type: ignore[attr-defined]
    pose, twist = msg.pose, msg.twist  # type: ignore[attr-defined]
    o = pose.pose.orientation
    assert [pose.pose.position.x, pose.pose.position.y, pose.pose.position.z] == p
    assert [o.w, o.x, o.y, o.z] == q
    assert [twist.twist.linear.x, twist.twist.linear.y, twist.twist.linear.z] == v
    assert [twist.twist.angular.x, twist.twist.angular.y, twist.twist.angular.z] == w
    assert not pose.covariance.any() and not twist.covariance.any()


def test_odometry_rows_of_a_batch_are_its_messages() -> None:
    rng = np.random.default_rng(3)
    p, q, v, w = (rng.standard_normal((5, n)) for n in (3, 4, 3, 3))
    rows = cdr.odometry_rows(p, q, v, w)
    for k in range(5):
        one = cdr.odometry_rows(p[k:k + 1], q[k:k + 1], v[k:k + 1], w[k:k + 1])[0]
        assert cdr.odometry(7, "map", f"glider_{k}", rows[k]) == cdr.odometry(
            7, "map", f"glider_{k}", one)


@given(STAMPS, NAMES, _vec(4), _vec(3), _vec(3), st.booleans())
def test_imu(ns: int, frame: str, q: list[float], w: list[float], a: list[float],
             known: bool) -> None:
    msg = _same_bytes(cdr.imu(ns, frame, q, w, a, acceleration_known=known),
                      "sensor_msgs/msg/Imu")
    o, av, la = msg.orientation, msg.angular_velocity, msg.linear_acceleration  # type: ignore[attr-defined]
    assert msg.header.frame_id == frame  # type: ignore[attr-defined]
    assert [o.w, o.x, o.y, o.z] == q
    assert [av.x, av.y, av.z] == w and [la.x, la.y, la.z] == a
    cov = msg.linear_acceleration_covariance  # type: ignore[attr-defined]
    assert cov[0] == (0.0 if known else -1.0) and not cov[1:].any()


@given(STAMPS, NAMES, st.integers(1, 3), st.integers(0, 9))
def test_image(ns: int, frame: str, rows: int, cols: int) -> None:
    samples = np.arange(rows * cols, dtype=np.float32).reshape(rows, cols) / 3
    msg = _same_bytes(cdr.image(ns, frame, samples), "sensor_msgs/msg/Image")
    assert (msg.height, msg.width, msg.encoding, msg.is_bigendian, msg.step) == (  # type: ignore[attr-defined]
        rows, cols, "32FC1", 0, 4 * cols)
    assert msg.header.frame_id == frame  # type: ignore[attr-defined]
    decoded = np.frombuffer(msg.data.tobytes(), dtype="<f4").reshape(rows, cols)  # type: ignore[attr-defined]
    np.testing.assert_array_equal(decoded, samples)


@given(st.integers(min_value=-(2**63), max_value=2**63 - 1))
def test_clock_clamps_to_what_a_ros_time_holds(ns: int) -> None:
    msg = _same_bytes(cdr.clock(ns), "rosgraph_msgs/msg/Clock")
    t = msg.clock  # type: ignore[attr-defined]
    assert 0 <= t.nanosec < 10**9
    assert t.sec * 10**9 + t.nanosec == min(max(ns, 0), cdr.MAX_TIME_NS)


def _wheel_fields(type_name: str) -> list[tuple[str, str]]:
    """``(field, type)`` of ``pkg/msg/Type`` as the installed ROS 2 wheels define it, nested
    types expanded depth first."""
    import importlib

    pkg, _, name = type_name.split("/")
    cls = getattr(importlib.import_module(f"{pkg}.msg"), name)
    out = []
    for field, kind in cls.get_fields_and_field_types().items():
        out.append((field, kind))
        base = kind.split("[")[0].removeprefix("sequence<").removesuffix(">")
        if "/" in base:
            nested_pkg, nested = base.split("/")
            out += _wheel_fields(f"{nested_pkg}/msg/{nested}")
    return out


def _store_fields(type_name: str) -> list[str]:
    out = []
    for field, (kind, detail) in typestore().fielddefs[type_name][1]:
        out.append(field)
        if kind.name == "NAME":
            out += _store_fields(detail)
    return out


@pytest.mark.parametrize("type_name", ["nav_msgs/msg/Odometry", "sensor_msgs/msg/Imu",
                                       "sensor_msgs/msg/Image", "rosgraph_msgs/msg/Clock"])
def test_the_wheels_define_these_types_with_the_fields_encoded_here(type_name: str) -> None:
    """The layouts written here and checked against rosbags' store are the installed ROS 2
    distribution's: the same fields, nested, in the same order."""
    assert [f for f, _ in _wheel_fields(type_name)] == _store_fields(type_name)
