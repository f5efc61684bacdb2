"""Helpers of the CAN tests: unique virtual channels and waiting on conditions."""

from __future__ import annotations

import threading
import time
import uuid
from collections.abc import Callable


def unique(prefix: str) -> str:
    """A virtual-bus channel / mem:// bus name no other test uses."""
    return f"{prefix}{uuid.uuid4().hex[:10]}"


def wait_until(predicate: Callable[[], bool], timeout: float = 5.0, poll: float = 0.005) -> bool:
    """True as soon as ``predicate()`` holds; False if it still fails after ``timeout`` s."""
    deadline = time.monotonic() + timeout
    idle = threading.Event()
    while not predicate():
        if time.monotonic() >= deadline:
            return False
        idle.wait(poll)
    return True
