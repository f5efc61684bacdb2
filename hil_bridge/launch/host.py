"""The node host: the process that runs a container's nodes (``python -m hil_bridge.launch.host``).

The launch runner (:class:`hil_bridge.launch.process.ContainerProcess`) spawns one host per
container: a fresh interpreter (``subprocess``, never a ``fork`` of a process holding threads
and sockets), with the runner's end of a socket pair as its control channel (file descriptor
``FD``, the only argument). Over it, as pickled tuples:

1. the runner sends ``("nodes", {"domain": str, "bus": str, "allow_modules": [...],
   "sync": bool, "realtime": int, "nodes": [{"name", "entry", "params"}, ...]})``; the host
   imports the nodes' modules and answers ``("prepared", None)`` (hosts of one launch import at
   the same time);
2. on ``("construct", None)`` the host activates the domain and constructs the nodes in order,
   answering ``("constructed", None)`` (a container of several nodes composes the bus first:
   they deliver to each other in-process, :mod:`hil_bridge.bus.intra`); on ``("start",
   None)`` it starts them in order, answering ``("ready", None)``. The runner constructs every
   container's nodes in the launch file's order before it starts any, as it does with threads,
   so no node runs (a server's clock ticking) while the next ones are still being built. A
   node that fails is answered with
   ``("error", "node: traceback text")``, after the host stopped those of its nodes it started.
   When the launch runs the bus's proxy (``sync``), before it answers "constructed" and again
   before it starts its nodes, the host syncs every bus endpoint of the process
   (:func:`~hil_bridge.bus.transport.sync_open`, up to ``SYNC_TIMEOUT_S``): a node starts only
   once its endpoint knows the subscriptions the proxy held (the recorder's, those of the nodes
   constructed earlier), so none of those misses the first messages it publishes. With a
   ``realtime`` priority (the launch file's, > 0) the bus's I/O thread and every thread the
   nodes start run under ``SCHED_FIFO`` at it (the nodes are built at normal priority); once
   they started, so do the host's own threads (this one, which answers, and its watchdog:
   :func:`~hil_bridge.priority.realtime_threads`), and each node's stats say so
   (``scheduling``);
3. then it answers requests until told to stop: ``("stats", name)`` -> ``("stats", dict)``,
   ``("failure", name)`` and ``("final_failure", name)`` (the end of the run) -> ``("failure",
   str | None)``, ``("finished", name)`` -> ``("finished", bool | None)``, ``("stop", name)``
   -> ``("stopped", (stats, failure))``; it exits once every
   node stopped, or stops them all and exits if the channel closes (the runner is gone).

A host outlives no runner: the kernel sends it SIGTERM when the runner dies, however it dies
(``PR_SET_PDEATHSIG``; a runner killed with -9 included). SIGTERM, like a closed channel, makes
the host stop its nodes (so they remove their pty links and shared-memory tile stores) and
exit; one that has not exited :data:`STOP_GRACE_S` seconds later is ended by SIGALRM. A node
still starting when told gives up what it waits for (its echo workers, say) and is stopped at
once (:func:`hil_bridge.lifetime.wait_unless_stopping`). The SIGTERM handler arms that alarm
first and then sets a :class:`~hil_bridge.lifetime.StopFlag` (and the process's, the same
kind), which takes no lock: SIGTERMs in quick succession (the parent's death and the runner's
own) once deadlocked a handler on its own ``threading.Event``. Neither rests on the main thread
alone: a watchdog thread notices a new parent (the runner gone) within :data:`WATCHDOG_S` and
arms the same stop and alarm, should the main thread never get to run the SIGTERM handler; a
reply the runner can no longer receive ends the host's service loop, and the nodes are stopped
and the host ends (``os._exit``) whatever raised. Ctrl-C reaches every process of the
terminal's group: the host ignores SIGINT, and the runner decides the order in which nodes
stop. Log records go to standard error as ``LEVEL logger: message``; the runner prefixes each
line with the node's name (or the container's).
"""

from __future__ import annotations

import contextlib
import logging
import os
import signal
import sys
import threading
import time
import traceback
from collections.abc import Iterable
from multiprocessing.connection import Connection
from typing import Any

from hil_bridge.bus.domain import resolve, use
from hil_bridge.bus.intra import compose
from hil_bridge.bus.transport import sync_open
from hil_bridge.launch.runner import SYNC_TIMEOUT_S, failure_of, finished_of
from hil_bridge.launch.spec import resolve_entry
from hil_bridge.lifetime import StopFlag, die_with_parent, freeze_heap, request_stop
from hil_bridge.priority import realtime, realtime_io, realtime_threads

__all__ = ["StopFlag", "main"]

log = logging.getLogger(__name__)

#: seconds a host has to stop its nodes after SIGTERM before SIGALRM ends it
STOP_GRACE_S = 20
#: how often the watchdog thread looks for the runner (seconds)
WATCHDOG_S = 0.5


def _stop_soon(stop_all: StopFlag) -> None:
    """Arm SIGALRM (its default action ends the process, whatever the main thread does), then
    ask the service loop to stop the nodes. Safe in a signal handler and in any thread."""
    signal.alarm(STOP_GRACE_S)
    stop_all.set()
    request_stop()  # a node's start waiting for something slow gives up (hil_bridge.lifetime)


def _watchdog(parent_pid: int, stop_all: StopFlag) -> None:
    """Thread body: once this process has another parent (its runner died), stop soon."""
    while os.getppid() == parent_pid:
        time.sleep(WATCHDOG_S)
    _stop_soon(stop_all)


def _prepare(nodes: list[dict[str, Any]], allow_modules: list[str]) -> list[type]:
    """Import every node's class (the slow part of starting: numpy, scipy, numba...)."""
    return [resolve_entry(node["entry"], where=f"{node['name']}.entry",
                          allow_modules=allow_modules) for node in nodes]


def _report(where: str) -> str:
    """Log the exception being handled with its traceback (the runner shows the host's last
    lines) and return one line naming ``where`` and the exception."""
    log.error("%s raised", where, exc_info=True)
    last = traceback.format_exc().rstrip().splitlines()[-1]
    return f"{where} raised {last}"


def _construct(nodes: list[dict[str, Any]], classes: list[type],
               bus: str) -> tuple[dict[str, Any], str | None]:
    """Construct ``nodes`` in order: the nodes, or the error text naming the node that failed."""
    made: dict[str, Any] = {}
    for node, cls in zip(nodes, classes, strict=True):
        try:
            made[node["name"]] = cls(node["name"], bus=bus, **node["params"])
        except BaseException:
            return made, _report(f"{node['name']}: constructor")
    return made, None


def _sync(bus: str | None) -> str | None:
    """Sync this process's endpoints on ``bus`` (None: the launch runs no proxy, nothing to
    sync with); the error text naming those that did not get in sync."""
    late = [] if bus is None else sync_open(SYNC_TIMEOUT_S, url=bus)
    if late:
        return (f"bus endpoint(s) {', '.join(sorted(set(late)))} not in sync with the proxy "
                f"after {SYNC_TIMEOUT_S:g} s")
    return None


def _start(made: dict[str, Any], sync: str | None) -> str | None:
    """Start the nodes in order (once in ``sync``, :func:`_sync`); on a failure stop them all
    (reverse) and name the one."""
    error = _sync(sync)
    if error is not None:
        _stop_nodes(made.values())
        return error
    for name, obj in made.items():
        try:
            obj.start()
        except BaseException:
            text = _report(f"{name}: start()")
            _stop_nodes(made.values())
            return text
    return None


def _start_realtime(priority: int) -> str:
    """Have the threads the nodes start run under ``SCHED_FIFO`` at ``priority`` (the launch
    file's ``realtime``), with the bus's I/O thread (:func:`hil_bridge.priority.realtime_io`,
    before construction); one line says what they got (where the OS refuses, the launcher has
    warned once for the run, and this host's stats say why)."""
    got = realtime(priority, inherit=True)
    if got.startswith("fifo"):
        log.info("realtime: the nodes' threads run SCHED_FIFO at priority %d", priority)
    else:
        log.debug("realtime %d: %s; the nodes run at normal priority (the launcher warned)",
                  priority, got)
    return got


def _stop_nodes(nodes: Iterable[Any]) -> None:
    """Stop ``nodes`` in reverse order; one that raises does not keep the others running."""
    for obj in reversed(list(nodes)):
        with contextlib.suppress(Exception):
            obj.stop()


def _send(conn: Connection, message: tuple[str, Any]) -> bool:
    """Send ``message`` to the runner; False when it is gone (the channel broke)."""
    try:
        conn.send(message)
    except OSError:
        return False
    return True


def _next(conn: Connection) -> tuple[str, Any] | None:
    """The runner's next request, or None when it is gone."""
    try:
        kind, detail = conn.recv()
    except (EOFError, OSError):
        return None
    return kind, detail


def _serve(conn: Connection, made: dict[str, Any], stop_all: StopFlag,
           first: tuple[str, Any] | None = None, scheduling: str | None = None) -> None:
    """Answer the runner's requests (``first``, then what comes) until every node stopped or
    the runner is gone (the channel closed, or a reply failed); nodes left are stopped in
    reverse order, whatever ends the loop."""
    running = dict(made)
    try:
        while running:
            if first is not None:
                (kind, name), first = first, None
            elif stop_all.is_set():
                break
            else:
                try:
                    if not conn.poll(0.2):
                        continue
                    kind, name = conn.recv()
                except (EOFError, OSError):
                    break
            if not _answer(conn, running, kind, name, scheduling):
                break
    finally:
        _stop_nodes(running.values())


def _answer(conn: Connection, running: dict[str, Any], kind: str, name: str,
            scheduling: str | None = None) -> bool:
    """Answer one request; False when the runner cannot receive the answer (it is gone). A
    node's stats carry its threads' ``scheduling`` when the launch asked for real time."""
    obj = running.get(name)
    if obj is None:
        reply: tuple[str, Any] = ("error", f"no running node {name!r} in this host")
    else:
        try:
            if kind == "stats":
                reply = ("stats", _with(obj.stats(), scheduling))
            elif kind in ("failure", "final_failure"):
                reply = ("failure", failure_of(obj, final=kind == "final_failure"))
            elif kind == "finished":
                reply = ("finished", finished_of(obj))
            elif kind == "stop":
                del running[name]
                obj.stop()
                reply = ("stopped", (_with(obj.stats(), scheduling), failure_of(obj)))
            else:
                reply = ("error", f"unknown request {kind!r}")
        except Exception as exc:  # the runner names the node and the call
            reply = ("error", f"{kind}() raised {type(exc).__name__}: {exc}")
    return _send(conn, reply)


def _with(stats: dict[str, Any], scheduling: str | None) -> dict[str, Any]:
    return stats if scheduling is None else {**stats, "scheduling": scheduling}


def main(argv: list[str] | None = None) -> int:
    args = sys.argv[1:] if argv is None else argv
    if len(args) != 2:
        sys.stderr.write("usage: python -m hil_bridge.launch.host FD PARENT_PID\n")
        return 2
    stop_all = StopFlag()

    def _on_term(_signum: int, _frame: object) -> None:
        _stop_soon(stop_all)

    signal.signal(signal.SIGTERM, _on_term)
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    die_with_parent(int(args[1]))
    threading.Thread(target=_watchdog, args=(int(args[1]), stop_all), name="host-watchdog",
                     daemon=True).start()
    logging.basicConfig(level=logging.INFO, stream=sys.stderr,
                        format="%(levelname)s %(name)s: %(message)s")
    conn = Connection(int(args[0]))
    try:
        kind, request = conn.recv()
    except (EOFError, OSError):
        return 1
    if kind != "nodes":
        return 2
    try:
        classes = _prepare(request["nodes"], request["allow_modules"])
    except Exception as exc:
        _send(conn, ("error", f"{type(exc).__name__}: {exc}"))
        return 1
    if not _send(conn, ("prepared", None)):
        return 1
    if _next(conn) != ("construct", None) or stop_all.is_set():
        return 1
    rt = int(request.get("realtime", 0))
    if rt:
        realtime_io(rt)  # before the first socket starts its I/O thread
    if len(request["nodes"]) > 1:  # a container's nodes deliver to each other in-process
        compose(request["bus"])
    with use(resolve(request["domain"])):
        made, error = _construct(request["nodes"], classes, request["bus"])
        sync = request["bus"] if request["sync"] else None
        if error is None:
            error = _sync(sync)
        if error is not None:
            _stop_nodes(made.values())
            _send(conn, ("error", error))
            return 1
        freeze_heap(collect=True)  # nothing of this launch runs yet
        if not _send(conn, ("constructed", None)):
            _stop_nodes(made.values())
            return 1
        request_ = _next(conn)
        if request_ != ("start", None):  # the launch stops before it started these nodes
            _serve(conn, made, stop_all, first=request_)
            return 0
        scheduling = _start_realtime(rt) if rt else None
        error = _start(made, sync)
        if scheduling is not None and scheduling.startswith("fifo"):
            realtime(rt)  # it stays real time, but what it starts from now on begins normal
            realtime_threads(rt)  # the watchdog too: no thread here takes the lock at normal
        if error is not None:
            _send(conn, ("error", error))
            return 1
        freeze_heap()
        _send(conn, ("ready", None))  # if the runner is gone, _serve finds it so and stops all
    _serve(conn, made, stop_all, scheduling=scheduling)
    conn.close()
    return 0


def _exit(code: int) -> None:
    """End the host once its nodes stopped, whatever threads they leaked: a non-daemon thread
    left running would keep the interpreter waiting for it at exit, beyond the reach of the
    launcher's death and of SIGALRM. The leak is logged, by thread name."""
    left = [t.name for t in threading.enumerate()
            if t is not threading.main_thread() and t.is_alive() and not t.daemon]
    if left:
        log.warning("threads still running after every node stopped: %s", ", ".join(left))
    logging.shutdown()
    sys.stdout.flush()
    sys.stderr.flush()
    os._exit(code)


def _run() -> None:
    """``main``, then :func:`_exit` whatever happened (exit status 1, and the traceback in
    the log, when ``main`` raised)."""
    code = 1
    try:
        code = main()
    except BaseException:
        log.critical("the host failed", exc_info=True)
    finally:
        _exit(code)


if __name__ == "__main__":
    _run()
