"""CPU priority (Linux nice and real-time scheduling, both per thread): work that must yield to
the loop, and the loop itself.

Echo workers and echo nodes (:mod:`hil_bridge.server.echo_pool`,
:mod:`hil_bridge.server.echo_nodes`, the whole process) and the launch's bus monitor
(:mod:`hil_bridge.launch.monitor`, its receive thread) call :func:`lower_priority`, so that when
the cores are short the server's tick loop and the nodes get them first. The server's tick
thread calls :func:`raise_priority` in ``realtime`` mode (``tick_nice``): a negative nice needs
``CAP_SYS_NICE`` or an ``RLIMIT_NICE`` that allows it (``ulimit -e``;
``/etc/security/limits.conf``: ``@realtime - nice -10``), as ros2_control's real-time thread
priority needs its limits; where it is not allowed, the thread keeps its nice and says why.

**Real time.** A nice only weighs a thread's share of the cores: a woken thread still waits for
the running one's time slice, a few milliseconds on a loaded machine, at every hop of a message
(publisher, its ZeroMQ I/O thread, the proxy, the subscriber's I/O thread, the subscriber).
``SCHED_FIFO`` (:func:`realtime`, priority 1..98) runs a woken thread at once, ahead of every
normal thread: what a launch node's ``realtime`` key asks for (docs/launch.md, *Real time*), as
ros2_control's ``thread_priority`` does. It needs ``CAP_SYS_NICE`` or an ``RLIMIT_RTPRIO`` that
allows it (``ulimit -r``; limits.conf: ``@realtime - rtprio 98``); where it is not allowed the
thread runs on at its normal priority and says why. A real-time node process runs every thread
real time: they share its interpreter lock, and a normal thread holding it would hold the
real-time ones behind every other process of the machine. Work that would hold a core for long
(echo workers and echo nodes) runs in processes of its own, started at normal priority
(:func:`normal_children`); a loop that never sleeps leaves real time (:func:`loop_priority`).
"""

from __future__ import annotations

import contextlib
import os
import threading
from collections.abc import Iterable, Iterator
from typing import Any

__all__ = ["RunThreads", "can_raise", "can_realtime", "leave_realtime", "loop_priority",
           "lower_priority", "normal_children", "raise_priority", "realtime", "realtime_io",
           "realtime_priority", "realtime_threads"]

#: the highest priority :func:`realtime` takes (99 is left to the kernel's own threads)
MAX_REALTIME = 98


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
            _to_normal(tid)
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


def loop_priority(*, paced: bool, nice: int) -> str:
    """Set the priority of the calling loop thread (the server's tick thread) and return it for
    a summary. A thread that runs real time (its node host's ``realtime``) goes one above it, so
    above the node's other threads, when the loop is ``paced`` (it sleeps between its
    iterations), and leaves real time when not (unpaced, it would hold a core from every normal
    thread); a normal paced thread asks for ``nice`` (< 0; :func:`raise_priority`)."""
    rt = realtime_priority()
    if rt and not paced:
        leave_realtime()
        return "normal (unpaced)"
    if rt:
        return realtime(min(rt + 1, MAX_REALTIME))
    if paced and nice < 0:
        return raise_priority(nice)
    return "unchanged"


def _check_realtime(priority: int) -> None:
    if not 1 <= priority <= MAX_REALTIME:
        raise ValueError(f"realtime: expected a priority 1..{MAX_REALTIME}, got {priority}")


def realtime_priority(tid: int = 0) -> int:
    """The ``SCHED_FIFO``/``SCHED_RR`` priority thread ``tid`` runs at (0: the calling thread);
    0 when it runs a normal policy (or the OS cannot say)."""
    try:
        policy = os.sched_getscheduler(tid) & ~getattr(os, "SCHED_RESET_ON_FORK", 0)
        if policy not in (os.SCHED_FIFO, os.SCHED_RR):
            return 0
        return int(os.sched_getparam(tid).sched_priority)
    except (OSError, AttributeError):
        return 0


def realtime(priority: int, *, inherit: bool = False) -> str:
    """Run the calling thread under ``SCHED_FIFO`` at ``priority`` (1..98). With ``inherit``,
    threads it starts later run so too (a node host, before starting its nodes); without, they
    and every process it starts begin at normal priority (``SCHED_RESET_ON_FORK``). Returns
    what the thread runs at, for a summary: ``"fifo 30"``, or ``"normal (fifo 30 not
    permitted: ...)"`` where the OS refuses (no privilege, another OS)."""
    _check_realtime(priority)
    flags = 0 if inherit else getattr(os, "SCHED_RESET_ON_FORK", 0)
    try:
        os.sched_setscheduler(0, os.SCHED_FIFO | flags, os.sched_param(priority))
    except (OSError, AttributeError) as exc:
        why = exc.strerror if isinstance(exc, OSError) and exc.strerror else exc
        return f"normal (fifo {priority} not permitted: {why})"
    return f"fifo {priority}"


def realtime_threads(priority: int, threads: Iterable[threading.Thread] | None = None) -> int:
    """Run ``threads`` (default: every Python thread of this process) that are below
    ``priority`` under ``SCHED_FIFO`` at ``priority``, with ``SCHED_RESET_ON_FORK`` (what they
    start later begins at normal priority); threads at or above it keep theirs. A process whose
    nodes run real time calls it once they started: a thread of its own left at normal priority
    (a node host's answering thread and watchdog, a launcher's log pumps) takes the interpreter
    lock now and then, and when another process preempts it while it holds the lock, the
    real-time threads wait behind that process. Returns how many threads it raised; none where
    the OS refuses."""
    _check_realtime(priority)
    policy = os.SCHED_FIFO | getattr(os, "SCHED_RESET_ON_FORK", 0)
    raised = 0
    for thread in threading.enumerate() if threads is None else threads:
        tid = thread.native_id
        if tid is None or not thread.is_alive() or realtime_priority(tid) >= priority:
            continue
        try:
            os.sched_setscheduler(tid, policy, os.sched_param(priority))
        except ProcessLookupError:  # it ended meanwhile
            continue
        except (OSError, AttributeError):
            break
        raised += 1
    return raised


class RunThreads:
    """The threads a run starts from its construction on, and the calling thread (a launcher's
    main thread, whose process may hold other callers' threads: a test's): :meth:`raise_to`
    runs them real time (:func:`realtime_threads`), :meth:`restore` returns the calling thread
    to normal scheduling if :meth:`raise_to` took it out of it (the others end with the run)."""

    def __init__(self) -> None:
        self._before = set(threading.enumerate()) - {threading.current_thread()}
        self._raised = False

    def raise_to(self, priority: int) -> None:
        was = realtime_priority()
        realtime_threads(priority, [t for t in threading.enumerate() if t not in self._before])
        self._raised = self._raised or (not was and realtime_priority() > 0)

    def restore(self) -> None:
        if self._raised:
            leave_realtime()
            self._raised = False


def can_realtime(priority: int) -> bool:
    """Whether a thread of this process may run under ``SCHED_FIFO`` at ``priority`` (probed on
    a thread of its own, which ends)."""
    _check_realtime(priority)
    got: list[str] = []
    probe = threading.Thread(target=lambda: got.append(realtime(priority)), name="rt-probe")
    probe.start()
    probe.join()
    return bool(got) and got[0].startswith("fifo")


def _to_normal(tid: int) -> None:
    if realtime_priority(tid):
        os.sched_setscheduler(tid, os.SCHED_OTHER, os.sched_param(0))


def leave_realtime() -> None:
    """Return the calling thread to normal scheduling (``SCHED_OTHER``, its nice unchanged) if it
    runs a real-time policy (a node host's own thread once its nodes started)."""
    with contextlib.suppress(OSError, AttributeError):
        _to_normal(0)


@contextlib.contextmanager
def normal_children() -> Iterator[None]:
    """Processes the calling thread starts in this block begin at normal priority, even when
    the thread runs real time (``SCHED_RESET_ON_FORK`` for the block)."""
    prio = realtime_priority()
    if not prio:
        yield
        return
    policy = os.sched_getscheduler(0)  # the reset flag included, as it was
    os.sched_setscheduler(0, policy | os.SCHED_RESET_ON_FORK, os.sched_param(prio))
    try:
        yield
    finally:
        os.sched_setscheduler(0, policy, os.sched_param(prio))


def realtime_io(priority: int, ctx: Any = None) -> str:
    """Have the I/O threads of ZeroMQ context ``ctx`` (default: the process's shared one, which
    the bus's endpoints use), not yet holding a socket (libzmq starts them with the first), run
    under ``SCHED_FIFO`` at ``priority``, when this process may (probed first: libzmq aborts the
    process on a refusal). Returns what they will run at."""
    import zmq

    _check_realtime(priority)
    if ctx is None:
        ctx = zmq.Context.instance()
    if not can_realtime(priority):
        return f"normal (fifo {priority} not permitted)"
    ctx.set(zmq.THREAD_SCHED_POLICY, os.SCHED_FIFO)
    ctx.set(zmq.THREAD_PRIORITY, priority)
    return f"fifo {priority}"
