"""The pose of a sonar's vehicle at a ping's emission, found off the server's tick loop.

A ping is answered at its vehicle's pose at its emission stamp, from a pose history
(:meth:`hil_bridge.server.pose_history.PoseHistory.pose_at`: the fleet's in the server, the
bus's states in an echo node). :class:`EmissionPoses` finds it:

- a stamp the history covers: interpolated between the two ticks around it, at once;
- a stamp before the history: the oldest pose kept (``ping_stamp_old``);
- a stamp after the newest tick (by at most ``horizon_ns``, the server's ``pose_history_s``)
  while the server ticks: the ping is *held* until the history has recorded a tick at or after
  its stamp, then interpolated (``ping_stamp_waited``; the wall time it waited is in
  ``ping_wait_ms``). A held ping whose covering tick has not come ``wait_s`` wall seconds after
  its arrival (the server's ``pose_wait_ticks``), or when the server stops ticking, is
  *extrapolated* from the newest tick (its velocity, its acceleration since the tick before,
  its body rates: :func:`sim_core.pose.pose_extrapolate`; ``ping_stamp_extrapolated``, the
  sim time extrapolated in ``ping_extrapolated_ms``); so is such a ping when nothing waits
  (``wait_s`` 0) or the ticks have ended;
- a stamp later than that: the newest tick's pose (``ping_stamp_future``): the stamp is not
  on this server's time.

A held ping whose pose cannot be found (a bug) is logged and counted in ``ping_pose_errors``.

The tick loop never waits for any of it: the history tells :meth:`EmissionPoses.on_tick` of each
recorded tick, which only wakes this module's thread; that thread finds the poses of the pings
a tick released and hands them on (``on_pose``), in stamp order. Pings found at once are
handed on from the caller's thread (the bus's).

A history that is fed from elsewhere on demand (an echo node's, from the server's pose ring)
comes with ``refresh``: it is called before each ping's stamp is compared with the newest tick,
and every ``refresh_s`` by this module's thread while pings are held. Nothing polls the
history's source between pings, then, and a held ping waits at most ``refresh_s`` longer than
its tick.
"""

from __future__ import annotations

import logging
import threading
import time
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

from hil_bridge.bus.faults import Faults
from hil_bridge.server.pose_history import PoseHistory, VehiclePose

__all__ = ["EMISSION_COUNTERS", "EmissionPoses"]

log = logging.getLogger(__name__)

#: counters of :meth:`EmissionPoses.stats` (besides the gauge ``pings_waiting_tick``)
EMISSION_COUNTERS = ("ping_stamp_old", "ping_stamp_future", "ping_stamp_waited",
                     "ping_stamp_extrapolated", "ping_pose_errors")


@dataclass(frozen=True, slots=True)
class _Held:
    vid: int
    t_ns: int
    received: float
    payload: Any


class EmissionPoses:
    """Poses at the pings' emission (module docstring) of the vehicles of ``history``.

    ``horizon_ns``: how far (sim ns) after the newest tick a stamp may be and still be this
    server's time (waited for, or extrapolated); ``wait_s``: how long (wall s after its
    arrival) a ping stamped after the newest tick waits for its tick before it is
    extrapolated (0: never held). ``on_pose(payload, pose, received)`` gets every ping's pose;
    ``on_error(payload, why)`` (optional) each held ping whose pose could not be answered.
    ``refresh()`` (optional) brings the history up to date, every ``refresh_s`` wall seconds
    while pings are held (module docstring); it is never called under this object's lock, since
    it records ticks into the history, which calls ``on_tick``.
    ``start()`` starts the thread, ``ticks_ended()`` says the server stopped ticking (held
    pings are extrapolated now, later ones at once), ``close()`` does the same and joins the
    thread.
    """

    def __init__(self, history: PoseHistory, *, horizon_ns: int, wait_s: float,
                 on_pose: Callable[[Any, VehiclePose, float], None],
                 refresh: Callable[[], None] | None = None, refresh_s: float = 0.001,
                 on_error: Callable[[Any, str], None] | None = None) -> None:
        if horizon_ns < 0 or not wait_s >= 0 or not refresh_s > 0:
            raise ValueError(f"horizon_ns, wait_s, refresh_s: expected >= 0, >= 0, > 0, got "
                             f"{horizon_ns}, {wait_s}, {refresh_s}")
        self.history = history
        self._refresh = refresh
        self.refresh_s = float(refresh_s)
        self.horizon_ns = int(horizon_ns)
        self.wait_s = float(wait_s)
        self._on_pose = on_pose
        self._on_error = on_error
        self._cond = threading.Condition()
        self._held: list[_Held] = []
        self._newest = history.recorded_ns
        self._ticking = True
        self._closed = False
        self._thread: threading.Thread | None = None
        self._c = dict.fromkeys(EMISSION_COUNTERS, 0)
        self._wait_ms: deque[float] = deque(maxlen=10000)
        self._extrapolated_ms: deque[float] = deque(maxlen=10000)
        history.add_listener(self.on_tick)

    def start(self, faults: Faults) -> None:
        """Start the thread that answers held pings; an exception that ends it is reported to
        ``faults`` (the server's: the run fails naming it)."""
        if self._thread is None and self.wait_s > 0:
            self._thread = threading.Thread(
                target=faults.guarded("emission poses thread", self._run),
                name="emission-poses", daemon=True)
            self._thread.start()

    def on_tick(self, t_ns: int) -> None:
        """The history recorded tick ``t_ns`` (the recording thread: wakes the thread only)."""
        with self._cond:
            self._newest = max(self._newest, t_ns)
            if self._held:
                self._cond.notify()

    def ticks_ended(self) -> None:
        with self._cond:
            self._ticking = False
            self._cond.notify()

    def close(self) -> None:
        with self._cond:
            self._ticking = False
            self._closed = True
            self._cond.notify()
        if self._thread is not None:
            self._thread.join()
            self._thread = None

    def request(self, vid: int, t_ns: int, payload: Any, received: float) -> None:
        """Find vehicle ``vid``'s pose at emission ``t_ns`` for ``payload`` (arrived at
        ``received``, ``time.monotonic()``): at once, or once its tick is recorded."""
        if self._refresh is not None:
            self._refresh()
        with self._cond:
            hold = (self._ticking and self._thread is not None
                    and self._newest < t_ns <= self._newest + self.horizon_ns)
            if hold:
                self._held.append(_Held(vid, t_ns, received, payload))
                self._cond.notify()
        if not hold:
            self._answer(_Held(vid, t_ns, received, payload), held=False)

    def stats(self) -> dict[str, Any]:
        """The counters of :data:`EMISSION_COUNTERS`, ``pings_waiting_tick`` (held now) and
        the raw ``ping_wait_ms`` (wall ms each held ping waited) and ``ping_extrapolated_ms``
        (sim ms each extrapolated pose lies past the newest tick) lists."""
        with self._cond:
            out: dict[str, Any] = dict(self._c)
            out["pings_waiting_tick"] = len(self._held)
            out["ping_wait_ms"] = list(self._wait_ms)
            out["ping_extrapolated_ms"] = list(self._extrapolated_ms)
        return out

    def _answer(self, h: _Held, *, held: bool) -> None:
        pose = self.history.pose_at(h.vid, h.t_ns, extrapolate_ns=self.horizon_ns)
        counter = {"oldest": "ping_stamp_old", "newest": "ping_stamp_future",
                   "extrapolated": "ping_stamp_extrapolated",
                   "history": "ping_stamp_waited" if held else ""}[pose.source]
        with self._cond:
            if counter:
                self._c[counter] += 1
            if held:
                self._wait_ms.append((time.monotonic() - h.received) * 1e3)
            if pose.source == "extrapolated":
                self._extrapolated_ms.append(pose.ahead_ns / 1e6)
        self._on_pose(h.payload, pose, h.received)

    def _due(self) -> list[_Held] | None:
        """Under the lock: the held pings to answer now (stamp order), once there are some;
        None when closed with nothing held; an empty list when the history should be refreshed
        (``refresh_s`` passed with pings held)."""
        while True:
            now = time.monotonic()
            due: list[_Held] = []
            keep: list[_Held] = []
            for h in self._held:
                released = (h.t_ns <= self._newest or not self._ticking
                            or now >= h.received + self.wait_s)
                (due if released else keep).append(h)
            if due:
                self._held = keep
                return sorted(due, key=lambda h: h.t_ns)
            if self._closed:
                return None
            first = min((h.received for h in self._held), default=None)
            if first is None:
                self._cond.wait()
            elif self._refresh is None:
                self._cond.wait(first + self.wait_s - now)
            elif not self._cond.wait(min(first + self.wait_s - now, self.refresh_s)):
                return []

    def _run(self) -> None:
        while True:
            with self._cond:
                due = self._due()
            if due is None:
                return
            if not due:  # pings held: read the history's source (outside the lock)
                if self._refresh is not None:
                    self._refresh()
                continue
            for h in due:
                try:
                    self._answer(h, held=True)
                except Exception as exc:  # one ping's failure must not strand the others
                    log.exception("no pose at emission %d ns for vehicle %d", h.t_ns, h.vid)
                    with self._cond:
                        self._c["ping_pose_errors"] += 1
                    if self._on_error is not None:  # the ping is over: nothing waits for it
                        self._on_error(h.payload, f"no pose at emission: {exc!r}")
