"""Helpers shared by the bus tests."""

from __future__ import annotations

import threading
import time
from collections.abc import Callable

WAIT = 10.0


def poll_until(pred: Callable[[], bool], timeout: float = WAIT) -> bool:
    """Poll a real condition every few ms until it holds or ``timeout`` s pass."""
    deadline = time.monotonic() + timeout
    tick = threading.Event()
    while not pred():
        if time.monotonic() > deadline:
            return False
        tick.wait(0.005)
    return True
