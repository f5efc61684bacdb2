"""Flight logs in: the trajectories people have, read into :class:`sim_core.trajectory.Trajectory`.

Formats, chosen by the file's content first and its extension second (:func:`detect_format`);
:data:`READERS` maps each name to ``"module:function"``, imported lazily:

- ``csv`` (``.csv`` with a header row): ``t`` and ``x, y, z`` (m ENU) or ``lat, lon, alt``
  (deg, deg, m); optional ``heading, bank, airspeed``, ``qw, qx, qy, qz`` (ENU/FLU), ``id``,
  ``alive`` (:mod:`hil_bridge.recording.logs.table`);
- ``npz``: the same columns as arrays (a swarm trace: ``t`` (T,), the others (T, N));
- ``ulog`` (PX4 ``.ulg``, pyulog): ``vehicle_global_position``, ``vehicle_local_position``
  (placed geodetically about its reference when it has one), ``vehicle_gps_position`` or
  ``sensor_gps`` (``topic`` chooses, ``NAME[N]`` an instance), and ``vehicle_attitude``;
- ``dataflash`` (ArduPilot ``.bin``, pymavlink): ``POS``, ``GPS`` (one receiver: the first,
  or ``topic`` ``GPS[1]``, ``GPS2``, ...) or ``AHR2``; ``ATT``/``AHR2``;
- ``tlog`` (MAVLink ``.tlog``, pymavlink): ``GLOBAL_POSITION_INT`` or ``LOCAL_POSITION_NED``
  (``topic`` chooses); ``ATTITUDE_QUATERNION`` or ``ATTITUDE``;
- ``ros2`` (a ROS 2 bag directory, ``.mcap`` or ``.db3``; rosbags): ``nav_msgs/Odometry``,
  ``geometry_msgs/PoseStamped`` or ``PoseWithCovarianceStamped`` (``topic`` chooses);
- ``echoloop`` (an echoloop recording, ``.mcap`` with profile ``echoloop``):
  ``/glider/<id>/state`` (``vehicle_id`` or ``topic`` chooses).

Every reader honours ``topic`` (the position source by name) or refuses it (CSV/NPZ: a table
has one position); a name the file does not have fails with one line listing those it has.

Geodetic logs are converted to local ENU about the first fix or ``origin``; NED/FRD ones to
ENU/FLU; time jumps and gaps are reported, position jumps reported and never flown: the log is
split there and one segment flown (:mod:`hil_bridge.recording.logs.track`). A file without a
usable pose raises :class:`NoPoseError` listing what it holds.
"""

from __future__ import annotations

import importlib
from collections.abc import Callable
from functools import lru_cache
from pathlib import Path

from hil_bridge.recording.logs.track import (
    MAX_SPEED_MPS,
    LogReport,
    NoPoseError,
    PoseLog,
    to_trajectory,
)
from sim_core.trajectory import Trajectory

__all__ = [
    "MAX_SPEED_MPS",
    "READERS",
    "LogReport",
    "NoPoseError",
    "PoseLog",
    "detect_format",
    "load_trajectory",
    "read_log",
]

#: format name -> "module:function(path, *, vehicle_id, topic) -> PoseLog"
READERS: dict[str, str] = {
    "csv": "hil_bridge.recording.logs.table:read_csv",
    "npz": "hil_bridge.recording.logs.table:read_npz",
    "ulog": "hil_bridge.recording.logs.ulog:read_ulog",
    "dataflash": "hil_bridge.recording.logs.mavlink:read_dataflash",
    "tlog": "hil_bridge.recording.logs.mavlink:read_tlog",
    "ros2": "hil_bridge.recording.logs.rosbag:read_ros2_bag",
    "echoloop": "hil_bridge.recording.logs.recording:read_recording",
}

_EXTENSIONS = {".csv": "csv", ".txt": "csv", ".npz": "npz", ".ulg": "ulog", ".bin": "dataflash",
               ".tlog": "tlog", ".db3": "ros2", ".mcap": "ros2"}
_MCAP_MAGIC = b"\x89MCAP0\r\n"


def _mcap_profile(head: bytes) -> str:
    """The profile string of an MCAP header record that follows the magic (``""`` if cut)."""
    rec = head[len(_MCAP_MAGIC):]
    if len(rec) < 13 or rec[0] != 0x01:
        return ""
    n = int.from_bytes(rec[9:13], "little")
    return rec[13:13 + n].decode("utf-8", "replace")


def detect_format(path: str | Path) -> str:
    """The :data:`READERS` name for ``path``, from its content, else its extension."""
    p = Path(path)
    if p.is_dir():
        if (p / "metadata.yaml").exists() or any(p.glob("*.mcap")) or any(p.glob("*.db3")):
            return "ros2"
        raise ValueError(f"{p}: a directory that is no ROS 2 bag (no metadata.yaml, .mcap or "
                         ".db3 inside)")
    try:
        with open(p, "rb") as f:
            head = f.read(4096)
    except OSError as exc:
        raise ValueError(f"{p}: cannot read ({exc.strerror or exc})") from None
    if head.startswith(b"ULog\x01\x12\x35"):
        return "ulog"
    if head.startswith(_MCAP_MAGIC):
        return "echoloop" if _mcap_profile(head) == "echoloop" else "ros2"
    if head.startswith(b"SQLite format 3\x00"):
        return "ros2"
    if head.startswith(b"PK\x03\x04"):
        return "npz"
    if head.startswith(b"\xa3\x95"):
        return "dataflash"
    if len(head) > 9 and head[8] in (0xFE, 0xFD) and p.suffix.lower() != ".csv":
        return "tlog"
    by_ext = _EXTENSIONS.get(p.suffix.lower())
    if by_ext is not None:
        return by_ext
    try:
        first = head.decode("utf-8").lstrip().splitlines()[0] if head.strip() else ""
    except UnicodeDecodeError:
        first = ""
    if "," in first:
        return "csv"
    raise ValueError(
        f"{p}: unknown log format (content starts {head[:8]!r}, extension {p.suffix!r}); "
        f"expected one of {sorted(set(_EXTENSIONS))} or a ROS 2 bag directory"
    )


def _reader(name: str) -> Callable[..., PoseLog]:
    module, func = READERS[name].split(":")
    fn: Callable[..., PoseLog] = getattr(importlib.import_module(module), func)
    return fn


@lru_cache(maxsize=8)
def _read_cached(
    path: str, stamp: tuple[int, int], vehicle_id: int | None, topic: str | None,
    origin: tuple[float, float, float] | None, max_gap_s: float, max_speed_mps: float,
    segment: int | None,
) -> tuple[Trajectory, LogReport]:
    fmt = detect_format(path)
    log = _reader(fmt)(Path(path), vehicle_id=vehicle_id, topic=topic)
    return to_trajectory(log, path=path, origin=origin, max_gap_s=max_gap_s,
                         max_speed_mps=max_speed_mps, segment=segment)


def read_log(
    path: str | Path,
    *,
    vehicle_id: int | None = None,
    topic: str | None = None,
    origin: tuple[float, float, float] | None = None,
    max_gap_s: float = 1.0,
    max_speed_mps: float = MAX_SPEED_MPS,
    segment: int | None = None,
) -> tuple[Trajectory, LogReport]:
    """Trajectory and :class:`LogReport` of a flight log of any format in :data:`READERS`.

    ``vehicle_id``: the vehicle of a multi-vehicle log (a swarm trace, a recording, a tlog
    with several systems); ``topic``: the position source by name (a ROS 2 bag's pose topic;
    a ULog topic, ``NAME[N]`` for instance N; a tlog's ``GLOBAL_POSITION_INT`` or
    ``LOCAL_POSITION_NED``; a DataFlash ``POS``, ``AHR2``, ``GPS[N]``, ``GPS2`` = ``GPS[1]``; a
    recording's ``/glider/<id>/state``; refused by CSV/NPZ); ``origin``: (lat deg, lon deg,
    alt m) of the local ENU frame for geodetic logs (default the first fix); ``max_gap_s``:
    longer intervals between poses are reported as gaps; ``max_speed_mps``: a step implying a
    faster speed is a position jump, where the log is split into segments; ``segment``: the
    one to fly (0-based; default the longest in time). Raises ``ValueError``
    (:class:`NoPoseError` when the file has no usable pose) naming the file. Results are
    cached per file version, so the replay command, the server and an echo worker process
    that read one log parse it once each.
    """
    p = Path(path)
    try:
        st = p.stat()
    except OSError as exc:
        raise ValueError(f"{p}: cannot read ({exc.strerror or exc})") from None
    org: tuple[float, float, float] | None = None
    if origin is not None:
        if len(origin) != 3:
            raise ValueError(f"origin: expected (lat, lon, alt), got {origin!r}")
        org = (float(origin[0]), float(origin[1]), float(origin[2]))
    if segment is not None and segment < 0:
        raise ValueError(f"segment: expected an index >= 0, got {segment}")
    return _read_cached(str(p), (st.st_mtime_ns, st.st_size), vehicle_id, topic,
                        org, float(max_gap_s), float(max_speed_mps), segment)


def load_trajectory(
    path: str | Path,
    *,
    vehicle_id: int | None = None,
    topic: str | None = None,
    origin: tuple[float, float, float] | None = None,
    max_speed_mps: float = MAX_SPEED_MPS,
    segment: int | None = None,
) -> Trajectory:
    """The trajectory of :func:`read_log` (the scene's ``kind: file`` reader)."""
    return read_log(path, vehicle_id=vehicle_id, topic=topic, origin=origin,
                    max_speed_mps=max_speed_mps, segment=segment)[0]

