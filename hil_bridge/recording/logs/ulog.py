"""PX4 ULog (``.ulg``) through pyulog.

Position: ``vehicle_global_position`` (``lat``, ``lon`` deg, ``alt`` m AMSL) when the log has
it, else ``vehicle_local_position`` (``x, y, z`` m NED about the EKF origin; ``vx, vy, vz``
m/s NED; samples with ``xy_valid`` or ``z_valid`` false are dropped). Attitude:
``vehicle_attitude`` ``q[0..3]`` (world-from-body NED/FRD, converted to ENU/FLU). Times are
the messages' ``timestamp`` (µs since boot). Instance 0 of each topic is used.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from hil_bridge.recording.logs.track import NoPoseError, PoseLog, describe, parser_chatter
from sim_core.pose import quat_enu_flu_from_ned_frd

__all__ = ["read_ulog"]

_TOPICS = ["vehicle_global_position", "vehicle_local_position", "vehicle_attitude"]


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


def read_ulog(path: Path, *, vehicle_id: int | None = None, topic: str | None = None) -> PoseLog:
    """The poses of a PX4 ULog (module docstring)."""
    notes: list[str] = []
    ulog = _load(path, _TOPICS, notes)
    data = {d.name: d.data for d in ulog.data_list if d.multi_id == 0}
    glob, local, att = (data.get(n) for n in _TOPICS)
    if glob is not None and len(glob["timestamp"]):
        t = glob["timestamp"] * 1e-6
        pos = np.stack([glob["lat"], glob["lon"], glob["alt"]], axis=1).astype(np.float64)
        log = PoseLog(format="PX4 ULog", source="vehicle_global_position", t=t, position=pos,
                      frame="geodetic")
    elif local is not None and len(local["timestamp"]):
        valid = np.ones(len(local["timestamp"]), dtype=bool)
        for flag in ("xy_valid", "z_valid"):
            if flag in local:
                valid &= local[flag].astype(bool)
        t = local["timestamp"][valid] * 1e-6
        pos = np.stack([local[k][valid] for k in "xyz"], axis=1).astype(np.float64)
        vel = None
        if all(k in local for k in ("vx", "vy", "vz")):
            vel = np.stack([local[k][valid] for k in ("vx", "vy", "vz")], axis=1).astype(
                np.float64)
        log = PoseLog(format="PX4 ULog", source="vehicle_local_position", t=t, position=pos,
                      frame="ned", velocity=vel)
        if not valid.all():
            log.notes.append(f"vehicle_local_position: {int((~valid).sum())} sample(s) with "
                             "xy_valid/z_valid false dropped")
    else:
        everything = _load(path, None, notes)
        found: dict[str, int] = {}
        for d in everything.data_list:
            found[d.name] = found.get(d.name, 0) + len(d.data["timestamp"])
        said = f" ({'; '.join(notes)})" if notes else ""
        raise NoPoseError(f"{path}: PX4 ULog without a usable pose: no vehicle_global_position "
                          "or vehicle_local_position messages; the log holds "
                          f"{describe(found)}{said}")
    if att is not None and all(f"q[{i}]" in att for i in range(4)) and len(att["timestamp"]):
        q_ned = np.stack([att[f"q[{i}]"] for i in range(4)], axis=1).astype(np.float64)
        ok = np.linalg.norm(q_ned, axis=1) > 0
        log.att_t = att["timestamp"][ok] * 1e-6
        log.att_q = quat_enu_flu_from_ned_frd(q_ned[ok])
        log.att_source = "vehicle_attitude"
    log.vehicle_id = vehicle_id
    log.notes.extend(notes)
    return log
