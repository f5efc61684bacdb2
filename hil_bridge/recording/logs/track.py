"""From what a log holds to a :class:`sim_core.trajectory.Trajectory`, with a report of what
was used.

Every reader returns a :class:`PoseLog`: position samples in the log's own frame (local ENU,
local NED, or geodetic latitude/longitude/altitude), optionally an attitude stream at its
own times (already world-from-body ENU/FLU: NED/FRD ones go through
:func:`sim_core.pose.quat_enu_flu_from_ned_frd`), and heading, bank, speed or velocity
where the log has them.
:func:`to_trajectory` then does the same for every format:

1. rows with non-finite values are dropped and counted;
2. time jumps: a sample not later than the last kept one (clock reset, reordering, duplicate)
   is dropped and reported; gaps longer than ``max_gap_s`` are reported (the trajectory
   interpolates linearly across them, so the report says where that happens);
3. geodetic positions go to local ENU about ``origin`` (lat, lon, alt), default the first fix
   (pymap3d, WGS-84); NED positions to ENU (:func:`sim_core.pose.enu_from_ned`);
4. the attitude is interpolated (slerp) to the position times; heading = yaw and bank = −roll
   of it (a coordinated left turn has positive bank, ``docs/spec``); without attitude heading
   is the direction of travel and bank the coordinated-turn bank ``atan(V ψ̇ / g)``;
5. speed: the log's, else the norm of its velocity, else the slope of the ENU track;
6. position jumps: a step between two samples implying a speed above ``max_speed_mps`` (an
   origin reset, a GPS glitch: no vehicle flies it) is reported with its time and size, and the
   track is split there into *segments*, never interpolated through. One segment is flown:
   ``segment`` (0-based), by default the longest in time (the first of equally long ones);
   the report lists them all with their time spans.
"""

from __future__ import annotations

import contextlib
import io
import os
import sys
import tempfile
from collections.abc import Iterator
from dataclasses import dataclass, field
from typing import Any, Literal

import numpy as np
from numpy.typing import NDArray

from hil_bridge.errors import HilError
from sim_core.pose import enu_from_ned, euler_from_quat, quat_normalize, quat_slerp
from sim_core.trajectory import Trajectory

__all__ = ["MAX_SPEED_MPS", "LogReport", "NoPoseError", "PoseLog", "describe", "parser_chatter",
           "to_trajectory"]

FloatArray = NDArray[np.float64]
G = 9.81
#: default position-jump threshold (m/s): faster than any vehicle the project replays flies
MAX_SPEED_MPS = 150.0
#: at most this many gaps / jumps are listed one by one in a report (all are counted)
_LISTED = 5


class NoPoseError(HilError, ValueError):
    """A log holds no usable pose; the message lists what the file holds."""


@dataclass
class PoseLog:
    """Poses as a log holds them (see the module docstring); arrays over K position samples.

    ``frame``: ``"enu"``/``"ned"`` metres about the log's local origin, or ``"geodetic"``
    (``position`` columns latitude deg, longitude deg, altitude m). ``att_t`` (A,) s and
    ``att_q`` (A, 4) ENU/FLU world-from-body; ``velocity`` (K, 3) in ``frame``'s axes
    (ENU axes for geodetic logs, NED for NED); ``heading``/``bank``/``speed`` (K,) when the
    log has them.
    """

    format: str
    source: str
    t: FloatArray
    position: FloatArray
    frame: Literal["enu", "ned", "geodetic"]
    att_t: FloatArray | None = None
    att_q: FloatArray | None = None
    att_source: str = ""
    velocity: FloatArray | None = None
    heading: FloatArray | None = None
    bank: FloatArray | None = None
    speed: FloatArray | None = None
    vehicle_id: int | None = None
    notes: list[str] = field(default_factory=list)


@dataclass
class LogReport:
    """What a trajectory was made of, and what in the log looked wrong."""

    path: str
    format: str
    source: str
    att_source: str
    samples: int
    duration_s: float
    rate_hz: float
    origin: tuple[float, float, float] | None
    nonfinite: int = 0
    backward: list[tuple[float, float]] = field(default_factory=list)
    gaps: list[tuple[float, float]] = field(default_factory=list)
    #: (time s of the sample after the step, step m, implied speed m/s)
    jumps: list[tuple[float, float, float]] = field(default_factory=list)
    #: (first time s, last time s, samples) of each jump-free piece; ``segment`` is flown
    segments: list[tuple[float, float, int]] = field(default_factory=list)
    segment: int = 0
    max_speed_mps: float = MAX_SPEED_MPS
    vehicle_id: int | None = None
    notes: list[str] = field(default_factory=list)
    heading_from_track: bool = False

    def lines(self) -> list[str]:
        """The report as short lines for a terminal (first line: what was read)."""
        if self.att_source:
            att = f" + {self.att_source}"
        elif self.heading_from_track:
            att = " (no attitude: heading and bank from the track)"
        else:
            att = " (no attitude: heading and bank as logged)"
        out = [f"{self.path}: {self.format}, {self.source}{att}: {self.samples} poses over "
               f"{self.duration_s:.2f} s ({self.rate_hz:.1f} Hz)"]
        if self.origin is not None:
            out.append("  local ENU origin lat {:.7f} lon {:.7f} alt {:.2f} m".format(*self.origin))
        if self.nonfinite:
            out.append(f"  dropped {self.nonfinite} sample(s) with non-finite values")
        if self.backward:
            listed = ", ".join(f"{a:.3f} -> {b:.3f} s" for a, b in self.backward[:_LISTED])
            out.append(f"  time jumps back: {len(self.backward)} sample(s) dropped ({listed})")
        if self.gaps:
            listed = ", ".join(f"{a:.3f}-{b:.3f} s" for a, b in self.gaps[:_LISTED])
            out.append(f"  time gaps: {len(self.gaps)}, interpolated linearly across ({listed})")
        if self.jumps:
            listed = ", ".join(f"{a:.3f} s: {m:.1f} m ({v:.0f} m/s)"
                               for a, m, v in self.jumps[:_LISTED])
            out.append(f"  position jumps (faster than {self.max_speed_mps:g} m/s): "
                       f"{len(self.jumps)}, never flown ({listed})")
            spans = ", ".join(f"{k}: {a:.3f}-{b:.3f} s ({n} poses)"
                              for k, (a, b, n) in enumerate(self.segments))
            out.append(f"  segments: {spans}; segment {self.segment} flown (--segment "
                       "chooses)")
        out.extend(f"  {n}" for n in self.notes)
        return out

    def as_dict(self) -> dict[str, Any]:
        return {
            "path": self.path, "format": self.format, "source": self.source,
            "attitude": self.att_source, "samples": self.samples,
            "duration_s": self.duration_s, "rate_hz": self.rate_hz,
            "origin": None if self.origin is None else list(self.origin),
            "nonfinite": self.nonfinite, "time_jumps_back": [list(b) for b in self.backward],
            "gaps": [list(g) for g in self.gaps], "position_jumps": [list(j) for j in self.jumps],
            "segments": [list(g) for g in self.segments], "segment": self.segment,
            "max_speed_mps": self.max_speed_mps,
            "vehicle_id": self.vehicle_id, "notes": list(self.notes),
            "heading_from_track": self.heading_from_track,
        }


def _monotonic(t: FloatArray) -> tuple[NDArray[np.bool_], list[tuple[float, float]]]:
    """Mask keeping samples later than every earlier kept one; the (previous, new) time of
    each dropped sample."""
    keep = np.ones(t.shape, dtype=bool)
    running = np.maximum.accumulate(t)
    keep[1:] = t[1:] > running[:-1]
    dropped = np.flatnonzero(~keep)
    return keep, [(float(running[i - 1]), float(t[i])) for i in dropped]


def _track_heading_bank(t: FloatArray, xyz: FloatArray, speed: FloatArray) -> tuple[
        FloatArray, FloatArray]:
    v = np.gradient(xyz[:, :2], t, axis=0)
    heading = np.arctan2(v[:, 1], v[:, 0])
    rate = np.gradient(np.unwrap(heading), t)
    return heading, np.arctan(speed * rate / G)


def to_trajectory(
    log: PoseLog,
    *,
    path: str,
    origin: tuple[float, float, float] | None = None,
    max_gap_s: float = 1.0,
    max_speed_mps: float = MAX_SPEED_MPS,
    segment: int | None = None,
) -> tuple[Trajectory, LogReport]:
    """The :class:`Trajectory` of ``log`` and its :class:`LogReport` (module docstring)."""
    if not max_speed_mps > 0:
        raise ValueError(f"max_speed_mps: expected a speed > 0 m/s, got {max_speed_mps}")
    if origin is not None and log.frame != "geodetic":
        raise ValueError(f"{path}: --origin needs geodetic positions; {log.source} holds local "
                         f"{log.frame.upper()} metres")
    t = np.asarray(log.t, dtype=np.float64)
    pos = np.asarray(log.position, dtype=np.float64)
    optional = {name: getattr(log, name) for name in ("velocity", "heading", "bank", "speed")}
    finite = np.isfinite(t) & np.all(np.isfinite(pos), axis=1)
    for arr in optional.values():
        if arr is not None:
            ok = np.isfinite(np.asarray(arr, dtype=np.float64))
            finite &= ok.all(axis=tuple(range(1, ok.ndim)))
    nonfinite = int(np.count_nonzero(~finite))
    t, pos = t[finite], pos[finite]
    opt = {k: None if v is None else np.asarray(v, dtype=np.float64)[finite]
           for k, v in optional.items()}
    keep, backward = _monotonic(t)
    t, pos = t[keep], pos[keep]
    opt = {k: None if v is None else v[keep] for k, v in opt.items()}
    if t.size < 2:
        raise NoPoseError(f"{path}: {log.source} has {t.size} usable pose(s) after dropping "
                          f"{nonfinite} non-finite and {len(backward)} out-of-order sample(s); "
                          "a trajectory needs at least 2")
    used_origin: tuple[float, float, float] | None = None
    velocity = opt["velocity"]
    if log.frame == "geodetic":
        import pymap3d

        used_origin = origin if origin is not None else (
            float(pos[0, 0]), float(pos[0, 1]), float(pos[0, 2]))
        e, n, u = pymap3d.geodetic2enu(pos[:, 0], pos[:, 1], pos[:, 2], *used_origin)
        xyz = np.stack([np.asarray(e), np.asarray(n), np.asarray(u)], axis=1)
    elif log.frame == "ned":
        xyz = enu_from_ned(pos)
        if velocity is not None:
            velocity = enu_from_ned(velocity)
    else:
        xyz = pos
    step = np.linalg.norm(np.diff(xyz, axis=0), axis=1)
    step_speed = step / np.diff(t)
    at = np.flatnonzero(step_speed > max_speed_mps)
    jumps = [(float(t[i + 1]), float(step[i]), float(step_speed[i])) for i in at]
    bounds = list(zip([0, *(at + 1).tolist()], [*(at + 1).tolist(), t.size], strict=True))
    segments = [(float(t[lo]), float(t[hi - 1]), hi - lo) for lo, hi in bounds]
    chosen = _segment(path, log.source, segments, segment)
    lo, hi = bounds[chosen]
    t, xyz = t[lo:hi], xyz[lo:hi]
    velocity = None if velocity is None else velocity[lo:hi]
    opt = {k: None if v is None else v[lo:hi] for k, v in opt.items()}
    dt = np.diff(t)
    gaps = [(float(t[i]), float(t[i + 1])) for i in np.flatnonzero(dt > max_gap_s)]
    if opt["speed"] is not None:
        speed = opt["speed"]
    elif velocity is not None:
        speed = np.linalg.norm(velocity, axis=1)
    else:
        speed = np.linalg.norm(np.gradient(xyz, t, axis=0), axis=1)
    notes = list(log.notes)
    quat = _attitude_at(log, t, notes)
    if quat is not None:
        roll, _, yaw = euler_from_quat(quat)
        heading, bank = yaw, -roll
    else:
        heading, bank = _track_heading_bank(t, xyz, speed)
    if opt["heading"] is not None:
        heading = opt["heading"]
    if opt["bank"] is not None:
        bank = opt["bank"]
    traj = Trajectory(t, xyz, heading, bank, speed, quat=quat)
    report = LogReport(
        path=path, format=log.format, source=log.source, att_source=log.att_source if
        quat is not None else "", samples=int(t.size), duration_s=float(t[-1] - t[0]),
        rate_hz=float(1.0 / np.median(dt)), origin=used_origin, nonfinite=nonfinite,
        backward=backward, gaps=gaps, jumps=jumps, segments=segments, segment=chosen,
        max_speed_mps=float(max_speed_mps), vehicle_id=log.vehicle_id, notes=notes,
        heading_from_track=quat is None and opt["heading"] is None,
    )
    return traj, report


def _segment(path: str, source: str, segments: list[tuple[float, float, int]],
             wanted: int | None) -> int:
    """The segment to fly: ``wanted``, else the longest in time; it needs 2 poses."""
    spans = ", ".join(f"{k}: {a:.3f}-{b:.3f} s ({n} poses)" for k, (a, b, n) in
                      enumerate(segments))
    if wanted is None:
        chosen = max(range(len(segments)), key=lambda k: (segments[k][1] - segments[k][0],
                                                          -k))
    elif 0 <= wanted < len(segments):
        chosen = wanted
    else:
        raise ValueError(f"{path}: segment {wanted}: {source} has {len(segments)} segment(s) "
                         f"between its position jumps ({spans})")
    if segments[chosen][2] < 2:
        raise NoPoseError(f"{path}: {source}: segment {chosen} has a single pose; a "
                          f"trajectory needs at least 2 (segments: {spans})")
    return chosen


def _attitude_at(log: PoseLog, t: FloatArray, notes: list[str]) -> FloatArray | None:
    """The log's attitude slerped to the position times ``t`` (K, 4), or None."""
    if log.att_t is None or log.att_q is None or len(log.att_t) == 0:
        return None
    at = np.asarray(log.att_t, dtype=np.float64)
    aq = np.asarray(log.att_q, dtype=np.float64)
    ok = np.isfinite(at) & np.all(np.isfinite(aq), axis=1) & (np.linalg.norm(aq, axis=1) > 0)
    at, aq = at[ok], aq[ok]
    keep, back = _monotonic(at)
    at, aq = at[keep], quat_normalize(aq[keep])
    if back:
        notes.append(f"attitude: {len(back)} out-of-order sample(s) dropped")
    if at.size == 0:
        return None
    if at.size == 1:
        return np.repeat(aq, t.size, axis=0)
    outside = int(np.count_nonzero((t < at[0]) | (t > at[-1])))
    if outside:
        notes.append(f"attitude: {outside} pose(s) outside the attitude's time span hold its "
                     "first/last sample")
    tq = np.clip(t, at[0], at[-1])
    seg = np.clip(np.searchsorted(at, tq, side="right") - 1, 0, at.size - 2)
    f = (tq - at[seg]) / (at[seg + 1] - at[seg])
    return quat_slerp(aq[seg], aq[seg + 1], f)


def describe(found: dict[str, int]) -> str:
    """``"a (3), b (10)"`` from ``{name: count}``, for :class:`NoPoseError` messages."""
    if not found:
        return "nothing"
    return ", ".join(f"{k} ({v})" for k, v in sorted(found.items()))


@contextlib.contextmanager
def parser_chatter(name: str) -> Iterator[list[str]]:
    """Collect what a third-party parser prints (pyulog and pymavlink print their warnings,
    pymavlink's C indexer straight to file descriptor 2) as report notes ``"<name>: <line>"``
    instead of letting it reach the terminal."""
    notes: list[str] = []
    buf = io.StringIO()
    sys.stderr.flush()
    saved = os.dup(2)
    try:
        with tempfile.TemporaryFile() as raw:
            os.dup2(raw.fileno(), 2)
            try:
                with contextlib.redirect_stdout(buf), contextlib.redirect_stderr(buf):
                    yield notes
            finally:
                os.dup2(saved, 2)
                raw.seek(0)
                text = buf.getvalue() + raw.read().decode("utf-8", "replace")
                lines = dict.fromkeys(ln.strip() for ln in text.splitlines() if ln.strip())
                notes.extend(f"{name}: {ln}" for ln in list(lines)[:3])
    finally:
        os.close(saved)
