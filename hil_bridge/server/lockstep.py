"""Lockstep: who the simulation server waits for before each step, and for how long.

In ``lockstep`` mode the server (:class:`hil_bridge.server.sim_server.SimServer`) publishes a
tick, then asks :meth:`LockstepGate.wait` before computing the next one. The gate holds it until
every
*participant* has answered what that tick owes it:

1. **Autopilots** (by glider/vehicle id). An autopilot answers each state *step* it is sent
   with one ``GliderCmd`` whose ``step`` is that state's ``step`` (the CAN adapter maps the
   answered CAN sample back to it). A swarm glider's state step changes only with a physics
   step, so its answer is needed before the next physics step; a commanded vehicle moves at
   every tick, so its answer is needed before every tick. Dead gliders owe nothing.
2. **Sonar heads** (by sonar id). A head that pings on sim time fires its ping stamped ``h``
   once it has seen a tick at or after ``h``, and says when its next ping is due
   (``SonarPing.next_ns``). The gate holds the server at the first tick at or after ``h``
   until that ping arrived, so the ping is answered at the pose of that tick. While the server
   itself still computes the previous echo of a head (which a lockstep head waits for before
   its next ping), that head's wait does not time out. A ping of a lockstep head that is not a
   sim-time ping (``next_ns < 0``: fired on the head's own clock before it followed the host)
   is not answered (``pings_ignored``).

A participant registers with its first answer (a command; a ping with ``next_ns >= 0``) or is
registered up front (the server's ``autopilots`` and ``sonar_heads``): only up-front
registration makes the first steps deterministic. A participant not heard from yet is waited
for up to ``start_timeout_s`` (start-up of the other nodes); afterwards up to ``timeout_s`` per
step. A miss is a *stall* (``stalls`` counts participant-steps, ``stalled_steps`` steps): the
step goes ahead on held commands. ``max_stalls`` misses in a row release the participant
(``lockstep_released``, listed in ``freewheeling``) until it answers again. While waiting, the
``resend`` callback (the server re-publishing its last tick) runs every ``resend_s``, so
messages lost before every subscriber was connected are sent again. Never a deadlock.
"""

from __future__ import annotations

import threading
import time
from collections.abc import Callable, Iterable, Mapping
from dataclasses import dataclass
from typing import Any

from hil_bridge.files.config import load_yaml

__all__ = ["LockstepGate", "Pacer", "runs_lockstep", "speed_params"]


class Pacer:
    """Holds a tick loop to ``speed`` sim seconds per wall second, from when it is made:
    :meth:`wait` before the tick at sim time ``t_ns`` sleeps until its wall time (or ``stop``).
    ``catch_up`` keeps the schedule when the loop falls behind (``realtime``: it catches up,
    and a tick more than one ``tick_ns`` late is reported); otherwise a late tick re-bases the
    schedule on itself (a lockstep run at most ``speed`` never bursts to make up a slow
    partner)."""

    def __init__(self, speed: float, tick_ns: int, stop: threading.Event, *,
                 catch_up: bool) -> None:
        self.speed, self.tick_s, self.stop, self.catch_up = speed, tick_ns / 1e9, stop, catch_up
        self._wall0, self._sim0 = time.monotonic(), 0

    def wait(self, t_ns: int) -> bool:
        """Sleep until the tick at ``t_ns`` is due; True if it was more than a tick late."""
        remaining = self._wall0 + (t_ns - self._sim0) / 1e9 / self.speed - time.monotonic()
        if remaining > 0:
            self.stop.wait(remaining)
            return False
        late = remaining < -self.tick_s
        if late and not self.catch_up:
            self._wall0, self._sim0 = time.monotonic(), t_ns
        return late


def _clock_of(params: Mapping[str, Any]) -> Mapping[str, Any]:
    """The clock a server of launch ``params`` runs: its ``clock``, else its scene's."""
    clock = params.get("clock")
    if clock is None:
        scene = params.get("scene")
        data = scene if isinstance(scene, Mapping) else load_yaml(scene) if isinstance(
            scene, str) else None
        clock = data.get("clock") if isinstance(data, Mapping) else None
    return clock if isinstance(clock, Mapping) else {}


def runs_lockstep(params: Mapping[str, Any]) -> bool:
    """Whether a server of launch ``params`` runs a ``lockstep`` clock: a launch then composes
    it with its firmware nodes (:func:`hil_bridge.launch.spec.compose_lockstep`)."""
    return _clock_of(params).get("mode") == "lockstep"


def speed_params(params: Mapping[str, Any], speed: float | None) -> dict[str, Any]:
    """A server's launch ``params`` at ``speed`` (``echoloop launch --speed``): a ``realtime``
    clock at that ``rate`` (None: ``fast``), a ``lockstep`` or ``fast`` one at that
    ``max_speed`` (None: unpaced)."""
    clock = dict(_clock_of(params))
    if clock.get("mode", "realtime") == "realtime":
        clock.update({"mode": "fast"} if speed is None else {"rate": speed})
    else:
        clock["max_speed"] = speed
    return {**params, "clock": clock}

_Key = tuple[str, int]  # ("glider", id) or ("sonar", id)


@dataclass(slots=True)
class _Owed:
    step: int
    alive: bool
    every_tick: bool


class LockstepGate:
    """See the module docstring. Thread-safe: callbacks feed it, the tick loop waits on it."""

    def __init__(
        self,
        *,
        lockstep: bool,
        timeout_s: float,
        max_stalls: int,
        start_timeout_s: float,
        resend_s: float = 0.5,
        autopilots: Iterable[int] = (),
        sonars: Iterable[int] = (),
    ) -> None:
        if not (timeout_s > 0 and start_timeout_s > 0 and resend_s > 0) or max_stalls < 1:
            raise ValueError(
                f"lockstep needs timeout_s, start_timeout_s, resend_s > 0 and max_stalls >= 1; "
                f"got {timeout_s}, {start_timeout_s}, {resend_s}, {max_stalls}"
            )
        self.lockstep = bool(lockstep)
        self.timeout_s = float(timeout_s)
        self.start_timeout_s = float(start_timeout_s)
        self.resend_s = float(resend_s)
        self.max_stalls = int(max_stalls)
        self._cond = threading.Condition()
        self._interrupted = False
        self.autopilots: set[int] = {int(a) for a in autopilots}
        self._answered: dict[int, int] = {}
        self._owed: dict[int, _Owed] = {}
        self._holds: dict[int, int] = {int(s): 0 for s in sonars}
        self._echoes_pending: dict[int, int] = {}
        self._echo_done_at: dict[int, float] = {}
        self._heard: set[_Key] = set()
        self._freewheel: set[_Key] = set()
        #: stalls per participant ("glider 3", "sonar 0")
        self._stalls_by: dict[str, int] = {}
        self._in_a_row: dict[_Key, int] = {}
        self.counters = {"stalls": 0, "stalled_steps": 0, "lockstep_released": 0,
                         "lockstep_resends": 0, "pings_ignored": 0}

    # ------------------------------------------------------------------ fed by the server

    def on_cmd(self, gid: int, step: int) -> None:
        """A command from glider ``gid``'s autopilot answering state step ``step``."""
        key = ("glider", gid)
        with self._cond:
            self.autopilots.add(gid)
            self._answered[gid] = max(self._answered.get(gid, -1), int(step))
            self._heard.add(key)
            self._freewheel.discard(key)
            self._cond.notify_all()

    def on_ping(self, sonar: int, stamp_ns: int, next_ns: int) -> bool:
        """A ping of ``sonar`` stamped ``stamp_ns``; ``next_ns >= 0``: the head pings on sim
        time and its next ping is due then. Returns whether to answer it; its echo is then
        pending until :meth:`echo_done`."""
        key = ("sonar", sonar)
        with self._cond:
            if self.lockstep and next_ns < 0 and sonar in self._holds:
                self.counters["pings_ignored"] += 1
                return False
            self._echoes_pending[sonar] = self._echoes_pending.get(sonar, 0) + 1
            if next_ns >= 0:
                hold = self._holds.get(sonar)
                if hold is None or stamp_ns >= hold:
                    self._holds[sonar] = int(next_ns)
                self._heard.add(key)
                self._freewheel.discard(key)
            self._cond.notify_all()
        return True

    def echo_done(self, sonar: int) -> None:
        """The server published (or gave up) the echo of one ping of ``sonar``."""
        with self._cond:
            self._echoes_pending[sonar] = max(0, self._echoes_pending.get(sonar, 0) - 1)
            self._echo_done_at[sonar] = time.monotonic()
            self._cond.notify_all()

    def published(self, gid: int, step: int, *, alive: bool, every_tick: bool) -> None:
        """The server published glider ``gid``'s state of ``step``."""
        with self._cond:
            self._owed[gid] = _Owed(int(step), bool(alive), bool(every_tick))

    def interrupt(self) -> None:
        """End any :meth:`wait` now and every later one at once (the server is stopping)."""
        with self._cond:
            self._interrupted = True
            self._cond.notify_all()

    # ------------------------------------------------------------------ the wait

    def pending(self) -> int:
        """Pings answered but whose echo is not yet published (or given up)."""
        with self._cond:
            return sum(self._echoes_pending.values())

    def _missing(self, t_ns: int, physics_due: bool, skip: set[_Key],
                 sonars_only: bool = False) -> list[_Key]:
        out: list[_Key] = []
        for gid in [] if sonars_only else sorted(self.autopilots):
            key = ("glider", gid)
            owed = self._owed.get(gid)
            if key in self._freewheel or key in skip or owed is None or not owed.alive:
                continue
            if not (owed.every_tick or physics_due):
                continue
            if self._answered.get(gid, -1) < owed.step:
                out.append(key)
        for sonar, hold in sorted(self._holds.items()):
            key = ("sonar", sonar)
            if key not in self._freewheel and key not in skip and hold <= t_ns:
                out.append(key)
        return out

    def _deadline(self, key: _Key, started: float) -> float | None:
        """Wall time at which ``key`` stalls this wait (None: not while its echo computes)."""
        since = started
        if key[0] == "sonar":
            if self._echoes_pending.get(key[1], 0) > 0:
                return None
            since = max(started, self._echo_done_at.get(key[1], started))
        return since + (self.timeout_s if key in self._heard else self.start_timeout_s)

    def wait(self, t_ns: int, *, physics_due: bool, resend: Callable[[], None] | None = None,
             sonars_only: bool = False) -> None:
        """Before the tick after ``t_ns`` (the last published one): wait for what it owes.

        ``physics_due``: the next tick steps the swarm, so swarm gliders must have answered.
        ``sonars_only``: wait for the sonar heads' pings only (after the last tick of a run
        with an end: a ping due at it is still answered, no autopilot is owed a next step).
        """
        started = time.monotonic()
        next_resend = started + self.resend_s
        stalled: set[_Key] = set()
        with self._cond:
            while not self._interrupted:
                missing = self._missing(t_ns, physics_due, stalled, sonars_only)
                if not missing:
                    break
                now = time.monotonic()
                deadlines = {key: self._deadline(key, started) for key in missing}
                late = [k for k, d in deadlines.items() if d is not None and d <= now]
                if late:
                    stalled.update(late)
                    continue
                if resend is not None and now >= next_resend:
                    next_resend = now + self.resend_s
                    self.counters["lockstep_resends"] += 1
                    self._cond.release()
                    try:
                        resend()
                    finally:
                        self._cond.acquire()
                    continue
                wakes = [d for d in deadlines.values() if d is not None]
                if resend is not None:
                    wakes.append(next_resend)
                self._cond.wait(max(0.0, min(wakes) - now) if wakes else 0.1)
            if self._interrupted:
                return
            if stalled:
                self.counters["stalled_steps"] += 1
                self.counters["stalls"] += len(stalled)
                for kind, ident in stalled:
                    name = f"{kind} {ident}"
                    self._stalls_by[name] = self._stalls_by.get(name, 0) + 1
            for key in stalled:
                n = self._in_a_row.get(key, 0) + 1
                self._in_a_row[key] = n
                if n >= self.max_stalls and key not in self._freewheel:
                    self._freewheel.add(key)
                    self.counters["lockstep_released"] += 1
            for key in self._heard - stalled:
                self._in_a_row[key] = 0

    # ------------------------------------------------------------------ report

    def stats(self) -> dict[str, Any]:
        """Counters plus ``freewheeling`` (glider ids), ``sonars_freewheeling`` and
        ``stalls_by`` (stalls per participant, ``"glider 3"``, ``"sonar 0"``: who held the loop
        up)."""
        with self._cond:
            out: dict[str, Any] = dict(self.counters)
            out["freewheeling"] = sorted(k[1] for k in self._freewheel if k[0] == "glider")
            out["sonars_freewheeling"] = sorted(k[1] for k in self._freewheel if k[0] == "sonar")
            out["lockstep_sonars"] = sorted(self._holds)
            out["stalls_by"] = dict(sorted(self._stalls_by.items()))
        return out
