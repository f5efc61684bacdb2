"""A launchable node that reports the scheduling of the threads its process runs."""

from __future__ import annotations

import os
import subprocess
import sys
import threading
from typing import Any

from hil_bridge.bus.transport import open_transport
from hil_bridge.priority import normal_children, realtime_priority


def _io_priorities() -> list[int]:
    """The real-time priority of each ZeroMQ I/O thread of this process."""
    out = []
    for tid in os.listdir("/proc/self/task"):
        with open(f"/proc/self/task/{tid}/comm") as f:
            if f.read().startswith("ZMQbg/IO"):
                out.append(realtime_priority(int(tid)))
    return out


def _child_priority() -> int:
    """The real-time priority a process started here begins with."""
    code = "import os; print(os.sched_getparam(0).sched_priority)"
    return int(subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                              check=True).stdout)


class SchedReporter:
    """``SchedReporter(name, *, bus)``: its stats give the real-time priority (0: normal) of the
    thread that built it, of the one that started it, of a thread it started, of the thread
    asking for its stats, of every Python thread of its process then (the distinct priorities),
    of its process's bus I/O threads, and of processes its thread starts as they are and within
    :func:`hil_bridge.priority.normal_children`."""

    def __init__(self, name: str, *, bus: str) -> None:
        self.name = name
        self.built_at = realtime_priority()
        self._transport = open_transport(bus)  # the bus's I/O thread starts with its sockets
        self.started_at = -1
        self._seen: dict[str, int] = {}

    def start(self) -> None:
        self.started_at = realtime_priority()
        done = threading.Event()

        def body() -> None:
            self._seen["thread"] = realtime_priority()
            self._seen["child"] = _child_priority()
            with normal_children():
                self._seen["child_normal"] = _child_priority()
            self._seen["thread_after"] = realtime_priority()
            done.set()

        threading.Thread(target=body, daemon=True).start()
        done.wait(60.0)

    def stop(self) -> None:
        self._transport.close()

    def stats(self) -> dict[str, Any]:
        return {"built_at": self.built_at, "started_at": self.started_at,
                "asked_at": realtime_priority(), "io": _io_priorities(),
                "threads": sorted({realtime_priority(t.native_id or 0)
                                   for t in threading.enumerate()}), **self._seen}
