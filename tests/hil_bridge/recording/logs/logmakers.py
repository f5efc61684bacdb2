"""Small flight logs of every kind, written with the formats' own writers or byte by byte.

One known flight (:func:`truth`): a climbing left turn of radius 50 m at 12 m/s about a
geodetic origin, with the attitude a coordinated turn has. Each writer stores it the way the
format does (geodetic or NED positions, NED/FRD attitude) so a reader must undo exactly that.
"""

from __future__ import annotations

import math
import struct
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pymap3d

from sim_core.pose import quat_from_euler

ORIGIN = (47.397742, 8.545594, 488.0)  # lat deg, lon deg, alt m
RADIUS, SPEED, CLIMB = 50.0, 12.0, 1.0


@dataclass
class Flight:
    t: np.ndarray  # (K,) s
    enu: np.ndarray  # (K, 3) m about ORIGIN
    roll: np.ndarray  # FLU, rad (right wing down positive)
    pitch: np.ndarray  # FLU, rad (nose down positive)
    yaw: np.ndarray  # ENU, rad from east towards north

    @property
    def geodetic(self) -> np.ndarray:
        lat, lon, alt = pymap3d.enu2geodetic(*self.enu.T, *ORIGIN)
        return np.stack([lat, lon, alt], axis=1)

    @property
    def ned(self) -> np.ndarray:
        return np.stack([self.enu[:, 1], self.enu[:, 0], -self.enu[:, 2]], axis=1)

    @property
    def ned_euler(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Roll, pitch, yaw as NED/FRD logs hold them (hand conversion: same roll, pitch
        negated, yaw from north clockwise)."""
        return self.roll, -self.pitch, np.mod(math.pi / 2 - self.yaw, 2 * math.pi)

    @property
    def ned_quat(self) -> np.ndarray:
        return quat_from_euler(*self.ned_euler)

    @property
    def quat(self) -> np.ndarray:
        return quat_from_euler(self.roll, self.pitch, self.yaw)


def truth(t: np.ndarray) -> Flight:
    w = SPEED / RADIUS
    enu = np.stack([RADIUS * np.sin(w * t), RADIUS * (1 - np.cos(w * t)), CLIMB * t], axis=1)
    bank = math.atan(SPEED * SPEED / (9.81 * RADIUS))
    k = t.shape
    return Flight(t, enu, np.full(k, -bank), np.full(k, -math.atan2(CLIMB, SPEED)), w * t)


# --------------------------------------------------------------------------- ULog (by spec)


def _ulog_msg(kind: bytes, payload: bytes) -> bytes:
    return struct.pack("<HB", len(payload), kind[0]) + payload


def write_ulog(path: Path, pos: Flight, att: Flight, *, local: bool, glob: bool) -> None:
    """A ULog per the PX4 format spec: header, flag bits, formats, subscriptions, data."""
    formats = {
        "vehicle_local_position": "uint64_t timestamp;float x;float y;float z;float vx;float vy;"
                                  "float vz;bool xy_valid;bool z_valid;",
        "vehicle_global_position": "uint64_t timestamp;double lat;double lon;float alt;",
        "vehicle_attitude": "uint64_t timestamp;float[4] q;",
        "battery_status": "uint64_t timestamp;float voltage_v;",
    }
    out = bytearray(b"ULog\x01\x12\x35" + bytes([1]) + struct.pack("<Q", 0))
    out += _ulog_msg(b"B", bytes(16) + struct.pack("<3Q", 0, 0, 0))
    for name, fields in formats.items():
        out += _ulog_msg(b"F", f"{name}:{fields}".encode())
    ids = {name: i for i, name in enumerate(formats)}
    for name, i in ids.items():
        out += _ulog_msg(b"A", struct.pack("<BH", 0, i) + name.encode())
    rows: list[tuple[float, bytes]] = []
    vel = np.gradient(pos.ned, pos.t, axis=0)
    for k, t in enumerate(pos.t):
        us = round(t * 1e6)
        if local:
            n = pos.ned[k]
            rows.append((t, struct.pack("<HQffffff??", ids["vehicle_local_position"], us,
                                        *n, *vel[k], True, True)))
        if glob:
            g = pos.geodetic[k]
            rows.append((t, struct.pack("<HQddf", ids["vehicle_global_position"], us, *g)))
        rows.append((t, struct.pack("<HQf", ids["battery_status"], us, 12.6)))
    q = att.ned_quat
    for k, t in enumerate(att.t):
        rows.append((t, struct.pack("<HQ4f", ids["vehicle_attitude"], round(t * 1e6), *q[k])))
    for _, payload in sorted(rows, key=lambda r: r[0]):
        out += _ulog_msg(b"D", payload)
    path.write_bytes(bytes(out))


# --------------------------------------------------------------------------- DataFlash (by spec)


def _df_fmt(kind: int, name: str, fmt: str, columns: str, length: int) -> bytes:
    return b"\xa3\x95\x80" + struct.pack("<BB4s16s64s", kind, length, name.encode(),
                                         fmt.encode(), columns.encode())


def write_dataflash(path: Path, pos: Flight, att: Flight, *, with_pos: bool = True) -> None:
    """An ArduPilot DataFlash log: FMT records, then POS (int32 1e-7 deg) and ATT (deg)."""
    out = bytearray(_df_fmt(0x80, "FMT", "BBnNZ", "Type,Length,Name,Format,Columns", 89))
    out += _df_fmt(129, "POS", "QLLf", "TimeUS,Lat,Lng,Alt", 3 + 8 + 4 + 4 + 4)
    out += _df_fmt(130, "ATT", "Qfff", "TimeUS,Roll,Pitch,Yaw", 3 + 8 + 12)
    out += _df_fmt(131, "BAT", "Qf", "TimeUS,Volt", 3 + 8 + 4)
    rows: list[tuple[float, bytes]] = []
    for k, t in enumerate(pos.t):
        us = round(t * 1e6) + 1000
        if with_pos:
            lat, lon, alt = pos.geodetic[k]
            rows.append((t, b"\xa3\x95\x81" + struct.pack("<Qiif", us, round(lat * 1e7),
                                                          round(lon * 1e7), alt)))
        rows.append((t, b"\xa3\x95\x83" + struct.pack("<Qf", us, 12.6)))
    r, p, y = (np.degrees(a) for a in att.ned_euler)
    for k, t in enumerate(att.t):
        rows.append((t, b"\xa3\x95\x82" + struct.pack("<Qfff", round(t * 1e6) + 1000, r[k],
                                                      p[k], y[k])))
    for _, rec in sorted(rows, key=lambda row: row[0]):
        out += rec
    path.write_bytes(bytes(out))


#: ArduPilot's GPS record: 4.x (instance field ``I``, its unit ``#`` in FMTU) and 3.x (no
#: instance field; the second receiver is the ``GPS2`` record)
_GPS_4X = ("QBBIHBcLLeffffB", "TimeUS,I,Status,GMS,GWk,NSats,HDop,Lat,Lng,Alt,Spd,GCrs,VZ,Yaw,U",
           "s#-s-S-DUmnhnh-", "F--C-0BGGB000--")
_GPS_3X = ("QBIHBcLLefffB", "TimeUS,Status,GMS,GWk,NSats,HDop,Lat,Lng,Alt,Spd,GCrs,VZ,U")
_DF_STRUCT = {"Q": "Q", "B": "B", "I": "I", "H": "H", "c": "h", "L": "i", "e": "i", "f": "f",
              "N": "16s"}


def _df_struct(fmt: str) -> str:
    return "<" + "".join(_DF_STRUCT[c] for c in fmt)


def write_dataflash_gps(path: Path, receivers: list[Flight], att: Flight, *, layout: str,
                        no_fix: tuple[int, ...] = ()) -> None:
    """An ArduPilot DataFlash log of several GPS receivers, their records interleaved in time
    as the logger writes them, and ATT; no POS. ``layout``: ``"4x"`` (one ``GPS`` record with
    instance field ``I``, declared by an FMTU record), ``"4x-no-fmtu"`` (the same without
    FMTU) or ``"3x"`` (``GPS`` and ``GPS2``). The first ``no_fix[r]`` samples of receiver
    ``r`` have no fix (``Status`` 1)."""
    gps_fmt, gps_cols = _GPS_3X if layout == "3x" else _GPS_4X[:2]
    gps_len = 3 + struct.calcsize(_df_struct(gps_fmt))
    out = bytearray(_df_fmt(0x80, "FMT", "BBnNZ", "Type,Length,Name,Format,Columns", 89))
    out += _df_fmt(130, "ATT", "Qfff", "TimeUS,Roll,Pitch,Yaw", 3 + 8 + 12)
    out += _df_fmt(131, "GPS", gps_fmt, gps_cols, gps_len)
    if layout == "3x":
        out += _df_fmt(132, "GPS2", gps_fmt, gps_cols, gps_len)
    if layout == "4x":
        out += _df_fmt(172, "FMTU", "QBNN", "TimeUS,FmtType,UnitIds,MultIds", 3 + 8 + 1 + 32)
        out += b"\xa3\x95\xac" + struct.pack("<QB16s16s", 0, 131, _GPS_4X[2].encode(),
                                               _GPS_4X[3].encode())
    rows: list[tuple[float, bytes]] = []
    for r, flight in enumerate(receivers):
        vel = np.gradient(flight.enu, flight.t, axis=0)
        for k, t in enumerate(flight.t):
            lat, lon, alt = flight.geodetic[k]
            status = 1 if k < (no_fix[r] if r < len(no_fix) else 0) else 3
            ve, vn, vu = vel[k]
            course = math.degrees(math.atan2(ve, vn)) % 360.0
            fix = (status, 0, 2200, 12, 70, round(lat * 1e7), round(lon * 1e7),
                   round(alt * 100), math.hypot(ve, vn), course, -vu)
            us = round(t * 1e6) + 1000
            if layout == "3x":
                head = b"\xa3\x95" + bytes([131 if r == 0 else 132])
                body = struct.pack(_df_struct(gps_fmt), us, *fix, 1)
            else:
                head = b"\xa3\x95\x83"
                body = struct.pack(_df_struct(gps_fmt), us, r, *fix, 0.0, 1)
            rows.append((t, head + body))
    r_, p_, y_ = (np.degrees(a) for a in att.ned_euler)
    for k, t in enumerate(att.t):
        rows.append((t, b"\xa3\x95\x82" + struct.pack("<Qfff", round(t * 1e6) + 1000, r_[k],
                                                      p_[k], y_[k])))
    for _, rec in sorted(rows, key=lambda row: row[0]):
        out += rec
    path.write_bytes(bytes(out))


# --------------------------------------------------------------------------- tlog (pymavlink)


def write_tlog(path: Path, pos: Flight, att: Flight, *, sysids: tuple[int, ...] = (1,),
               local: bool = False) -> None:
    """A MAVLink 2 telemetry log packed by pymavlink: 8-byte big-endian µs + packet."""
    from pymavlink.dialects.v20 import common

    rows: list[tuple[float, bytes]] = []
    vel = np.gradient(pos.ned, pos.t, axis=0)
    for sysid in sysids:
        mav = common.MAVLink(None, srcSystem=sysid, srcComponent=1)
        hb = mav.heartbeat_encode(1, 3, 0, 0, 0)
        rows.append((0.0, hb.pack(mav)))
        for k, t in enumerate(pos.t):
            ms = round(t * 1e3)
            if local:
                msg = mav.local_position_ned_encode(ms, *pos.ned[k], *vel[k])
            else:
                lat, lon, alt = pos.geodetic[k]
                msg = mav.global_position_int_encode(
                    ms, round(lat * 1e7), round(lon * 1e7), round(alt * 1e3), 0,
                    *(round(v * 100) for v in vel[k]), 0)
            rows.append((t, msg.pack(mav)))
        q = att.ned_quat
        for k, t in enumerate(att.t):
            msg = mav.attitude_quaternion_encode(round(t * 1e3), *q[k], 0.0, 0.0, 0.0)
            rows.append((t, msg.pack(mav)))
    with open(path, "wb") as f:
        for t, data in sorted(rows, key=lambda row: row[0]):
            f.write(struct.pack(">Q", round(1.7e15 + t * 1e6)) + data)


# --------------------------------------------------------------------------- ROS 2 (rosbags)


def write_ros2_bag(path: Path, flight: Flight, *, storage: str, extra_topic: bool = False,
                   with_pose: bool = True) -> None:
    """A ROS 2 bag written by rosbags: /odom nav_msgs/Odometry (and /pose PoseStamped)."""
    from rosbags.rosbag2 import StoragePlugin, Writer
    from rosbags.typesys import Stores, get_typestore

    ts = get_typestore(Stores.ROS2_HUMBLE)
    T = ts.types
    plugin = StoragePlugin.MCAP if storage == "mcap" else StoragePlugin.SQLITE3
    vel = np.gradient(flight.enu, flight.t, axis=0)
    with Writer(path, version=9, storage_plugin=plugin) as w:
        odom = w.add_connection("/odom", "nav_msgs/msg/Odometry", typestore=ts)
        pose = w.add_connection("/pose", "geometry_msgs/msg/PoseStamped", typestore=ts)
        text = w.add_connection("/status", "std_msgs/msg/String", typestore=ts)
        for k, t in enumerate(flight.t):
            ns = round(t * 1e9) + 5_000_000_000
            stamp = T["builtin_interfaces/msg/Time"](sec=ns // 10**9, nanosec=ns % 10**9)
            header = T["std_msgs/msg/Header"](stamp=stamp, frame_id="map")
            qw, qx, qy, qz = flight.quat[k]
            p = T["geometry_msgs/msg/Pose"](
                position=T["geometry_msgs/msg/Point"](x=flight.enu[k, 0], y=flight.enu[k, 1],
                                                      z=flight.enu[k, 2]),
                orientation=T["geometry_msgs/msg/Quaternion"](x=qx, y=qy, z=qz, w=qw))
            if with_pose:
                v = T["geometry_msgs/msg/Vector3"](x=float(np.linalg.norm(vel[k])), y=0.0, z=0.0)
                zero = T["geometry_msgs/msg/Vector3"](x=0.0, y=0.0, z=0.0)
                msg = T["nav_msgs/msg/Odometry"](
                    header=header, child_frame_id="base_link",
                    pose=T["geometry_msgs/msg/PoseWithCovariance"](
                        pose=p, covariance=np.zeros(36)),
                    twist=T["geometry_msgs/msg/TwistWithCovariance"](
                        twist=T["geometry_msgs/msg/Twist"](linear=v, angular=zero),
                        covariance=np.zeros(36)))
                w.write(odom, ns + 1000, ts.serialize_cdr(msg, "nav_msgs/msg/Odometry"))
                if extra_topic:
                    ps = T["geometry_msgs/msg/PoseStamped"](header=header, pose=p)
                    w.write(pose, ns + 2000,
                            ts.serialize_cdr(ps, "geometry_msgs/msg/PoseStamped"))
            w.write(text, ns, ts.serialize_cdr(T["std_msgs/msg/String"](data="ok"),
                                               "std_msgs/msg/String"))
