"""CPU priority (Linux nice, which is per thread): work that must yield to the loop, and the
loop itself.

Echo workers and echo nodes (:mod:`hil_bridge.server.echo_pool`,
:mod:`hil_bridge.server.echo_nodes`, the whole process) and the launch's bus monitor
(:mod:`hil_bridge.launch.monitor`, its receive thread) call :func:`lower_priority`, so that when
the cores are short the server's tick loop and the nodes get them first. The server's tick
thread calls :func:`raise_priority` in ``realtime`` mode (``tick_nice``): a negative nice needs
``CAP_SYS_NICE`` or an ``RLIMIT_NICE`` that allows it (``ulimit -e``;
``/etc/security/limits.conf``: ``@realtime - nice -10``), as ros2_control's real-time thread
priority needs its limits; where it is not allowed, the thread keeps its nice and says why.
"""

from __future__ import annotations

import contextlib
import os
import threading

__all__ = ["can_raise", "lower_priority", "raise_priority"]


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


def can_raise(nice: int) -> bool:
    """Whether a thread of this process may set its nice to ``nice`` (probed on a thread of its
    own, which ends)."""
    got: list[str] = []
    probe = threading.Thread(target=lambda: got.append(raise_priority(nice)), name="nice-probe")
    probe.start()
    probe.join()
    return bool(got) and "not permitted" not in got[0] and not got[0].startswith("unchanged")


def raise_priority(nice: int) -> str:
    """Set the calling thread's nice to ``nice`` (<= 0; threads it starts later inherit it).
    Returns what the thread runs at, for a summary: ``"nice -10"``, or ``"nice 0 (nice -10 not
    permitted: ...)"`` where the OS refuses (no privilege, another OS)."""
    if nice > 0:
        raise ValueError(f"nice: expected <= 0 (a raise), got {nice}")
    tid = threading.get_native_id()
    try:
        current = os.getpriority(os.PRIO_PROCESS, tid)
    except (OSError, AttributeError) as exc:
        return f"unchanged ({exc})"
    if current <= nice:
        return f"nice {current}"
    try:
        os.setpriority(os.PRIO_PROCESS, tid, nice)
    except OSError as exc:
        return f"nice {current} (nice {nice} not permitted: {exc.strerror or exc})"
    return f"nice {nice}"
