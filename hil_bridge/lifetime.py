"""A node process's life: it ends with the one that spawned it (Linux ``PR_SET_PDEATHSIG``), and
its heap, once built, stays out of the garbage collector's way.

Node hosts (:mod:`hil_bridge.launch.host`, SIGTERM: they stop their nodes first), echo
workers (:mod:`hil_bridge.server.echo_pool`) and echo nodes (:mod:`hil_bridge.server.echo_nodes`)
(SIGKILL: they hold nothing to clean up) call :func:`die_with_parent` first thing, so none
outlives a parent killed with -9. :func:`reap` ends the children a parent asked to stop.

**Asked to stop while starting.** A node host told to stop (SIGTERM, its runner gone) has
``hil_bridge.launch.host.STOP_GRACE_S`` to stop its nodes before SIGALRM ends it, and a node
still in its ``start()`` stops only once that returns. A start that waits for something slow
(a server waiting up to a minute for its echo workers to load their scene and build the first
tiles) waits through :func:`wait_unless_stopping`, which gives up once the process was asked
to stop (:func:`request_stop`, which the host's SIGTERM handler and watchdog call): the start
returns, the node is stopped and removes what it made. Before, a host whose launcher was
killed with -9 while its server waited took up to 17.6 s of its 20 s to go (the kill stress,
``python -m bench killstress``), and one still waiting when they ran out (a busier machine,
a bigger forest) was ended by SIGALRM with the server's tile store left in ``/dev/shm``.

**The heap.** CPython's cyclic garbage collector holds the interpreter lock while it runs, and
a full (generation 2) collection walks every tracked object: in a node process, the tens of
thousands of objects of the imported modules, the scene and the node itself, tens of
milliseconds on this project's 2-core machine (``python -m bench processes``, *Nodes as
processes*), during which none of the process's threads runs: a 250 Hz tick loop misses ticks,
a CAN adapter's frames wait. Such a collection comes every so often as surviving objects
accumulate. The same processes call :func:`freeze_heap` once their nodes are built
(``collect``: nothing runs yet) and again once they started: what exists then moves to the
collector's permanent generation (``gc.freeze``), so later collections walk only what the run
itself allocates and keeps.
"""

from __future__ import annotations

import contextlib
import ctypes
import gc
import os
import signal
import time
from collections.abc import Callable, Iterable
from typing import Any

__all__ = ["StopFlag", "die_with_parent", "freeze_heap", "reap", "request_stop", "stopping",
           "wait_unless_stopping"]

_PR_SET_PDEATHSIG = 1
#: how often :func:`wait_unless_stopping` looks at the process's stop flag (seconds)
STOP_POLL_S = 0.1


class StopFlag:
    """Set once, read by loops: a plain attribute, no lock, so a signal handler can set it even
    when the signal interrupts code that holds a lock, itself included
    (``threading.Event.set`` takes a lock: a second SIGTERM arriving inside a handler's
    ``set`` deadlocked a host's main thread, and with it the watchdog waiting for that lock)."""

    __slots__ = ("value",)

    def __init__(self) -> None:
        self.value = False

    def set(self) -> None:
        self.value = True

    def is_set(self) -> bool:
        return self.value


_STOPPING = StopFlag()


def request_stop() -> None:
    """Note that this process was asked to stop (safe in a signal handler)."""
    _STOPPING.set()


def stopping() -> bool:
    """Whether this process was asked to stop (:func:`request_stop`)."""
    return _STOPPING.is_set()


def wait_unless_stopping(ready: Callable[[float], bool], timeout_s: float) -> bool:
    """Wait for ``ready(seconds)`` (a wait of at most that long, True once what it waits for
    happened), called in slices of :data:`STOP_POLL_S`: True when it happened; False after
    ``timeout_s`` or as soon as this process was asked to stop."""
    deadline = time.monotonic() + timeout_s
    while not stopping():
        left = deadline - time.monotonic()
        if left <= 0:
            return False
        if ready(min(left, STOP_POLL_S)):
            return True
    return False


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


def freeze_heap(*, collect: bool = False) -> None:
    """Move every object the collector tracks to its permanent generation (``gc.freeze``, which
    splices the collector's lists: no walk), after a full collection if ``collect`` (only where
    no loop runs yet: it holds the interpreter lock for as long as it walks the heap). It does
    not count what it froze: ``gc.get_freeze_count()`` walks the whole permanent generation
    with the lock held (10 ms for 300,000 objects here), and the hosts call this once their
    nodes run; a 250 Hz server's first ticks waited behind that count."""
    if collect:
        gc.collect()
    gc.freeze()
