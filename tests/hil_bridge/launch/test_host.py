"""The node host's own guards (hil_bridge.launch.host): a runner that is gone never leaves a host
serving, whether the host learns it from a reply it cannot send, from its watchdog or from
SIGTERMs that come in quick succession; either way the process is asked to stop, so a node
still starting gives up what it waits for (hil_bridge.lifetime)."""

from __future__ import annotations

import multiprocessing
import os
import signal
import time
from collections.abc import Iterator
from typing import Any

import pytest

from hil_bridge import lifetime
from hil_bridge.launch import host


@pytest.fixture(autouse=True)
def _own_stop_flag(monkeypatch: pytest.MonkeyPatch) -> Iterator[None]:
    """The process's stop flag of these tests' own: the suite's process is never asked to stop
    (its bus syncs and echo waits would give up)."""
    monkeypatch.setattr(lifetime, "_STOPPING", lifetime.StopFlag())
    yield


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
    host._serve(ours, dict(nodes), host.StopFlag(), first=("stats", "a"))
    assert [n.stopped for n in nodes.values()] == [1, 1]
    ours.close()


def test_the_watchdog_stops_the_nodes_and_arms_the_alarm_once_the_parent_changed() -> None:
    stop_all = host.StopFlag()
    previous = signal.signal(signal.SIGALRM, signal.SIG_IGN)
    try:
        assert not lifetime.stopping()
        host._watchdog(os.getppid() + 1_000_000, stop_all)  # not our parent: it is "gone"
        assert stop_all.is_set() and lifetime.stopping()
        assert signal.alarm(0) > 0  # armed (and disarmed here)
    finally:
        signal.signal(signal.SIGALRM, previous)


def test_a_sigterm_inside_the_sigterm_handler_does_not_hang_the_host() -> None:
    """The leak this guards against: a second SIGTERM arriving while the handler was setting a
    ``threading.Event`` deadlocked the host's main thread on the Event's lock (and the
    watchdog behind it), so no alarm was ever armed and the host outlived its runner."""
    flag, calls = host.StopFlag(), []

    def on_term(_signum: int, _frame: object) -> None:
        calls.append(1)
        if len(calls) == 1:
            os.kill(os.getpid(), signal.SIGTERM)  # delivered while this handler runs
        host._stop_soon(flag)

    previous = signal.signal(signal.SIGTERM, on_term)
    previous_alarm = signal.signal(signal.SIGALRM, signal.SIG_IGN)
    try:
        os.kill(os.getpid(), signal.SIGTERM)
        deadline = time.monotonic() + 5.0
        while len(calls) < 2 and time.monotonic() < deadline:
            time.sleep(0.01)
        assert len(calls) == 2 and flag.is_set() and lifetime.stopping()
        assert signal.alarm(0) > 0
    finally:
        signal.signal(signal.SIGTERM, previous)
        signal.signal(signal.SIGALRM, previous_alarm)
