"""ArduPilot DataFlash (``.bin``) and MAVLink telemetry logs (``.tlog``) through pymavlink.

DataFlash: position from ``POS`` (``Lat``, ``Lng`` deg, ``Alt`` m AMSL), else ``GPS`` (fix
status >= 3; ``Spd`` horizontal and ``VZ`` m/s down give the speed), else ``AHR2``; attitude
from ``ATT`` (``Roll``, ``Pitch``, ``Yaw`` deg, NED/FRD Z-Y-X), else ``AHR2``. Times: ``TimeUS``.
GPS receivers are kept apart, never interleaved into one track: ArduPilot 4.x logs tell them by
the ``GPS`` instance field ``I`` (``GPS[0]``, ``GPS[1]``, ...), older ones write the second as
``GPS2`` (= ``GPS[1]``). Without ``topic`` the first receiver with a 3D fix is used (instance 0,
as the ULog reader takes instance 0 of every topic) and the report lists the others; ``topic``
names the position message: ``POS``, ``AHR2``, ``GPS``, ``GPS2`` or ``GPS[N]``.

tlog: position from ``GLOBAL_POSITION_INT`` (``lat``, ``lon`` 1e-7 deg, ``alt`` mm AMSL,
``vx, vy, vz`` cm/s NED), else ``LOCAL_POSITION_NED`` (m, m/s NED), or the one ``topic``
names; attitude from
``ATTITUDE_QUATERNION`` (``q1..q4`` = w, x, y, z NED/FRD), else ``ATTITUDE`` (rad). Times are
the vehicle's ``time_boot_ms`` (a reboot shows up as a time jump back). A tlog with several
vehicles (MAVLink system ids) needs ``vehicle_id`` = the system id. Frames pymavlink cannot
decode (a bad CRC, broken framing) are dropped and counted in the report.
"""

from __future__ import annotations

import re
from collections import defaultdict
from dataclasses import dataclass, field
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

_DF_TYPES = ["POS", "GPS", "GPS2", "ATT", "AHR2"]
_DF_SOURCE = re.compile(r"(POS|AHR2|GPS2?)(?:\[(\d{1,3})\])?")
_DF_SOURCES = "POS, AHR2, GPS (= GPS[0]), GPS2 (= GPS[1]) or GPS[N]"


def _gps_instance(m: Any) -> tuple[int, str]:
    """Receiver number and log name of a GPS message: the instance field (``I``) of ArduPilot
    4.x logs (``GPS[0]``, ``GPS[1]``), else 0 for ``GPS`` and 1 for ``GPS2`` (older logs)."""
    if m.get_type() == "GPS2":
        return 1, "GPS2"
    field = m.fmt.instance_field or ("I" if "I" in m.fmt.colhash else None)
    if field is None:
        return 0, "GPS"
    i = int(getattr(m, field))
    return i, f"GPS[{i}]"


@dataclass
class _DataFlash:
    """What a DataFlash log holds for poses: messages by type, GPS by receiver."""

    msgs: dict[str, list[Any]] = field(default_factory=lambda: defaultdict(list))
    #: receiver -> its 3D-fix samples, and its name and sample count (with or without a fix)
    gps: dict[int, list[Any]] = field(default_factory=lambda: defaultdict(list))
    gps_name: dict[int, str] = field(default_factory=dict)
    gps_all: dict[int, int] = field(default_factory=lambda: defaultdict(int))

    def add(self, m: Any) -> None:
        kind = m.get_type()
        if kind not in ("GPS", "GPS2"):
            self.msgs[kind].append(m)
            return
        i, name = _gps_instance(m)
        self.gps_name[i] = name
        self.gps_all[i] += 1
        if getattr(m, "Status", 3) >= 3:
            self.gps[i].append(m)

    def holds(self) -> dict[str, int]:
        """Position sources and their sample counts (GPS: all samples, fix or not)."""
        out = {n: len(self.msgs[n]) for n in ("POS", "AHR2") if self.msgs[n]}
        out.update({self.gps_name[i]: c for i, c in sorted(self.gps_all.items())})
        return out


def read_dataflash(path: Path, *, vehicle_id: int | None = None, topic: str | None = None
                   ) -> PoseLog:
    """The poses of an ArduPilot DataFlash log (module docstring)."""
    from pymavlink import DFReader

    held = _DataFlash()
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
                held.add(m)
        finally:
            reader.filehandle.close()
    wanted = None if topic is None else _df_source(path, topic, held)
    log = _dataflash_position(path, held, wanted, reader, notes)
    msgs = held.msgs
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


def _df_source(path: Path, topic: str, held: _DataFlash) -> str | int:
    """``"POS"``/``"AHR2"``, or the GPS receiver number, that ``topic`` names."""
    m = _DF_SOURCE.fullmatch(topic.strip())
    if m is None or (m[2] is not None and m[1] != "GPS"):
        raise ValueError(f"{path}: topic {topic!r}: expected a DataFlash position message, "
                         f"{_DF_SOURCES}; the log has {describe(held.holds())}")
    if m[1] == "GPS2":
        return 1
    if m[1] == "GPS":
        return int(m[2] or 0)
    return m[1]


def _dataflash_position(
    path: Path, held: _DataFlash, wanted: str | int | None, reader: Any, notes: list[str],
) -> PoseLog:
    """The position stream ``wanted`` (:func:`_df_source`; None: POS, else the first GPS
    receiver with a 3D fix, else AHR2)."""
    msgs = held.msgs
    if wanted is None:
        if msgs["POS"]:
            wanted = "POS"
        elif held.gps:
            # the first receiver, as the ULog reader takes instance 0 of every topic; several
            # receivers are never interleaved into one track
            wanted = 0 if 0 in held.gps else min(held.gps)
        elif msgs["AHR2"]:
            wanted = "AHR2"
        else:
            found = {n: int(c) for i, c in enumerate(getattr(reader, "counts", []))
                     if c and (n := getattr(reader, "id_to_name", {}).get(i))}
            said = f" ({'; '.join(notes)})" if notes else ""
            raise NoPoseError(f"{path}: DataFlash log without a usable pose: no POS, GPS (3D "
                              f"fix) or AHR2 messages; the log holds {describe(found)}{said}")
    if isinstance(wanted, int):
        chosen = held.gps.get(wanted, [])
        name = held.gps_name.get(wanted, f"GPS[{wanted}]")
        if not chosen:
            why = (f"{held.gps_all[wanted]} sample(s), none with a 3D fix"
                   if held.gps_all.get(wanted) else "no such receiver")
            raise NoPoseError(f"{path}: {name}: {why}; position sources in the log: "
                              f"{describe(held.holds())}")
    else:
        chosen, name = msgs[wanted], wanted
        if not chosen:
            raise NoPoseError(f"{path}: no {wanted} messages; position sources in the log: "
                              f"{describe(held.holds())}")
    p = _rows(chosen, ("TimeUS", "Lat", "Lng", "Alt"))
    log = PoseLog(format="ArduPilot DataFlash", source=name, t=p[:, 0] * 1e-6,
                  position=p[:, 1:4], frame="geodetic", notes=list(notes))
    if isinstance(wanted, int) and all(hasattr(chosen[0], f) for f in ("Spd", "VZ")):
        s = _rows(chosen, ("Spd", "VZ"))
        log.speed = np.hypot(s[:, 0], s[:, 1])
    if len(held.gps_all) > 1:
        names = ", ".join(held.gps_name[i] for i in sorted(held.gps_all))
        log.notes.append(f"GPS receivers in the log: {names}; {name} used "
                         "(--topic chooses the position message)")
    return log


# --------------------------------------------------------------------------- tlog

_TLOG_POSITIONS = ("GLOBAL_POSITION_INT", "LOCAL_POSITION_NED")
_TLOG_TYPES = [*_TLOG_POSITIONS, "ATTITUDE_QUATERNION", "ATTITUDE"]


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
    if topic is not None:
        name = topic.strip()
        if name not in _TLOG_POSITIONS or not d[name]:
            held = {k: len(d[k]) for k in _TLOG_POSITIONS if d[k]}
            raise ValueError(f"{path}: topic {topic!r}: not a position message of system "
                             f"{sysid} in this tlog; it has {describe(held)}")
    else:
        name = "GLOBAL_POSITION_INT" if d["GLOBAL_POSITION_INT"] else "LOCAL_POSITION_NED"
    if name == "GLOBAL_POSITION_INT":
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
    if found["BAD_DATA"]:
        log.notes.append(f"{found['BAD_DATA']} frame(s) pymavlink could not decode (bad CRC or "
                         "framing) dropped")
    log.notes.extend(notes)
    return log
