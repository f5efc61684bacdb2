"""CPU priority for work that must yield to the loop (Linux nice, which is per thread).

Echo workers (:mod:`hil_bridge.server.echo_pool`, the whole process) and the launch's bus
monitor (:mod:`hil_bridge.launch.monitor`, its receive thread) call :func:`lower_priority`, so
that when the cores are short the server's tick loop and the nodes get them first.
"""

from __future__ import annotations

import contextlib
import os
import threading

__all__ = ["lower_priority"]


def lower_priority(nice: int, *, thread_only: bool = False) -> None:
    """Add ``nice`` to every thread of this process, or only to the calling thread (threads
    started later inherit it from the thread that starts them). Where it cannot be set
    (another OS, a sandbox), nothing changes."""
    if thread_only:
        tids = [threading.get_native_id()]
    else:
        try:
            tids = [int(t) for t in os.listdir("/proc/self/task")]
        except OSError:
            tids = [0]
    for tid in tids:
        with contextlib.suppress(OSError):
            os.setpriority(os.PRIO_PROCESS, tid, os.getpriority(os.PRIO_PROCESS, tid) + nice)
