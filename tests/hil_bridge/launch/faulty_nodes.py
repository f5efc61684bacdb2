"""Launch entries that fail on purpose, one way each (``mode``), for test_launch_failures.py.

Allowed in a launch with ``allow_modules: [tests.hil_bridge.launch.faulty_nodes]``.
"""

from __future__ import annotations

import threading
from typing import Any

from hil_bridge.bus.messages import Clock
from hil_bridge.bus.node import Node

MODES = ("callback", "timer", "constructor", "start", "recovers", "never_recovers")


class Faulty(Node):
    """A node that fails in ``mode``:

    - ``callback``: its ``/clock`` callback raises;
    - ``timer``: its timer (every 10 ms of wall time) raises;
    - ``constructor`` / ``start``: its constructor / ``start()`` raises;
    - ``recovers``: ``start()`` declares a recoverable fault at ``link``, its first ``/clock``
      recovers it and sets ``done`` (a ``threading.Event``, when given);
    - ``never_recovers``: ``start()`` declares it and nothing recovers it.
    """

    def __init__(self, name: str, *, bus: str, mode: str,
                 done: threading.Event | None = None) -> None:
        if mode not in MODES:
            raise ValueError(f"mode: expected one of {MODES}, got {mode!r}")
        if mode == "constructor":
            raise RuntimeError("wiring bug in the constructor")
        super().__init__(name, bus=bus)
        self.mode = mode
        self.done = done
        if mode in ("callback", "recovers"):
            self.create_subscription(Clock, "/clock", self._on_clock)
        if mode == "timer":
            self.create_timer(0.01, self._tick)

    def start(self) -> Faulty:
        if self.mode == "start":
            raise OSError("device busy")
        if self.mode in ("recovers", "never_recovers"):
            self.faults.report("link", "port vanished", recoverable=True)
        super().start()
        return self

    def _on_clock(self, msg: Clock) -> None:
        if self.mode == "callback":
            raise ValueError(f"cannot handle clock {msg.stamp_ns}")
        self.faults.recovered("link")
        if self.done is not None:
            self.done.set()

    def _tick(self) -> None:
        raise ZeroDivisionError("timer bug")

    def stats(self) -> dict[str, Any]:
        return {**super().stats(), "mode": self.mode}


class OldStyle:
    """A launchable written before ``failure(final=...)``: its ``failure()`` takes no argument
    and fails once asked ``asked_before_failing`` times."""

    def __init__(self, name: str, *, bus: str, asked_before_failing: int = 0) -> None:
        self.name = name
        self.asked = 0
        self.limit = asked_before_failing

    def start(self) -> None:
        """Nothing to start."""

    def stop(self) -> None:
        """Nothing to stop."""

    def stats(self) -> dict[str, Any]:
        return {"asked": self.asked}

    def failure(self) -> str | None:
        self.asked += 1
        return "legacy reason" if self.asked > self.limit else None
