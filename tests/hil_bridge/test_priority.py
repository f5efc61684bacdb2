"""CPU priority (hil_bridge.priority): lower for work that yields to the loop, raised for the
server's tick thread where the OS allows it, real time (SCHED_FIFO) for the threads of a
real-time node, and its account where the OS does not allow it."""

from __future__ import annotations

import os
import subprocess
import sys
import threading
from collections.abc import Callable
from typing import Any

import pytest
import zmq

from hil_bridge.launch.monitor import BusMonitor
from hil_bridge.launch.spec import load
from hil_bridge.priority import (
    RunThreads,
    can_raise,
    can_realtime,
    leave_realtime,
    loop_priority,
    lower_priority,
    normal_children,
    raise_priority,
    realtime,
    realtime_io,
    realtime_priority,
    realtime_threads,
)
from hil_bridge.server.echo_pool import WORKER_NICE
from hil_bridge.server.sim_server import SimServer
from sim_core.config import ConfigError

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
    own = min(main_before, 0)  # a niced run (`nice make test`) starts above 0, where no raise
    if own == main_before:     # is always allowed
        assert can_raise(own)  # its own nice: always allowed
    assert _nice(threading.get_native_id()) == main_before  # the probe changed no other thread
    monkeypatch.setattr(os, "setpriority", lambda which, who, prio: (_ for _ in ()).throw(
        PermissionError(1, "Operation not permitted")))
    assert not can_raise(own - 1)


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


def _ticked(srv: SimServer) -> None:
    """Wait (at most 5 s) for the server's tick thread to run a few ticks."""
    for _ in range(500):
        if srv.stats()["ticks"] > 2:
            return
        threading.Event().wait(0.01)


@pytest.mark.parametrize(("mode", "asked"), [("realtime", -3), ("realtime", 0), ("fast", -3)])
def test_the_server_raises_its_tick_thread_in_realtime_only(mode: str, asked: int) -> None:
    scene = {"swarm": {"overrides": {"numAgents": 2}, "seed": 1}, "state_rate_hz": 50.0,
             "clock": {"mode": mode}}
    srv = SimServer("prio", bus=f"mem://prio_{mode}_{-asked}", scene=scene, tick_nice=asked)
    before = _nice(threading.get_native_id())
    srv.start()
    try:
        _ticked(srv)
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


def _in_thread(body: Callable[[], Any]) -> Any:
    """``body()`` run on a thread of its own (what it sets ends with the thread)."""
    got: list[Any] = []
    worker = threading.Thread(target=lambda: got.append(body()))
    worker.start()
    worker.join()
    return got[0]


def _child_priority() -> int:
    code = "import os; print(os.sched_getparam(0).sched_priority)"
    return int(subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                              check=True).stdout)


RT = can_realtime(3)
needs_rt = pytest.mark.skipif(not RT, reason="SCHED_FIFO not permitted here (the refusal is "
                                             "tested with a refusing OS below)")


@needs_rt
def test_a_realtime_thread_starts_normal_threads_and_processes_unless_it_inherits() -> None:
    def body(inherit: bool) -> tuple[str, int, int, int]:
        got = realtime(3, inherit=inherit)
        return got, realtime_priority(), _in_thread(realtime_priority), _child_priority()

    assert _in_thread(lambda: body(False)) == ("fifo 3", 3, 0, 0)
    assert _in_thread(lambda: body(True)) == ("fifo 3", 3, 3, 3)
    assert realtime_priority() == 0  # the caller's thread never changed


@needs_rt
def test_normal_children_start_normal_and_the_thread_keeps_its_priority() -> None:
    def body() -> tuple[int, int, int, int]:
        realtime(4, inherit=True)
        with normal_children():
            inside = _child_priority(), _in_thread(realtime_priority)
        return (*inside, realtime_priority(), _child_priority())

    # a thread started in the block starts normal too (reset on fork covers threads)
    assert _in_thread(body) == (0, 0, 4, 4)
    with normal_children():  # a normal thread: nothing to do
        assert _child_priority() == 0


@needs_rt
def test_leaving_and_lowering_return_a_thread_to_normal_scheduling() -> None:
    def leave() -> tuple[int, int]:
        realtime(3)
        before = realtime_priority()
        leave_realtime()
        return before, realtime_priority()

    def lower() -> tuple[int, int]:
        realtime(3)
        nice = _nice(threading.get_native_id())
        lower_priority(2, thread_only=True)
        return realtime_priority(), _nice(threading.get_native_id()) - nice

    assert _in_thread(leave) == (3, 0)
    assert _in_thread(lower) == (0, 2)


class _Parked:
    """A thread waiting until the block ends, at real-time priority ``rt`` (0: normal)."""

    def __init__(self, rt: int = 0) -> None:
        self._stop, ready = threading.Event(), threading.Event()

        def body() -> None:
            if rt:
                realtime(rt)
            ready.set()
            self._stop.wait()

        self.thread = threading.Thread(target=body, daemon=True)
        self.thread.start()
        ready.wait()

    def priority(self) -> int:
        return realtime_priority(self.thread.native_id or 0)

    def __enter__(self) -> _Parked:
        return self

    def __exit__(self, *_exc: object) -> None:
        self._stop.set()
        self.thread.join()


@needs_rt
def test_realtime_threads_raises_the_threads_below_it_and_no_other() -> None:
    with _Parked() as low, _Parked(2) as lower, _Parked(6) as higher, _Parked() as other:
        assert realtime_threads(4, [low.thread, lower.thread, higher.thread]) == 2
        assert [p.priority() for p in (low, lower, higher, other)] == [4, 4, 6, 0]
        # what a raised thread starts begins normal (SCHED_RESET_ON_FORK)
        assert os.sched_getscheduler(low.thread.native_id or 0) & os.SCHED_RESET_ON_FORK
    assert realtime_priority() == 0


def test_realtime_threads_stops_where_the_os_refuses(monkeypatch: pytest.MonkeyPatch) -> None:
    def refuse(*_args: object) -> None:
        raise PermissionError(1, "Operation not permitted")

    monkeypatch.setattr(os, "sched_setscheduler", refuse)
    with _Parked() as low:
        assert realtime_threads(4, [low.thread]) == 0
        assert low.priority() == 0


@needs_rt
def test_a_run_raises_its_own_threads_and_gives_its_caller_back() -> None:
    def body() -> tuple[int, int, int, int, int]:
        with _Parked() as before:
            own = RunThreads()
            with _Parked() as during:
                own.raise_to(3)
                raised = realtime_priority(), during.priority(), before.priority()
                own.restore()
                return (*raised, realtime_priority(), during.priority())

    assert _in_thread(body) == (3, 3, 0, 0, 3)

    def already_realtime() -> int:
        realtime(5)
        own = RunThreads()
        own.raise_to(3)
        own.restore()  # it did not raise this thread: it leaves it as it was
        return realtime_priority()

    assert _in_thread(already_realtime) == 5


@needs_rt
@pytest.mark.parametrize(("paced", "want"), [(True, ("fifo 6", 6)),
                                             (False, ("normal (unpaced)", 0))])
def test_a_realtime_loop_goes_above_its_process_when_paced_and_leaves_when_not(
    paced: bool, want: tuple[str, int],
) -> None:
    def body() -> tuple[str, int]:
        realtime(5)
        return loop_priority(paced=paced, nice=-3), realtime_priority()

    assert _in_thread(body) == want


def test_a_normal_loop_asks_for_its_nice_when_paced() -> None:
    assert _in_thread(lambda: loop_priority(paced=False, nice=-3)) == "unchanged"
    assert _in_thread(lambda: loop_priority(paced=True, nice=0)) == "unchanged"
    got = _in_thread(lambda: loop_priority(paced=True, nice=-1))
    assert got.startswith("nice -1") or "not permitted" in got


def test_a_refused_realtime_is_named_and_leaves_zeromq_alone(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    def refuse(*_args: object) -> None:
        raise PermissionError(1, "Operation not permitted")

    class Ctx:
        def __init__(self) -> None:
            self.options: dict[int, int] = {}

        def set(self, option: int, value: int) -> None:
            self.options[option] = value

    monkeypatch.setattr(os, "sched_setscheduler", refuse)
    assert realtime(5) == "normal (fifo 5 not permitted: Operation not permitted)"
    assert not can_realtime(5)
    ctx = Ctx()
    assert realtime_io(5, ctx) == "normal (fifo 5 not permitted)"
    assert ctx.options == {}  # libzmq would abort the process on the refusal
    monkeypatch.undo()
    if RT:
        assert realtime_io(5, ctx) == "fifo 5"
        assert ctx.options == {zmq.THREAD_SCHED_POLICY: os.SCHED_FIFO, zmq.THREAD_PRIORITY: 5}


@pytest.mark.parametrize("bad", [0, 99, -1])
def test_a_realtime_priority_is_checked(bad: int) -> None:
    with pytest.raises(ValueError, match=rf"realtime: expected a priority 1..98, got {bad}"):
        realtime(bad)


@pytest.mark.parametrize("bad", [99, -1, True])
def test_a_launch_node_realtime_is_checked_at_load(bad: object) -> None:
    node = {"name": "n", "entry": "tests.hil_bridge.launch.heapnodes:HeapReporter",
            "realtime": bad}
    with pytest.raises(ConfigError,
                       match=r"realtime: expected (a SCHED_FIFO priority 1..98 |an integer)"):
        load({"nodes": [node]}, allow_modules=["tests.hil_bridge.launch"])


@needs_rt
@pytest.mark.parametrize(("mode", "want"), [("realtime", ("fifo 6", 6)),
                                            ("fast", ("normal (unpaced)", 0))])
def test_a_realtime_server_runs_its_tick_thread_above_its_own(
    mode: str, want: tuple[str, int],
) -> None:
    scene = {"swarm": {"overrides": {"numAgents": 2}, "seed": 1}, "state_rate_hz": 50.0,
             "clock": {"mode": mode}}
    srv = SimServer("rtprio", bus=f"mem://rtprio_{mode}", scene=scene)

    def start() -> None:  # as a real-time node host starts its nodes
        realtime(5, inherit=True)
        srv.start()

    _in_thread(start)
    try:
        _ticked(srv)
        got = srv.stats()["tick_priority"]
        tid = next(t.native_id for t in threading.enumerate() if t.name == "rtprio-tick")
        assert tid is not None
        assert (got, realtime_priority(tid)) == want
    finally:
        srv.stop()
