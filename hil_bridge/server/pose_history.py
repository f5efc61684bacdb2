"""A short history of some vehicles' poses, one entry per tick, interpolated for the instants
between ticks (a ping's emission).

:class:`PoseHistory` is fed by whoever sees the ticks: the server's
:class:`~hil_bridge.server.fleet.Fleet` records every tick it computes, an echo node
(:mod:`hil_bridge.server.echo_nodes`) records the states it receives on the bus. Fed the same
ticks, both give the same poses bit for bit: the bus carries the float64 values unchanged.
Listeners (:meth:`PoseHistory.add_listener`) are told of every recorded tick. Every method is
thread-safe; :meth:`record` is called from one thread (the one that sees the ticks).
"""

from __future__ import annotations

import bisect
import math
import threading
from collections import deque
from collections.abc import Callable, Iterable, Sequence
from dataclasses import dataclass
from typing import Any, Literal

import numpy as np
from numpy.typing import NDArray

from sim_core.pose import pose_extrapolate, pose_interpolate, velocity_interpolate

__all__ = ["PoseHistory", "PoseSource", "VehiclePose"]

F8 = NDArray[np.float64]

#: where a :class:`VehiclePose` comes from: between two recorded ticks (or on one),
#: extrapolated past the newest, or the newest (oldest) state for a time after (before) those
PoseSource = Literal["history", "extrapolated", "newest", "oldest"]


@dataclass(frozen=True, slots=True)
class VehiclePose:
    """A vehicle's pose at ``t_ns``: ``position`` (3,) m, ``orientation`` (4,) world-from-body,
    ``velocity`` (3,) m/s world, body ``rates`` (3,) rad/s; ``source`` says how it was found
    (:data:`PoseSource`; for ``newest``/``oldest``, ``t_ns`` is that state's); ``ahead_ns``:
    how far past the newest state an extrapolated pose lies."""

    t_ns: int
    position: F8
    orientation: F8
    velocity: F8
    rates: F8
    source: PoseSource
    ahead_ns: int = 0


class PoseHistory:
    """The poses of vehicles ``ids`` over the last ``history_s`` s of ticks ``tick_ns`` apart
    (at least two ticks)."""

    def __init__(self, ids: Iterable[int], *, tick_ns: int, history_s: float) -> None:
        keep = max(2, math.ceil(history_s * 1e9 / tick_ns) + 1)
        #: per id: (t_ns, position, velocity, quat, rates) of each recorded tick
        self._history: dict[int, deque[tuple[int, F8, F8, F8, F8]]] = {
            int(i): deque(maxlen=keep) for i in sorted(ids)
        }
        self._lock = threading.Lock()
        self._recorded_ns = -1
        self._listeners: list[Callable[[int], None]] = []
        self._mirror: Any = None

    def mirror_to(self, ring: Any) -> None:
        """Also write every tick that records all of :attr:`ids` to ``ring``
        (:meth:`hil_bridge.server.pose_ring.PoseRing.write`, rows in the order of
        :attr:`ids`)."""
        self._mirror = ring

    @property
    def ids(self) -> tuple[int, ...]:
        """The vehicles kept, in increasing id order."""
        return tuple(self._history)

    def add_listener(self, callback: Callable[[int], None]) -> None:
        """Call ``callback(t_ns)`` after every recorded tick, on the recording thread: it must
        not block. Add listeners before the first tick is recorded."""
        self._listeners.append(callback)

    @property
    def recorded_ns(self) -> int:
        """The newest recorded tick (sim ns; -1 before the first)."""
        with self._lock:
            return self._recorded_ns

    def record(self, t_ns: int, ids: Sequence[int], position: F8, velocity: F8, quat: F8,
               rates: F8) -> None:
        """The poses of tick ``t_ns``: rows of ``position``, ``velocity`` (M, 3), ``quat``
        (M, 4), ``rates`` (M, 3) in the order of ``ids`` (those not kept are ignored; a kept id
        missing from ``ids`` records nothing). The same tick again replaces it."""
        if not self._history:
            return
        rows = []
        with self._lock:
            for k, vid in enumerate(ids):
                hist = self._history.get(vid)
                if hist is None:
                    continue
                if hist and hist[-1][0] == t_ns:
                    hist.pop()  # the same tick again: the newer computation replaces it
                hist.append((t_ns, position[k].copy(), velocity[k].copy(), quat[k].copy(),
                             rates[k].copy()))
                rows.append(k)
            self._recorded_ns = max(self._recorded_ns, t_ns)
        if self._mirror is not None and len(rows) == len(self._history):
            order = [rows[i] for i in np.argsort([ids[k] for k in rows], kind="stable")]
            self._mirror.write(t_ns, position[order], velocity[order], quat[order], rates[order])
        for listener in self._listeners:
            listener(t_ns)

    def latest(self, vid: int) -> tuple[int, F8, F8] | None:
        """Vehicle ``vid``'s newest recorded ``(t_ns, position (3,), velocity (3,))``, or None
        before its first state."""
        with self._lock:
            hist = self._history[vid]
            if not hist:
                return None
            t, p, v, _, _ = hist[-1]
        return t, p, v

    def pose_at(self, vid: int, t_ns: int, *, extrapolate_ns: int = 0) -> VehiclePose:
        """Vehicle ``vid``'s pose at ``t_ns``: interpolated between the two recorded states
        around it (Hermite position and velocity, slerp attitude, linear body rates); up to
        ``extrapolate_ns`` after the newest state, extrapolated from it (its velocity, its
        acceleration since the state before, its body rates:
        :func:`sim_core.pose.pose_extrapolate`); else the newest (oldest) state when ``t_ns``
        is after (before) the history."""
        with self._lock:
            hist = list(self._history[vid])
        if not hist:
            raise ValueError(f"no pose of vehicle {vid} recorded yet")
        times = [h[0] for h in hist]
        if t_ns > times[-1] and t_ns - times[-1] <= extrapolate_ns:
            t1, p1, v1, q1, w1 = hist[-1]
            accel = np.zeros(3)
            if len(hist) > 1:
                t0, _, v0, _, _ = hist[-2]
                accel = (v1 - v0) / ((t1 - t0) / 1e9)
            p, q, v = pose_extrapolate(t1 / 1e9, p1, v1, accel, q1, w1, t_ns / 1e9)
            return VehiclePose(t_ns, p, q, v, w1, "extrapolated", t_ns - t1)
        if t_ns >= times[-1]:
            t, p, v, q, w = hist[-1]
            return VehiclePose(t, p, q, v, w, "history" if t_ns == t else "newest")
        if t_ns < times[0]:
            t, p, v, q, w = hist[0]
            return VehiclePose(t, p, q, v, w, "oldest")
        k = bisect.bisect_right(times, t_ns) - 1
        (t0, p0, v0, q0, w0), (t1, p1, v1, q1, w1) = hist[k], hist[k + 1]
        a, b, at = t0 / 1e9, t1 / 1e9, t_ns / 1e9
        p, q = pose_interpolate(a, b, p0, p1, v0, v1, q0, q1, at)
        v = velocity_interpolate(a, b, p0, p1, v0, v1, at)
        s = (t_ns - t0) / (t1 - t0)
        return VehiclePose(t_ns, p, q, v, (1.0 - s) * w0 + s * w1, "history")
