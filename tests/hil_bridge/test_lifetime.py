"""hil_bridge.lifetime.freeze_heap: it freezes without walking what it froze."""

from __future__ import annotations

import gc

import pytest

from hil_bridge.lifetime import freeze_heap


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
