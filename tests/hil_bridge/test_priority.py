"""Lower CPU priority for work that yields to the loop (hil_bridge.priority)."""

from __future__ import annotations

import os
import threading

import pytest

from hil_bridge.launch.monitor import BusMonitor
from hil_bridge.priority import lower_priority

pytestmark = pytest.mark.skipif(not hasattr(os, "setpriority"), reason="no per-thread nice")


def _nice(tid: int) -> int:
    return os.getpriority(os.PRIO_PROCESS, tid)


def test_a_thread_lowers_its_own_priority_and_no_other() -> None:
    seen: list[tuple[int, int]] = []

    def body() -> None:
        before = _nice(threading.get_native_id())
        lower_priority(3, thread_only=True)
        seen.append((before, _nice(threading.get_native_id())))

    main_before = _nice(threading.get_native_id())
    worker = threading.Thread(target=body)
    worker.start()
    worker.join()
    assert seen == [(main_before, min(main_before + 3, 19))]
    assert _nice(threading.get_native_id()) == main_before


def test_the_bus_monitor_yields_to_the_nodes() -> None:
    monitor = BusMonitor("monitor", bus="mem://priority_monitor")
    monitor.start()
    try:
        assert monitor._thread is not None and monitor._thread.native_id is not None
        tid = monitor._thread.native_id
        for _ in range(200):  # the thread sets it first thing
            if _nice(tid) > _nice(threading.get_native_id()):
                break
            threading.Event().wait(0.01)
        assert _nice(tid) == min(_nice(threading.get_native_id()) + BusMonitor.NICE, 19)
    finally:
        monitor.stop()
