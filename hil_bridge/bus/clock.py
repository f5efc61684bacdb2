"""Sim time: :class:`SimClock` (integer nanoseconds, never decreasing).

Modes (``SimClock(mode, rate=1.0, start_ns=0)``):

- ``realtime`` — sim time runs with the wall clock (``time.monotonic_ns``) times the real-time
  factor ``rate``; for physical hardware in the loop. The stepping owner paces itself with
  :meth:`SimClock.sleep_until`.
- ``lockstep`` — sim time moves only when the stepping owner calls :meth:`SimClock.advance` /
  :meth:`SimClock.set_ns`; before each step the owner waits for that step's commands from the
  registered autopilots (:class:`hil_bridge.server.sim_server.SimServer`: timeout → freewheel and
  count a stall).
- ``fast`` — as ``lockstep`` but the owner steps as fast as it can without waiting for anyone.

``pause()``/``resume()`` and ``set_rate()`` re-base the mapping so :meth:`SimClock.now_ns` stays
continuous and monotonic. Listeners (:meth:`SimClock.add_listener`) are told of every change, which
is how node timers on an owner-stepped clock wake up.
"""

from __future__ import annotations

import threading
import time
from collections.abc import Callable

__all__ = ["MODES", "SimClock", "default_clock"]

MODES = ("realtime", "lockstep", "fast")


class SimClock:
    """Sim time source (see the module docstring). Thread-safe."""

    def __init__(self, mode: str = "realtime", *, rate: float = 1.0, start_ns: int = 0) -> None:
        if mode not in MODES:
            raise ValueError(f"unknown clock mode {mode!r}; expected one of {list(MODES)}")
        self._check_rate(rate)
        if start_ns < 0:
            raise ValueError(f"start_ns must be >= 0, got {start_ns}")
        self.mode = mode
        self._rate = float(rate)
        self._cond = threading.Condition()
        self._paused = False
        self._base_sim = int(start_ns)
        self._base_wall = time.monotonic_ns()
        self._last = int(start_ns)
        self._listeners: list[Callable[[], None]] = []

    @staticmethod
    def _check_rate(rate: float) -> None:
        if not (isinstance(rate, (int, float)) and rate > 0 and rate < float("inf")):
            raise ValueError(f"real-time factor must be a finite number > 0, got {rate!r}")

    @property
    def rate(self) -> float:
        return self._rate

    @property
    def paused(self) -> bool:
        return self._paused

    @property
    def owner_stepped(self) -> bool:
        """True in ``lockstep`` and ``fast``: only :meth:`advance`/:meth:`set_ns` move time."""
        return self.mode != "realtime"

    def _raw(self) -> int:
        if self.mode != "realtime" or self._paused:
            return self._base_sim
        return self._base_sim + int((time.monotonic_ns() - self._base_wall) * self._rate)

    def now_ns(self) -> int:
        """Current sim time in ns; never smaller than any value returned before."""
        with self._cond:
            t = self._raw()
            if t < self._last:
                t = self._last
            self._last = t
            return t

    def _rebase(self) -> None:
        self._base_sim = max(self._raw(), self._last)
        self._base_wall = time.monotonic_ns()

    def _changed(self) -> None:
        self._cond.notify_all()

    def _notify_listeners(self) -> None:
        for listener in tuple(self._listeners):
            listener()

    def set_rate(self, rate: float) -> None:
        """Change the real-time factor from now on (time stays continuous)."""
        self._check_rate(rate)
        with self._cond:
            self._rebase()
            self._rate = float(rate)
            self._changed()
        self._notify_listeners()

    def pause(self) -> None:
        """Freeze sim time (``realtime``: stops following the wall clock). Idempotent."""
        with self._cond:
            if not self._paused:
                self._rebase()
                self._paused = True
                self._changed()
        self._notify_listeners()

    def resume(self) -> None:
        """Continue from the frozen time. Idempotent."""
        with self._cond:
            if self._paused:
                self._paused = False
                self._base_wall = time.monotonic_ns()
                self._changed()
        self._notify_listeners()

    def advance(self, dt_ns: int) -> int:
        """Owner-stepped modes: move time forward by ``dt_ns`` >= 0; return the new time."""
        if dt_ns < 0:
            raise ValueError(f"dt_ns must be >= 0, got {dt_ns}")
        with self._cond:
            target = max(self._base_sim, self._last) + int(dt_ns)
        return self.set_ns(target)

    def set_ns(self, t_ns: int) -> int:
        """Owner-stepped modes: jump to ``t_ns`` (never backwards: ``ValueError``)."""
        if not self.owner_stepped:
            raise ValueError("set_ns/advance need a 'lockstep' or 'fast' clock; this is 'realtime'")
        with self._cond:
            if t_ns < self._last:
                raise ValueError(f"sim time cannot go back from {self._last} to {t_ns} ns")
            self._base_sim = self._last = int(t_ns)
            self._changed()
        self._notify_listeners()
        return int(t_ns)

    def wall_seconds_until(self, t_ns: int) -> float | None:
        """Wall seconds until sim time reaches ``t_ns`` if the wall clock drives it, else None
        (owner-stepped or paused: only a change can make it arrive)."""
        with self._cond:
            now = max(self._raw(), self._last)
            if now >= t_ns:
                return 0.0
            if self.mode != "realtime" or self._paused:
                return None
            return (t_ns - now) / self._rate / 1e9

    def sleep_until(self, t_ns: int, *, timeout: float | None = None) -> bool:
        """Block until ``now_ns() >= t_ns`` or ``timeout`` wall seconds; True if reached."""
        deadline = None if timeout is None else time.monotonic() + timeout
        with self._cond:
            while True:
                now = max(self._raw(), self._last)
                if now >= t_ns:
                    return True
                wait: float | None = None
                if self.mode == "realtime" and not self._paused:
                    wait = (t_ns - now) / self._rate / 1e9
                if deadline is not None:
                    left = deadline - time.monotonic()
                    if left <= 0:
                        return False
                    wait = left if wait is None else min(wait, left)
                self._cond.wait(wait)

    def add_listener(self, callback: Callable[[], None]) -> None:
        """Call ``callback()`` (no arguments, must not block) after every time/rate change."""
        with self._cond:
            self._listeners.append(callback)

    def remove_listener(self, callback: Callable[[], None]) -> None:
        with self._cond:
            if callback in self._listeners:
                self._listeners.remove(callback)

    def __repr__(self) -> str:
        return f"SimClock({self.mode!r}, rate={self._rate}, now_ns={self.now_ns()})"


_DEFAULT: SimClock | None = None
_DEFAULT_LOCK = threading.Lock()


def default_clock() -> SimClock:
    """The process-wide clock of nodes given none: ``realtime`` at rate 1 whose sim time is the
    system's monotonic clock (so stamps of default-clock nodes agree across processes)."""
    global _DEFAULT
    with _DEFAULT_LOCK:
        if _DEFAULT is None:
            _DEFAULT = SimClock("realtime", start_ns=time.monotonic_ns())
        return _DEFAULT
