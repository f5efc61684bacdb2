"""hil_bridge.lifetime: freeze_heap freezes without walking what it froze; a wait of a
process asked to stop gives up."""

from __future__ import annotations

import gc

import pytest

from hil_bridge import lifetime
from hil_bridge.lifetime import freeze_heap, request_stop, wait_unless_stopping


def test_freeze_heap_freezes_without_counting(monkeypatch: pytest.MonkeyPatch) -> None:
    """``gc.get_freeze_count`` walks the whole permanent generation with the interpreter lock
    held (milliseconds in a node's process, whose threads all wait): a host calls freeze_heap
    while its nodes run, so it must not count."""
    def walk() -> int:
        raise AssertionError("freeze_heap walked the permanent generation")

    kept = [[i] for i in range(1000)]  # tracked containers, for the freeze to move
    before = gc.get_freeze_count()
    try:
        with monkeypatch.context() as m:
            m.setattr(gc, "get_freeze_count", walk)
            freeze_heap()
        assert gc.get_freeze_count() >= before + len(kept)
    finally:
        gc.unfreeze()


def test_a_wait_gives_up_once_the_process_is_asked_to_stop(monkeypatch: pytest.MonkeyPatch
                                                          ) -> None:
    """What a node's start waits for (a server's echo workers) is waited for in slices of at
    most STOP_POLL_S; the process asked to stop (its launcher died), the wait ends there, and
    its host stops the node within its grace."""
    monkeypatch.setattr(lifetime, "_STOPPING", lifetime.StopFlag())
    slices: list[float] = []

    def third_time(s: float) -> bool:
        slices.append(s)
        return len(slices) == 3

    assert wait_unless_stopping(third_time, 60.0)
    assert len(slices) == 3 and max(slices) <= lifetime.STOP_POLL_S
    slices.clear()

    def stopped_meanwhile(s: float) -> bool:
        slices.append(s)
        if len(slices) == 2:
            request_stop()  # the host's SIGTERM handler, between two slices
        return False

    assert not wait_unless_stopping(stopped_meanwhile, 60.0)
    assert len(slices) == 2
    assert not wait_unless_stopping(third_time, 60.0)  # asked to stop: no wait at all
    assert len(slices) == 2
