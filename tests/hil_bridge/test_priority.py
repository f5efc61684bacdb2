"""CPU priority (hil_bridge.priority): lower for work that yields to the loop, raised for the
server's tick thread where the OS allows it, and its account where it does not."""

from __future__ import annotations

import os
import threading

import pytest

from hil_bridge.launch.monitor import BusMonitor
from hil_bridge.priority import can_raise, lower_priority, raise_priority
from hil_bridge.server.echo_pool import WORKER_NICE
from hil_bridge.server.sim_server import SimServer

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


def test_raising_priority_reports_what_the_thread_got() -> None:
    seen: list[tuple[str, int]] = []

    def body() -> None:
        got = raise_priority(-2)
        seen.append((got, _nice(threading.get_native_id())))

    main_before = _nice(threading.get_native_id())
    worker = threading.Thread(target=body)
    worker.start()
    worker.join()
    [(got, nice)] = seen
    if got.startswith(f"nice {main_before} (nice -2 not permitted:"):
        assert nice == main_before  # no CAP_SYS_NICE / RLIMIT_NICE here: unchanged, and why
    else:
        assert (got, nice) == (f"nice {min(-2, main_before)}", min(-2, main_before))
    assert _nice(threading.get_native_id()) == main_before


def test_a_refused_raise_is_named_not_raised(monkeypatch: pytest.MonkeyPatch) -> None:
    def refuse(which: int, who: int, prio: int) -> None:
        raise PermissionError(1, "Operation not permitted")

    monkeypatch.setattr(os, "setpriority", refuse)
    monkeypatch.setattr(os, "getpriority", lambda which, who: 0)
    assert raise_priority(-10) == "nice 0 (nice -10 not permitted: Operation not permitted)"
    with pytest.raises(ValueError, match="nice: expected <= 0"):
        raise_priority(3)


def test_can_raise_probes_on_a_thread_of_its_own(monkeypatch: pytest.MonkeyPatch) -> None:
    main_before = _nice(threading.get_native_id())
    assert can_raise(main_before)  # its own nice: always allowed
    assert _nice(threading.get_native_id()) == main_before  # the probe changed no other thread
    monkeypatch.setattr(os, "setpriority", lambda which, who, prio: (_ for _ in ()).throw(
        PermissionError(1, "Operation not permitted")))
    assert not can_raise(main_before - 1)


@pytest.mark.parametrize(("mode", "asked"), [("realtime", -3), ("realtime", 0), ("fast", -3)])
def test_echo_nodes_yield_unless_the_tick_thread_is_raised(mode: str, asked: int) -> None:
    scene = {"state_rate_hz": 50.0, "clock": {"mode": mode}}
    srv = SimServer("prio", bus=f"mem://prio_w_{mode}_{-asked}", scene=scene, tick_nice=asked)
    raised = mode == "realtime" and asked < 0 and can_raise(asked)
    assert srv._sonars.node_nice == (0 if raised else WORKER_NICE)


def _thread_nice(name: str) -> int | None:
    for t in threading.enumerate():
        if t.name == name and t.native_id is not None:
            return _nice(t.native_id)
    return None


@pytest.mark.parametrize(("mode", "asked"), [("realtime", -3), ("realtime", 0), ("fast", -3)])
def test_the_server_raises_its_tick_thread_in_realtime_only(mode: str, asked: int) -> None:
    scene = {"swarm": {"overrides": {"numAgents": 2}, "seed": 1}, "state_rate_hz": 50.0,
             "clock": {"mode": mode}}
    srv = SimServer("prio", bus=f"mem://prio_{mode}_{-asked}", scene=scene, tick_nice=asked)
    before = _nice(threading.get_native_id())
    srv.start()
    try:
        for _ in range(500):
            if srv.stats()["ticks"] > 2:
                break
            threading.Event().wait(0.01)
        got = srv.stats()["tick_priority"]
        nice = _thread_nice("prio-tick")
    finally:
        srv.stop()
    if mode == "fast" or asked == 0:
        assert (got, nice) == ("unchanged", before)
    elif "not permitted" in got:
        assert nice == before
    else:
        assert (got, nice) == (f"nice {min(asked, before)}", min(asked, before))


def test_tick_nice_is_checked_at_load() -> None:
    with pytest.raises(Exception, match="tick_nice: expected -20 <= nice <= 0, got 5"):
        SimServer("prio", bus="mem://prio_bad", scene={"state_rate_hz": 50.0}, tick_nice=5)
