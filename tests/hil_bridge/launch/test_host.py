"""The node host's own guards (hil_bridge.launch.host): a runner that is gone never leaves a host
serving, whether the host learns it from a reply it cannot send or from its watchdog."""

from __future__ import annotations

import multiprocessing
import os
import signal
import threading
from typing import Any

from hil_bridge.launch import host


class _Node:
    def __init__(self) -> None:
        self.stopped = 0

    def stats(self) -> dict[str, Any]:
        return {"ok": 1}

    def stop(self) -> None:
        self.stopped += 1


def test_a_reply_the_runner_cannot_receive_ends_the_service_and_stops_every_node() -> None:
    ours, theirs = multiprocessing.Pipe()
    theirs.close()  # the runner is gone
    nodes = {"a": _Node(), "b": _Node()}
    host._serve(ours, dict(nodes), threading.Event(), first=("stats", "a"))
    assert [n.stopped for n in nodes.values()] == [1, 1]
    ours.close()


def test_the_watchdog_stops_the_nodes_and_arms_the_alarm_once_the_parent_changed() -> None:
    stop_all = threading.Event()
    previous = signal.signal(signal.SIGALRM, signal.SIG_IGN)
    try:
        host._watchdog(os.getppid() + 1_000_000, stop_all)  # not our parent: it is "gone"
        assert stop_all.is_set()
        assert signal.alarm(0) > 0  # armed (and disarmed here)
    finally:
        signal.signal(signal.SIGALRM, previous)
