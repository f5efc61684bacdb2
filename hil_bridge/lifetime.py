"""A process that ends with the one that spawned it (Linux ``PR_SET_PDEATHSIG``).

Node hosts (:mod:`hil_bridge.launch.host`, SIGTERM: they stop their nodes first), echo
workers (:mod:`hil_bridge.server.echo_pool`) and echo nodes (:mod:`hil_bridge.server.echo_nodes`)
(SIGKILL: they hold nothing to clean up) call :func:`die_with_parent` first thing, so none
outlives a parent killed with -9. :func:`reap` ends the children a parent asked to stop.
"""

from __future__ import annotations

import contextlib
import ctypes
import os
import signal
import time
from collections.abc import Iterable
from typing import Any

__all__ = ["die_with_parent", "reap"]

_PR_SET_PDEATHSIG = 1


def die_with_parent(parent_pid: int, sig: int = signal.SIGTERM) -> None:
    """Have the kernel send ``sig`` to this process when its parent dies (``prctl``; the parent
    is the *thread* that spawned it, so spawn from a thread that outlives the child); exit now
    if the parent is already gone."""
    with contextlib.suppress(OSError, AttributeError):
        ctypes.CDLL(None, use_errno=True).prctl(_PR_SET_PDEATHSIG, int(sig), 0, 0, 0)
    if os.getppid() != parent_pid:
        os._exit(1)


def reap(procs: Iterable[Any], timeout_s: float) -> None:
    """Wait for ``procs`` (``multiprocessing.Process``, already asked to stop) to exit, all
    within ``timeout_s`` s; terminate those still running then (SIGTERM, 5 s more), kill
    those that ignore it."""
    deadline = time.monotonic() + timeout_s
    for proc in procs:
        proc.join(timeout=max(0.0, deadline - time.monotonic()))
        if proc.is_alive():
            proc.terminate()
            proc.join(timeout=5.0)
        if proc.is_alive():  # pragma: no cover - ignored SIGTERM
            proc.kill()
            proc.join()
