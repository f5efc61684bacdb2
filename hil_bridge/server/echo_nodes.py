"""Echo nodes: the sonars' pings answered by processes of their own, on the bus
(``echo_worker: nodes``).

The server (:class:`hil_bridge.server.sonars.ServerSonars`) starts :class:`EchoNodes`: ``n``
spawned processes, each a bus participant named ``<server>_echo<k>`` that serves a share of
the scene's sonars (the k-th, (k+n)-th, ... in id order). A node

- subscribes to its sonars' ``/sonar/<id>/ping``, and keeps the pose history the server's
  fleet keeps (:class:`hil_bridge.server.pose_history.PoseHistory`), copied from the server's
  ring in shared memory (:mod:`hil_bridge.server.pose_ring`): the same float64 values, so a
  ping's pose at emission is the one the server would find. The ring is read when a ping
  arrives, every half tick while a ping waits for its tick, and otherwise only every
  :data:`RING_POLL_S` (a quarter of the ring at most), so that it never wraps unread: a node
  between pings does not wake for every tick;
- answers each ping as the server's own echo thread does (it runs a
  :class:`~hil_bridge.server.sonars.ServerSonars` of its sonars with a thread worker:
  emission poses, deadlines, degradation, the tiles ahead of its sonars) and publishes
  ``/sonar/<id>/echo`` itself, stamped with the newest tick it has seen;
- node 0 also publishes the latched ``/forest/points``.

The server's process then never decodes a ping or encodes an echo: its interpreter is left to
the tick loop. The nodes run at a lower CPU priority (nice
:data:`~hil_bridge.server.echo_pool.WORKER_NICE`), so when the cores are short the tick loop
comes first, or at nice 0 when the server's tick thread holds a raised priority of its own
(``tick_nice``). Each builds the tiles its sonars reach (no tiles are shared between nodes: each
node's sonars fly their own part of the forest).

**Counters.** Every :data:`STATS_PERIOD_S` (and when it stops) a node sends its counters and
raw latency lists over its pipe; :meth:`EchoNodes.stats` merges the newest of each node
(counters summed, lists joined), so the server's summary and ``/diagnostics`` read as with
any other worker.

**Lifetime.** :meth:`EchoNodes.wait_ready` waits until every node is on the bus with its first
tiles built (the server ticks after it). :meth:`EchoNodes.close` asks each node to stop
(terminating one that has not within :data:`STOP_TIMEOUT_S`). A node exits on its own when
its pipe closes, and the kernel kills it with the server's process (``PR_SET_PDEATHSIG``). A
node that dies is reported to the server's :class:`~hil_bridge.bus.faults.Faults` (the run
fails naming it) and not replaced: its sonars are unanswered from then on.

Lockstep needs the server to see every ping and echo (:class:`~hil_bridge.server.lockstep.
LockstepGate`), and the nodes need a bus other processes reach: ``nodes`` is refused for a
lockstep clock or an in-process (``mem://``) bus. The pose ring is shared memory: the nodes
run on the server's host.
"""

from __future__ import annotations

import contextlib
import dataclasses
import logging
import multiprocessing
import os
import selectors
import signal
import threading
import time
from dataclasses import dataclass
from multiprocessing.connection import Connection
from typing import Any

import numpy as np

from hil_bridge.bus.faults import Faults
from hil_bridge.lifetime import die_with_parent, freeze_heap, reap
from hil_bridge.priority import lower_priority, normal_children
from hil_bridge.server.echo_compute import Region
from hil_bridge.server.echo_pool import WORKER_NICE
from hil_bridge.server.pose_history import PoseHistory
from hil_bridge.server.pose_ring import PoseRing

__all__ = ["NODE_NAME", "STATS_PERIOD_S", "STOP_TIMEOUT_S", "EchoNodes", "NodeSpec"]

log = logging.getLogger(__name__)

#: the node processes' name (``multiprocessing.Process.name``)
NODE_NAME = "echoloop-echo-node"
#: how often (wall s) a node sends its counters to the server
STATS_PERIOD_S = 1.0
#: how long close() lets a node stop before terminating it (s)
STOP_TIMEOUT_S = 5.0
#: seconds a node waits for its bus endpoint to be in sync before it says it is ready
NODE_SYNC_S = 10.0
#: bounds of how often (wall s) a node reads new ticks from the pose ring while a ping waits
#: for its tick (half a tick)
MIN_POLL_S, MAX_POLL_S = 0.0005, 0.005
#: how often (wall s) a node reads the pose ring between pings (at most a quarter of the ring)
RING_POLL_S = 0.1

#: the raw lists of the counters (joined, not summed, across nodes)
RAW = ("ping_echo_ms", "ping_wait_ms", "ping_extrapolated_ms", "echo_compute_ms")


@dataclass(frozen=True, slots=True)
class NodeSpec:
    """What one echo node needs: the server's ``server`` name, ``scene`` spec, ``bus`` URL,
    ``params`` (:class:`~hil_bridge.server.sim_server.ServerParams`), ``clock``
    (:class:`~sim_core.scene.ClockSpec`) and ``tick_ns``; its ``index`` and ``sonar_ids``;
    the ``ring`` of the server's poses (:class:`~hil_bridge.server.pose_ring.PoseRing` path),
    ``points`` (the ``/forest/points`` request, node 0 only) and the ``nice`` it adds to its
    CPU priority."""

    server: str
    scene: Any
    bus: str
    params: Any
    clock: Any
    tick_ns: int
    index: int
    sonar_ids: tuple[int, ...]
    ring: str
    points: tuple[tuple[Region, ...], int] | None
    nice: int = WORKER_NICE


def _node_main(spec: NodeSpec, conn: Connection, parent_pid: int) -> None:
    """Body of an echo node process (module docstring)."""
    die_with_parent(parent_pid, signal.SIGKILL)
    from hil_bridge.bus.clock import SimClock
    from hil_bridge.bus.node import Node
    from hil_bridge.files.scene import load_scene
    from hil_bridge.recording.logs import load_trajectory
    from hil_bridge.server.lockstep import LockstepGate
    from hil_bridge.server.sonars import ServerSonars
    from sim_core.sonar import precull
    from sim_core.world import ball

    signal.signal(signal.SIGINT, signal.SIG_IGN)
    lower_priority(spec.nice)
    name = f"{spec.server}_echo{spec.index}"
    scene = load_scene(spec.scene, trajectory_reader=load_trajectory)
    ball.warm_up()  # the leaf gather and the pre-cull compiled (or loaded) before a ping
    precull.warm_up()
    ring = PoseRing.open(spec.ring)
    history = PoseHistory(ring.ids, tick_ns=spec.tick_ns, history_s=spec.params.pose_history_s)
    ring_lock = threading.Lock()

    def refresh() -> None:
        with ring_lock:
            ring.follow(history)

    refresh()
    rate = spec.clock.rate if spec.clock.mode == "realtime" else 1.0
    tick_s = spec.tick_ns / 1e9 / rate
    faults = Faults(name)
    gate = LockstepGate(lockstep=False, timeout_s=1.0, max_stalls=1, start_timeout_s=1.0)
    sonars = ServerSonars(name, scene, history, spec.tick_ns, gate, spec.clock, spec.params,
                          lambda: max(history.recorded_ns, 0), None, sonar_ids=spec.sonar_ids,
                          pose_refresh=refresh,
                          pose_refresh_s=min(MAX_POLL_S, max(MIN_POLL_S, tick_s / 2)))
    node = Node(name, bus=spec.bus, clock=SimClock("lockstep"), faults=faults)
    sonars.serve(node, "thread", spec.points)
    freeze_heap(collect=True)  # built, nothing running yet
    node.start()
    node.transport.sync(NODE_SYNC_S)
    stop = threading.Event()
    period = min(RING_POLL_S, ring.slots * tick_s / 4)

    def follow() -> None:
        while not stop.wait(period):
            refresh()

    follower = threading.Thread(target=faults.guarded("pose ring", follow), name="pose-ring",
                                daemon=True)
    follower.start()
    sonars.start()

    def snapshot() -> dict[str, Any]:
        out = sonars.stats()
        for key in RAW:
            out[key] = np.asarray(out[key], dtype=np.float64)
        out["pose_ticks_missed"] = ring.missed
        out["failure"] = faults.failure() or ""
        return out

    freeze_heap()
    conn.send(("ready", os.getpid()))
    try:
        while not conn.poll(STATS_PERIOD_S):
            conn.send(("stats", snapshot()))
        with contextlib.suppress(EOFError, OSError):
            conn.recv()
    except (BrokenPipeError, EOFError, OSError):
        pass
    finally:
        stop.set()
        follower.join()
        sonars.ticks_ended()
        sonars.close()
        node.stop()
        with contextlib.suppress(BrokenPipeError, OSError):
            conn.send(("stats", snapshot()))
            conn.close()


class _Proc:
    def __init__(self, proc: Any, conn: Connection, sonar_ids: tuple[int, ...]) -> None:
        self.proc = proc
        self.conn = conn
        self.sonar_ids = sonar_ids
        self.ready = False
        self.stats: dict[str, Any] = {}
        self.gone = False
        self.failed = False


class EchoNodes:
    """``n`` echo node processes (at most one per sonar) serving the sonars of ``template``
    (module docstring).

    ``template`` is a :class:`NodeSpec` whose ``index``, ``sonar_ids`` and ``points`` are set
    per node (``points`` goes to node 0). ``faults``: the server's."""

    def __init__(self, template: NodeSpec, n: int, faults: Faults) -> None:
        ids = tuple(sorted(template.sonar_ids))
        n = max(1, min(n, len(ids)))
        self.faults = faults
        self.n = n
        self._lock = threading.Lock()
        self._ready = threading.Condition(self._lock)
        self._closing = False
        self._selector = selectors.DefaultSelector()
        self._wake_r, self._wake_w = os.pipe()
        self._selector.register(self._wake_r, selectors.EVENT_READ, None)
        ctx = multiprocessing.get_context("spawn")
        self._procs: list[_Proc] = []
        for k in range(n):
            mine = ids[k::n]
            spec = dataclasses.replace(template, index=k, sonar_ids=mine,
                                       points=template.points if k == 0 else None)
            ours, theirs = ctx.Pipe(duplex=True)
            proc = ctx.Process(target=_node_main, args=(spec, theirs, os.getpid()),
                               name=NODE_NAME, daemon=True)
            with normal_children():  # a real-time server's echo nodes compute: never real time
                proc.start()
            theirs.close()
            p = _Proc(proc, ours, mine)
            self._procs.append(p)
            self._selector.register(ours, selectors.EVENT_READ, p)
            self._selector.register(proc.sentinel, selectors.EVENT_READ, p)
        self._thread = threading.Thread(target=faults.guarded("echo nodes", self._run),
                                        name="echo-nodes", daemon=True)
        self._thread.start()

    @classmethod
    def spawn(cls, n: int, faults: Faults, **fields: Any) -> EchoNodes:
        """``n`` nodes of the :class:`NodeSpec` ``fields`` (all but ``index``)."""
        return cls(NodeSpec(index=0, **fields), n, faults)

    def wait_ready(self, timeout: float) -> bool:
        """Every node is on the bus with its first tiles built (within ``timeout`` s)."""
        deadline = time.monotonic() + timeout
        with self._ready:
            while not all(p.ready or p.gone for p in self._procs):
                left = deadline - time.monotonic()
                if left <= 0:
                    return False
                self._ready.wait(left)
            return all(p.ready for p in self._procs)

    def settled(self) -> bool:
        """Every node is ready or gone: :meth:`wait_ready` has nothing more to wait for."""
        with self._ready:
            return all(p.ready or p.gone for p in self._procs)

    def stats(self) -> dict[str, Any]:
        """The nodes' newest counters: numbers summed, :data:`RAW` lists joined,
        ``echo_workers`` the number of nodes, ``last_echo_error`` the last non-empty."""
        with self._lock:
            snaps = [dict(p.stats) for p in self._procs]
        out: dict[str, Any] = {key: [] for key in RAW}
        out["last_echo_error"] = ""
        for snap in snaps:
            for key, value in snap.items():
                if key in RAW:
                    out[key].extend(np.asarray(value).tolist())
                elif key == "last_echo_error":
                    out[key] = value or out[key]
                elif isinstance(value, int | float) and not isinstance(value, bool):
                    out[key] = out.get(key, 0) + value
        out["echo_workers"] = self.n
        out["echo_worker"] = "nodes"
        return out

    def _run(self) -> None:
        while True:
            for key, _ in self._selector.select(0.5):
                p: _Proc | None = key.data
                if p is None:
                    return
                if key.fileobj is p.conn:
                    try:
                        msg = p.conn.recv()
                    except (EOFError, OSError):
                        self._lost(p)
                        continue
                    self._on_message(p, msg)
                elif not p.proc.is_alive():
                    self._lost(p)

    def _on_message(self, p: _Proc, msg: tuple[str, Any]) -> None:
        kind, body = msg
        with self._ready:
            if kind == "ready":
                p.ready = True
                self._ready.notify_all()
            elif kind == "stats":
                failure = body.pop("failure", "")
                p.stats = body
                if failure and not p.failed:
                    p.failed = True
                    self.faults.report(f"echo node of sonars {list(p.sonar_ids)}", failure)

    def _lost(self, p: _Proc) -> None:
        if p.gone:  # its pipe and its sentinel may both say so
            return
        for obj in (p.conn, p.proc.sentinel):
            with contextlib.suppress(KeyError, ValueError, OSError):
                self._selector.unregister(obj)
        p.proc.join(timeout=1.0)
        with self._ready:
            p.gone = True
            self._ready.notify_all()
            closing = self._closing
        if not closing or p.proc.exitcode not in (0, None):
            self.faults.report(f"echo node of sonars {list(p.sonar_ids)} (pid {p.proc.pid})",
                               f"exited (code {p.proc.exitcode})")

    def close(self) -> None:
        """Stop every node, gather its last counters (idempotent)."""
        with self._lock:
            if self._closing:
                return
            self._closing = True
        for p in self._procs:
            with contextlib.suppress(BrokenPipeError, OSError):
                p.conn.send(None)
        reap([p.proc for p in self._procs], STOP_TIMEOUT_S)
        os.write(self._wake_w, b"\0")
        self._thread.join()
        for p in self._procs:  # their last counters, sent as they stopped
            with contextlib.suppress(EOFError, OSError):
                while p.conn.poll(0):
                    self._on_message(p, p.conn.recv())
            p.conn.close()
        self._selector.close()
        for fd in (self._wake_r, self._wake_w):
            with contextlib.suppress(OSError):
                os.close(fd)
