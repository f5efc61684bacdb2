"""ArduPilot DataFlash (``.bin``) and MAVLink telemetry logs (``.tlog``) through pymavlink.

DataFlash: position from ``POS`` (``Lat``, ``Lng`` deg, ``Alt`` m AMSL), else ``GPS`` (fix
status >= 3; ``Spd`` horizontal and ``VZ`` m/s down give the speed), else ``AHR2``; attitude
from ``ATT`` (``Roll``, ``Pitch``, ``Yaw`` deg, NED/FRD Z-Y-X), else ``AHR2``. Times: ``TimeUS``.

tlog: position from ``GLOBAL_POSITION_INT`` (``lat``, ``lon`` 1e-7 deg, ``alt`` mm AMSL,
``vx, vy, vz`` cm/s NED), else ``LOCAL_POSITION_NED`` (m, m/s NED); attitude from
``ATTITUDE_QUATERNION`` (``q1..q4`` = w, x, y, z NED/FRD), else ``ATTITUDE`` (rad). Times are
the vehicle's ``time_boot_ms`` (a reboot shows up as a time jump back). A tlog with several
vehicles (MAVLink system ids) needs ``vehicle_id`` = the system id.
"""

from __future__ import annotations

from collections import defaultdict
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from hil_bridge.recording.logs.track import NoPoseError, PoseLog, describe, parser_chatter
from sim_core.pose import quat_enu_flu_from_ned_frd, quat_from_euler

__all__ = ["read_dataflash", "read_tlog"]

FloatArray = NDArray[np.float64]


def _ned_quat_from_euler(roll: FloatArray, pitch: FloatArray, yaw: FloatArray) -> FloatArray:
    """ENU/FLU world-from-body of NED/FRD Z-Y-X Euler angles (rad)."""
    return quat_enu_flu_from_ned_frd(quat_from_euler(roll, pitch, yaw))


def _rows(msgs: list[Any], fields: tuple[str, ...]) -> FloatArray:
    return np.array([[float(getattr(m, f)) for f in fields] for m in msgs], dtype=np.float64)


# --------------------------------------------------------------------------- DataFlash

_DF_TYPES = ["POS", "GPS", "ATT", "AHR2"]


def read_dataflash(
    path: Path, *, vehicle_id: int | None = None, topic: str | None = None
) -> PoseLog:
    """The poses of an ArduPilot DataFlash log (module docstring)."""
    from pymavlink import DFReader

    msgs: dict[str, list[Any]] = defaultdict(list)
    with parser_chatter("pymavlink") as notes:
        try:
            reader = DFReader.DFReader_binary(str(path), zero_time_base=False)
        except Exception as exc:  # pymavlink raises bare Exceptions on bad files
            raise ValueError(f"{path}: cannot read DataFlash ({type(exc).__name__}: "
                             f"{exc})") from None
        try:
            while True:
                m = reader.recv_match(type=_DF_TYPES)
                if m is None:
                    break
                if m.get_type() == "GPS" and getattr(m, "Status", 3) < 3:
                    continue
                msgs[m.get_type()].append(m)
        finally:
            reader.filehandle.close()
    log = _dataflash_position(path, msgs, reader, notes)
    if msgs["ATT"]:
        a = _rows(msgs["ATT"], ("TimeUS", "Roll", "Pitch", "Yaw"))
        log.att_source = "ATT"
    elif msgs["AHR2"]:
        a = _rows(msgs["AHR2"], ("TimeUS", "Roll", "Pitch", "Yaw"))
        log.att_source = "AHR2"
    else:
        a = None
    if a is not None:
        log.att_t = a[:, 0] * 1e-6
        log.att_q = _ned_quat_from_euler(*np.radians(a[:, 1:4]).T)
    log.vehicle_id = vehicle_id
    return log


def _dataflash_position(
    path: Path, msgs: dict[str, list[Any]], reader: Any, notes: list[str]
) -> PoseLog:
    for name in ("POS", "GPS", "AHR2"):
        if msgs[name]:
            break
    else:
        found = {n: int(c) for i, c in enumerate(getattr(reader, "counts", []))
                 if c and (n := getattr(reader, "id_to_name", {}).get(i))}
        said = f" ({'; '.join(notes)})" if notes else ""
        raise NoPoseError(f"{path}: DataFlash log without a usable pose: no POS, GPS (3D fix) "
                          f"or AHR2 messages; the log holds {describe(found)}{said}")
    p = _rows(msgs[name], ("TimeUS", "Lat", "Lng", "Alt"))
    log = PoseLog(format="ArduPilot DataFlash", source=name, t=p[:, 0] * 1e-6,
                  position=p[:, 1:4], frame="geodetic", notes=list(notes))
    if name == "GPS" and all(hasattr(msgs[name][0], f) for f in ("Spd", "VZ")):
        s = _rows(msgs[name], ("Spd", "VZ"))
        log.speed = np.hypot(s[:, 0], s[:, 1])
    return log


# --------------------------------------------------------------------------- tlog

_TLOG_TYPES = ["GLOBAL_POSITION_INT", "LOCAL_POSITION_NED", "ATTITUDE_QUATERNION", "ATTITUDE"]


def read_tlog(path: Path, *, vehicle_id: int | None = None, topic: str | None = None) -> PoseLog:
    """The poses of a MAVLink telemetry log (module docstring)."""
    from pymavlink import mavutil

    by_sys: dict[int, dict[str, list[Any]]] = defaultdict(lambda: defaultdict(list))
    found: dict[str, int] = defaultdict(int)
    with parser_chatter("pymavlink") as notes:
        try:
            conn = mavutil.mavlogfile(str(path), robust_parsing=True)
        except Exception as exc:  # pymavlink raises bare Exceptions on bad files
            raise ValueError(f"{path}: cannot read tlog ({type(exc).__name__}: {exc})") from None
        try:
            while True:
                m = conn.recv_msg()
                if m is None:
                    break
                kind = m.get_type()
                found[kind] += 1
                if kind in _TLOG_TYPES:
                    by_sys[m.get_srcSystem()][kind].append(m)
        finally:
            conn.close()
    with_pose = sorted(s for s, d in by_sys.items()
                       if d["GLOBAL_POSITION_INT"] or d["LOCAL_POSITION_NED"])
    if not with_pose:
        raise NoPoseError(f"{path}: tlog without a usable pose: no GLOBAL_POSITION_INT or "
                          f"LOCAL_POSITION_NED messages; the log holds {describe(dict(found))}")
    if vehicle_id is None:
        if len(with_pose) > 1:
            raise ValueError(f"{path}: holds vehicles (MAVLink system ids) {with_pose}; "
                             "choose one with an id")
        sysid = with_pose[0]
    elif vehicle_id in with_pose:
        sysid = vehicle_id
    else:
        raise ValueError(f"{path}: no poses of system id {vehicle_id}; ids with poses: "
                         f"{with_pose}")
    d = by_sys[sysid]
    if d["GLOBAL_POSITION_INT"]:
        g = _rows(d["GLOBAL_POSITION_INT"], ("time_boot_ms", "lat", "lon", "alt", "vx", "vy",
                                              "vz"))
        log = PoseLog(format="MAVLink tlog", source="GLOBAL_POSITION_INT", t=g[:, 0] * 1e-3,
                      position=g[:, 1:4] * [1e-7, 1e-7, 1e-3], frame="geodetic",
                      velocity=np.stack([g[:, 5], g[:, 4], -g[:, 6]], axis=1) * 1e-2)
    else:
        p = _rows(d["LOCAL_POSITION_NED"], ("time_boot_ms", "x", "y", "z", "vx", "vy", "vz"))
        log = PoseLog(format="MAVLink tlog", source="LOCAL_POSITION_NED", t=p[:, 0] * 1e-3,
                      position=p[:, 1:4], frame="ned", velocity=p[:, 4:7])
    if d["ATTITUDE_QUATERNION"]:
        q = _rows(d["ATTITUDE_QUATERNION"], ("time_boot_ms", "q1", "q2", "q3", "q4"))
        ok = np.linalg.norm(q[:, 1:], axis=1) > 0
        log.att_t, log.att_q = q[ok, 0] * 1e-3, quat_enu_flu_from_ned_frd(q[ok, 1:])
        log.att_source = "ATTITUDE_QUATERNION"
    elif d["ATTITUDE"]:
        a = _rows(d["ATTITUDE"], ("time_boot_ms", "roll", "pitch", "yaw"))
        log.att_t, log.att_q = a[:, 0] * 1e-3, _ned_quat_from_euler(a[:, 1], a[:, 2], a[:, 3])
        log.att_source = "ATTITUDE"
    log.vehicle_id = sysid
    log.notes.extend(notes)
    return log
