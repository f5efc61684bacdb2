"""The bridge's messages at state and echo rate, serialised as ROS 2 does (CDR, little-endian).

A state becomes an ``Odometry`` 250 times a second per glider: building an rclpy message and
letting rclpy serialise it cost the bridge 40 µs of the 90 µs a publish took, so these types
are written here straight from the bus's numbers and published as bytes (``Publisher.publish``
takes a serialised message as it is). The layouts are the ROS 2 (Humble … Kilted) definitions
in XCDR1: a 4-byte encapsulation header (``00 01``: CDR, little-endian; two option bytes),
then each field at an offset aligned to its size, counted from the end of the header; a string
is a ``uint32`` length that counts its terminating NUL, then its bytes and the NUL; a sequence
is a ``uint32`` count, then its elements. The fixed numeric tail of a message (85 doubles of an
``Odometry``, 37 of an ``Imu``) is one row of a float64 array, so a batch of states is filled at
once (:func:`odometry_rows`) and each message is three byte strings joined.

tests/ros2_bridge/test_cdr.py holds every encoding to the bytes of rosbags' own serialiser
(an implementation of CDR independent of this one) and to its decoded fields.
"""

from __future__ import annotations

import functools
import struct

import numpy as np
import numpy.typing as npt

__all__ = ["ENCAPSULATION", "IMU_DOUBLES", "ODOMETRY_DOUBLES", "clock", "image", "imu",
           "odometry", "odometry_rows", "sec_nanosec", "stamp"]

#: CDR, little-endian, no options
ENCAPSULATION = b"\x00\x01\x00\x00"
#: ``Odometry`` after its strings: pose (position 3, orientation x y z w 4, covariance 36),
#: twist (linear 3, angular 3, covariance 36)
ODOMETRY_DOUBLES = 85
#: ``Imu`` after its string: orientation 4 + 9, angular velocity 3 + 9, linear acceleration
#: 3 + 9 (each with its covariance)
IMU_DOUBLES = 37
#: the latest time a ``builtin_interfaces/Time`` holds (its ``sec`` is an int32), ns
MAX_TIME_NS = (2**31 - 1) * 1_000_000_000 + 999_999_999
_TIME = struct.Struct("<iI")
_U32 = struct.Struct("<I")


def sec_nanosec(ns: int) -> tuple[int, int]:
    """A ``builtin_interfaces/Time``'s ``(sec, nanosec)`` of sim time ``ns``, clamped to
    ``[0, MAX_TIME_NS]``."""
    sec, nanosec = divmod(min(max(0, int(ns)), MAX_TIME_NS), 1_000_000_000)
    return sec, nanosec


def stamp(ns: int) -> bytes:
    """A ``builtin_interfaces/Time`` of sim time ``ns`` (:func:`sec_nanosec`)."""
    return _TIME.pack(*sec_nanosec(ns))


def _pad(offset: int, align: int) -> bytes:
    return b"\0" * (-offset % align)


def _strings(offset: int, texts: tuple[str, ...], align_after: int) -> bytes:
    """``texts`` as CDR strings starting at payload ``offset``, padded so that what follows is
    aligned to ``align_after``."""
    out = b""
    for text in texts:
        raw = text.encode() + b"\0"
        out += _pad(offset + len(out), 4) + _U32.pack(len(raw)) + raw
    return out + _pad(offset + len(out), align_after)


@functools.lru_cache(maxsize=4096)
def _after_stamp(*texts: str) -> bytes:
    """The header's ``frame_id`` (and an ``Odometry``'s ``child_frame_id``) after the stamp,
    padded for the doubles that follow (cached: one per topic)."""
    return _strings(_TIME.size, texts, 8)


def clock(ns: int) -> bytes:
    """``rosgraph_msgs/msg/Clock``."""
    return ENCAPSULATION + stamp(ns)


def odometry_rows(position: npt.ArrayLike, q_wxyz: npt.ArrayLike, linear: npt.ArrayLike,
                  angular: npt.ArrayLike) -> npt.NDArray[np.float64]:
    """The numeric tails (K, :data:`ODOMETRY_DOUBLES`) of K ``Odometry``: ``position`` (K, 3) m,
    attitude ``q_wxyz`` (K, 4), twist ``linear`` (K, 3) m/s and ``angular`` (K, 3) rad/s;
    covariances zero (unknown)."""
    q = np.asarray(q_wxyz, dtype=np.float64).reshape(-1, 4)
    rows = np.zeros((q.shape[0], ODOMETRY_DOUBLES))
    rows[:, 0:3] = position
    rows[:, 3:6] = q[:, 1:4]
    rows[:, 6] = q[:, 0]
    rows[:, 43:46] = linear
    rows[:, 46:49] = angular
    return rows


def odometry(stamp_ns: int, frame_id: str, child_frame_id: str,
             row: npt.NDArray[np.float64]) -> bytes:
    """``nav_msgs/msg/Odometry`` with one row of :func:`odometry_rows`."""
    return b"".join((ENCAPSULATION, stamp(stamp_ns), _after_stamp(frame_id, child_frame_id),
                     row.tobytes()))


def imu(stamp_ns: int, frame_id: str, q_wxyz: npt.ArrayLike, angular: npt.ArrayLike,
        linear_acceleration: npt.ArrayLike, *, acceleration_known: bool) -> bytes:
    """``sensor_msgs/msg/Imu``: covariances zero (unknown), except that an unknown
    acceleration has ``linear_acceleration_covariance[0] = -1`` (as ``sensor_msgs`` says)."""
    q = np.asarray(q_wxyz, dtype=np.float64)
    row = np.zeros(IMU_DOUBLES)
    row[0:3], row[3] = q[1:4], q[0]
    row[13:16] = angular
    row[25:28] = linear_acceleration
    if not acceleration_known:
        row[28] = -1.0
    return b"".join((ENCAPSULATION, stamp(stamp_ns), _after_stamp(frame_id), row.tobytes()))


def image(stamp_ns: int, frame_id: str, samples: npt.NDArray[np.float32]) -> bytes:
    """``sensor_msgs/msg/Image`` of a 2-D float array: ``32FC1``, one row per array row."""
    data = np.ascontiguousarray(samples, dtype="<f4")
    height, width = data.shape
    head = ENCAPSULATION + stamp(stamp_ns) + _strings(_TIME.size, (frame_id,), 4)
    offset = len(head) - len(ENCAPSULATION)
    head += struct.pack("<II", height, width)
    head += _strings(offset + 8, ("32FC1",), 1)
    offset = len(head) - len(ENCAPSULATION)
    head += b"\0" + _pad(offset + 1, 4) + struct.pack("<II", 4 * width, data.nbytes)
    return b"".join((head, data.data))  # the samples copied once
