"""PX4 ULog (``.ulg``) through pyulog.

Position sources, named by ``topic`` (``NAME`` = instance 0, ``NAME[N]`` = ``multi_id`` N), the
first one with a usable sample chosen without it:

1. ``vehicle_global_position``: ``lat``, ``lon`` deg, ``alt`` m AMSL;
2. ``vehicle_local_position``: ``x, y, z`` m NED about the EKF origin, ``vx, vy, vz`` m/s NED;
   samples with ``xy_valid`` or ``z_valid`` false are dropped. Samples whose reference is
   valid (``xy_global`` and ``z_global`` true, ``ref_lat``/``ref_lon``/``ref_alt`` finite) are
   placed geodetically as PX4 places them (:func:`px4_reproject`: its azimuthal equidistant
   projection about each sample's own reference, ``alt = ref_alt - z``), so ``--origin``
   works, the track lines up with GPS logs, and an origin moved in flight moves nothing;
   without a reference the track stays local NED;
3. ``vehicle_gps_position``, then ``sensor_gps``: samples with ``fix_type`` >= 3; ``lat``,
   ``lon`` degE7 and ``alt`` mm (PX4 <= 1.13) or ``latitude_deg``, ``longitude_deg``,
   ``altitude_msl_m``; ``vel_n_m_s``, ``vel_e_m_s``, ``vel_d_m_s`` where ``vel_ned_valid``.

Receivers (``multi_id``) are never interleaved into one track; the report lists the other
instances. Attitude: ``vehicle_attitude`` ``q[0..3]`` (world-from-body NED/FRD, converted to
ENU/FLU). Times are the messages' ``timestamp`` (µs since boot).
"""

from __future__ import annotations

import re
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from hil_bridge.recording.logs.track import NoPoseError, PoseLog, describe, parser_chatter
from sim_core.pose import quat_enu_flu_from_ned_frd

__all__ = ["POSITION_TOPICS", "px4_reproject", "read_ulog"]

FloatArray = NDArray[np.float64]
#: position topics in the order they are tried without ``topic``
POSITION_TOPICS = ("vehicle_global_position", "vehicle_local_position", "vehicle_gps_position",
                   "sensor_gps")
_ATTITUDE = "vehicle_attitude"
_TOPIC = re.compile(r"([a-z_0-9]+)(?:\[(\d{1,2})\])?")
#: PX4's CONSTANTS_RADIUS_OF_EARTH (m), the sphere of its local projection
PX4_EARTH_RADIUS_M = 6371000.0


def px4_reproject(
    x: FloatArray, y: FloatArray, ref_lat: FloatArray, ref_lon: FloatArray
) -> tuple[FloatArray, FloatArray]:
    """Latitude and longitude (deg) of local north ``x`` and east ``y`` (m) about the reference
    (deg): PX4's ``MapProjection::reproject`` (azimuthal equidistant, sphere of radius
    :data:`PX4_EARTH_RADIUS_M`), elementwise over arrays of one shape."""
    lat0, lon0 = np.radians(ref_lat), np.radians(ref_lon)
    xr, yr = x / PX4_EARTH_RADIUS_M, y / PX4_EARTH_RADIUS_M
    c = np.hypot(xr, yr)
    safe = np.where(c > 0, c, 1.0)
    sin_c, cos_c = np.sin(c), np.cos(c)
    lat = np.where(c > 0, np.arcsin(cos_c * np.sin(lat0) + xr * sin_c * np.cos(lat0) / safe),
                   lat0)
    lon = np.where(c > 0, lon0 + np.arctan2(yr * sin_c, safe * np.cos(lat0) * cos_c
                                            - xr * np.sin(lat0) * sin_c), lon0)
    return np.degrees(lat), np.degrees(lon)


def _load(path: Path, topics: list[str] | None, notes: list[str]) -> Any:
    from pyulog import ULog

    try:
        with parser_chatter("pyulog") as chatter:
            ulog = ULog(str(path), message_name_filter_list=topics, disable_str_exceptions=True)
    except Exception as exc:  # pyulog raises bare Exception/struct.error/IndexError on bad files
        raise ValueError(f"{path}: cannot read ULog ({type(exc).__name__}: {exc})") from None
    finally:
        notes[:] = chatter
    return ulog


def _f64(d: dict[str, Any], key: str, rows: Any = slice(None)) -> FloatArray:
    return np.asarray(d[key][rows], dtype=np.float64)


def _global(d: dict[str, Any], source: str) -> PoseLog | str:
    pos = np.stack([_f64(d, k) for k in ("lat", "lon", "alt")], axis=1)
    return PoseLog(format="PX4 ULog", source=source, t=_f64(d, "timestamp") * 1e-6,
                   position=pos, frame="geodetic")


def _local(d: dict[str, Any], source: str) -> PoseLog | str:
    n = len(d["timestamp"])
    valid = np.ones(n, dtype=bool)
    for flag in ("xy_valid", "z_valid"):
        if flag in d:
            valid &= d[flag].astype(bool)
    if not valid.any():
        return f"xy_valid or z_valid false in all {n} samples (no position estimate)"
    referenced = valid.copy()
    if all(k in d for k in ("xy_global", "z_global", "ref_lat", "ref_lon", "ref_alt")):
        referenced &= d["xy_global"].astype(bool) & d["z_global"].astype(bool)
        for k in ("ref_lat", "ref_lon", "ref_alt"):
            referenced &= np.isfinite(_f64(d, k))
    else:
        referenced[:] = False
    keep = referenced if referenced.any() else valid
    t = _f64(d, "timestamp", keep) * 1e-6
    x, y, z = (_f64(d, k, keep) for k in "xyz")
    vel = None
    if all(k in d for k in ("vx", "vy", "vz")):
        vel = np.stack([_f64(d, k, keep) for k in ("vx", "vy", "vz")], axis=1)
    notes = []
    if referenced.any():
        lat, lon = px4_reproject(x, y, _f64(d, "ref_lat", keep), _f64(d, "ref_lon", keep))
        alt = _f64(d, "ref_alt", keep) - z
        # velocity on geodetic logs is in ENU axes (PoseLog)
        log = PoseLog(format="PX4 ULog", source=source, t=t,
                      position=np.stack([lat, lon, alt], axis=1), frame="geodetic",
                      velocity=None if vel is None else vel[:, [1, 0, 2]] * [1.0, 1.0, -1.0])
        notes.append(f"{source}: placed geodetically about its reference (ref_lat, ref_lon, "
                     "ref_alt), as PX4 does")
    else:
        log = PoseLog(format="PX4 ULog", source=source, t=t, position=np.stack([x, y, z], axis=1),
                      frame="ned", velocity=vel)
        notes.append(f"{source}: no valid global reference (xy_global/z_global false or ref_lat "
                     "not finite): local NED about the EKF origin")
    dropped = n - int(keep.sum())
    if dropped:
        why = "with xy_valid/z_valid false" + (", or without a valid reference"
                                               if referenced.any() else "")
        notes.append(f"{source}: {dropped} sample(s) {why} dropped")
    log.notes.extend(notes)
    return log


def _gps(d: dict[str, Any], source: str) -> PoseLog | str:
    ok = np.asarray(d["fix_type"]) >= 3 if "fix_type" in d else np.ones(len(d["timestamp"]), bool)
    if not ok.any():
        return f"no 3D fix (fix_type >= 3) in its {ok.size} samples"
    if "latitude_deg" in d:
        pos = np.stack([_f64(d, k, ok) for k in ("latitude_deg", "longitude_deg",
                                                 "altitude_msl_m")], axis=1)
    else:
        pos = np.stack([_f64(d, k, ok) for k in ("lat", "lon", "alt")], axis=1) * [1e-7, 1e-7,
                                                                                   1e-3]
    log = PoseLog(format="PX4 ULog", source=source, t=_f64(d, "timestamp", ok) * 1e-6,
                  position=pos, frame="geodetic")
    if all(k in d for k in ("vel_n_m_s", "vel_e_m_s", "vel_d_m_s", "vel_ned_valid")) and bool(
            np.all(np.asarray(d["vel_ned_valid"])[ok])):
        log.velocity = np.stack([_f64(d, "vel_e_m_s", ok), _f64(d, "vel_n_m_s", ok),
                                 -_f64(d, "vel_d_m_s", ok)], axis=1)
    if not ok.all():
        log.notes.append(f"{source}: {int((~ok).sum())} sample(s) without a 3D fix dropped")
    return log


_MAKERS = {"vehicle_global_position": _global, "vehicle_local_position": _local,
           "vehicle_gps_position": _gps, "sensor_gps": _gps}
_NEEDS = {"vehicle_global_position": ("lat", "lon", "alt"),
          "vehicle_local_position": ("x", "y", "z"),
          "vehicle_gps_position": ("timestamp",), "sensor_gps": ("timestamp",)}


def _name(topic: str, instance: int) -> str:
    return topic if instance == 0 else f"{topic}[{instance}]"


def _wanted(path: Path, topic: str, held: dict[tuple[str, int], dict[str, Any]]
            ) -> tuple[str, int]:
    """``(topic, multi_id)`` that ``topic`` names; a wrong name fails listing what is held."""
    m = _TOPIC.fullmatch(topic.strip())
    if m is None or m[1] not in POSITION_TOPICS or (m[1], int(m[2] or 0)) not in held:
        raise ValueError(f"{path}: topic {topic!r}: not a position topic of this ULog; it has "
                         f"{_holds(held)} (topic NAME or NAME[instance])")
    return m[1], int(m[2] or 0)


def _holds(held: dict[tuple[str, int], dict[str, Any]]) -> str:
    return describe({_name(n, i): len(d["timestamp"]) for (n, i), d in held.items()}) if held \
        else f"none of {', '.join(POSITION_TOPICS)}"


def read_ulog(path: Path, *, vehicle_id: int | None = None, topic: str | None = None) -> PoseLog:
    """The poses of a PX4 ULog (module docstring)."""
    notes: list[str] = []
    ulog = _load(path, [*POSITION_TOPICS, _ATTITUDE], notes)
    held: dict[tuple[str, int], dict[str, Any]] = {}
    att = None
    for d in ulog.data_list:
        if d.name == _ATTITUDE and d.multi_id == 0:
            att = d.data
        elif d.name in _MAKERS and len(d.data["timestamp"]) and all(
                k in d.data for k in _NEEDS[d.name]):
            held[(d.name, d.multi_id)] = d.data
    if topic is not None:
        order = [_wanted(path, topic, held)]
    else:
        order = [(n, 0) for n in POSITION_TOPICS if (n, 0) in held]
    log: PoseLog | None = None
    passed: list[str] = []
    for name, inst in order:
        made = _MAKERS[name](held[(name, inst)], _name(name, inst))
        if isinstance(made, PoseLog):
            log = made
            break
        passed.append(f"{_name(name, inst)}: {made}")
    if log is None:
        if topic is not None:
            raise NoPoseError(f"{path}: {passed[0]}; position topics in the log: "
                              f"{_holds(held)}")
        everything = _load(path, None, notes)
        found: dict[str, int] = {}
        for d in everything.data_list:
            found[d.name] = found.get(d.name, 0) + len(d.data["timestamp"])
        said = f" ({'; '.join(notes)})" if notes else ""
        tried = f"; {'; '.join(passed)}" if passed else ""
        raise NoPoseError(f"{path}: PX4 ULog without a usable pose: no usable "
                          f"{', '.join(POSITION_TOPICS)} sample{tried}; the log holds "
                          f"{describe(found)}{said}")
    log.notes[:0] = [f"{p}; {log.source} used" for p in passed]
    others = sorted(_name(n, i) for n, i in held if n == log.source.split("[")[0]
                    and _name(n, i) != log.source)
    if others:
        log.notes.append(f"other instances of {log.source.split('[')[0]} in the log: "
                         f"{', '.join(others)} (--topic NAME[N] chooses)")
    if att is not None and all(f"q[{i}]" in att for i in range(4)) and len(att["timestamp"]):
        q_ned = np.stack([att[f"q[{i}]"] for i in range(4)], axis=1).astype(np.float64)
        ok = np.linalg.norm(q_ned, axis=1) > 0
        log.att_t = att["timestamp"][ok] * 1e-6
        log.att_q = quat_enu_flu_from_ned_frd(q_ned[ok])
        log.att_source = _ATTITUDE
    log.vehicle_id = vehicle_id
    log.notes.extend(notes)
    return log
