"""The shared failure record (hil_bridge.bus.faults): what makes a node's failure() say why."""

from __future__ import annotations

import logging
import threading

import pytest

from hil_bridge.bus.faults import Faults


def test_no_fault_is_no_failure() -> None:
    faults = Faults("n")
    assert faults.failure() is None
    assert faults.failure(final=True) is None
    assert faults.counts() == {}


def test_an_unrecoverable_fault_names_the_place_and_the_exception() -> None:
    faults = Faults("adapter")
    faults.report("rx loop", OSError(5, "I/O error"))
    assert faults.failure() == "rx loop: OSError: [Errno 5] I/O error"
    faults.report("callback /x", ValueError("bad"))
    assert faults.failure() == "rx loop: OSError: [Errno 5] I/O error (and 1 more)"
    assert faults.counts() == {"rx loop": 1, "callback /x": 1}


def test_a_recoverable_fault_fails_only_if_never_recovered() -> None:
    faults = Faults("head")
    faults.report("link", "port vanished", recoverable=True)
    assert faults.failure() is None  # still allowed to recover during the run
    assert faults.failure(final=True) == (
        "link: port vanished (declared recoverable, never recovered)")
    faults.recovered("link")
    assert faults.failure(final=True) is None
    assert faults.counts() == {"link": 1}


def test_each_place_is_logged_once_and_counted_always(caplog: pytest.LogCaptureFixture) -> None:
    faults = Faults("server")
    with caplog.at_level(logging.ERROR, logger="hil_bridge.bus.faults"):
        for _ in range(5):
            faults.report("tick", RuntimeError("boom"))
    assert len([r for r in caplog.records if "tick" in r.getMessage()]) == 1
    assert faults.counts() == {"tick": 5}
    assert len(faults.fatal()) == 5


def test_reports_from_many_threads_are_all_counted() -> None:
    faults = Faults("pool")

    def work() -> None:
        for _ in range(1000):
            faults.report("worker", "died", recoverable=True)

    threads = [threading.Thread(target=work) for _ in range(4)]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    assert faults.counts() == {"worker": 4000}
    assert len(faults.pending()) == 1


def test_a_guarded_thread_body_reports_what_escapes_it() -> None:
    faults = Faults("mock")

    def body() -> None:
        raise OSError("device gone")

    thread = threading.Thread(target=faults.guarded("rx loop", body))
    thread.start()
    thread.join()
    assert faults.failure() == "rx loop: OSError: device gone"
    faults.guarded("tx loop", lambda: None)()  # a body that returns reports nothing
    assert faults.counts() == {"rx loop": 1}
