"""Launch entries with and without an end of their own, for test_launch_finished.py.

Allowed in a launch with ``allow_modules: [tests.hil_bridge.launch.endnodes]``.
"""

from __future__ import annotations

from typing import Any


class Ends:
    """Finished once ``finished()`` was asked ``after`` times since ``start()`` (never before
    its start); ``after: null`` never finishes; ``has_end: false`` has no end (None)."""

    def __init__(self, name: str, *, bus: str, after: int | None = 3,
                 has_end: bool = True) -> None:
        self.name, self.bus, self.after, self.has_end = name, bus, after, has_end
        self.asked = 0
        self.started = False

    def start(self) -> None:
        self.started = True

    def stop(self) -> None:
        self.started = False

    def stats(self) -> dict[str, Any]:
        return {"asked": self.asked}

    def finished(self) -> bool | None:
        if not self.has_end:
            return None
        if self.started:
            self.asked += 1
        return self.after is not None and self.asked >= self.after
