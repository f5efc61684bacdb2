"""The workers behind :class:`hil_bridge.server.echo_service.EchoService`: one thread, or a
process pool.

Both offer the scheduler the same small surface: ``idle()``, ``echo(request, job)``,
``points(regions, limit)``, ``build(tile)`` (a tile ahead of the sonars or of the points),
``has_tile(tile)`` (built or being built), ``building(tile)``, ``up()``,
``may_prefetch(reserve)``, ``poll(timeout) -> replies`` and ``close()``; a reply is ``(kind,
request, result, error)`` with kind ``"echo"`` or ``"points"``.

:class:`ProcessPool` runs ``n`` spawned processes, each with its own copy of the scene, one job
at a time (so an idle worker is known and no job waits behind another), over one pipe each:

- **Tiles in shared memory.** A worker that needs a tile nobody has published builds it and
  publishes it (:class:`hil_bridge.server.shared_tiles.SharedTiles`); the others map the same pages.
  The pool keeps the tiles' bytes within the forest's ``max_cache_bytes``: beyond it the least
  recently needed tiles are unlinked and every worker is told to let go of them. Memory bound:
  ``max_cache_bytes`` of shared leaf arrays, plus per worker its interpreter (~150 MB with
  numpy, scipy and finufft); gathering leaves from a tile builds no index
  (:func:`sim_core.world.ball.ball_mask`).
- **The tick loop first.** Workers run at a lower CPU priority (nice :data:`WORKER_NICE`), so
  when the cores are short the server's tick loop, bus and scheduler threads get them first.
  Prefetching takes at most ``n - 1`` workers (with one worker, only an idle one), all of
  them before the server's first tick.
- **Nothing outlives the server.** ``close()`` stops the workers (terminating one that does not
  finish its job within :data:`STOP_TIMEOUT_S`) and removes the shared tiles; a worker exits on
  its own when the server process is gone: its pipe closes, and, should that never reach it
  (a worker still loading its scene, say), the kernel kills it when the server's process dies
  (``PR_SET_PDEATHSIG``; a worker holds nothing to clean up). A worker that dies is reported
  to the pool's :class:`~hil_bridge.bus.faults.Faults` (a failure of the server: the run
  exits non-zero) and replaced (at most :data:`MAX_RESTARTS` times); its echo is reported as an
  error.
"""

from __future__ import annotations

import contextlib
import logging
import multiprocessing
import os
import selectors
import signal
import threading
from collections import OrderedDict
from collections.abc import Sequence
from multiprocessing.connection import Connection
from typing import Any

from hil_bridge.bus.faults import Faults
from hil_bridge.lifetime import die_with_parent, freeze_heap, reap
from hil_bridge.priority import lower_priority, normal_children
from hil_bridge.server.echo_compute import (
    DeadlinePlanner,
    EchoJob,
    EchoRequest,
    Region,
    Synthesize,
    answer_echo,
    compute_points,
)
from sim_core.scene import Scene
from sim_core.sonar.cost import COST, EchoCost

__all__ = ["MAX_RESTARTS", "STOP_TIMEOUT_S", "WORKER_NAME", "WORKER_NICE", "ProcessPool",
           "ThreadWorker", "usable_cores"]

log = logging.getLogger(__name__)

#: the worker processes' name (``multiprocessing.Process.name``)
WORKER_NAME = "echoloop-echo"
#: niceness added to the worker processes (the server's own threads keep theirs)
WORKER_NICE = 5
#: how long close() lets a worker finish its job before terminating it (s)
STOP_TIMEOUT_S = 1.0
#: worker processes replaced after dying, at most, per pool
MAX_RESTARTS = 3

Reply = tuple[str, Any, Any, str]
Tile = tuple[int, int]


def usable_cores() -> int:
    """Cores this process may run on (its CPU affinity where the OS says, else all)."""
    try:
        return max(1, len(os.sched_getaffinity(0)))
    except AttributeError:  # pragma: no cover - not Linux
        return max(1, os.cpu_count() or 1)


class ThreadWorker:
    """The scheduler thread itself computes, one job per :meth:`poll` round (its echoes by
    ``synthesize``, None: :func:`sim_core.sonar.synthesize`)."""

    def __init__(self, scene: Scene, cost: EchoCost = COST,
                 synthesize: Synthesize | None = None) -> None:
        self.scene = scene
        self.planner = DeadlinePlanner(cost)
        self.synthesize = synthesize
        self._replies: list[Reply] = []
        self._wake = threading.Event()

    def idle(self) -> bool:
        return not self._replies

    def up(self) -> bool:
        return True

    def may_prefetch(self, reserve: int = 1) -> bool:
        return True

    def has_tile(self, tile: Tile) -> bool:
        return tile in self.scene.forest_source.cached_tiles

    def building(self, tile: Tile) -> bool:
        """Never: a tile is built within :meth:`build`."""
        return False

    def echo(self, request: EchoRequest, job: EchoJob) -> None:
        try:
            echo = answer_echo(self.scene, job, self.planner, synthesize=self.synthesize)
            self._replies.append(("echo", request, echo, ""))
        except ValueError as exc:
            self._replies.append(("echo", request, None, str(exc)))

    def points(self, regions: Sequence[Region], limit: int) -> None:
        try:
            self._replies.append(("points", None, compute_points(self.scene, regions, limit), ""))
        except ValueError as exc:
            self._replies.append(("points", None, None, str(exc)))

    def build(self, tile: Tile) -> None:
        try:
            self.scene.forest_source.ensure(tile)
        except ValueError as exc:
            log.warning("tile %s not built ahead: %s", tile, exc)

    def poll(self, timeout: float, wake: threading.Event | None = None) -> list[Reply]:
        if not self._replies and wake is not None:
            wake.wait(timeout)
        out, self._replies = self._replies, []
        return out

    def close(self) -> None:
        """Nothing to stop: the computing thread is the scheduler's."""


# ---------------------------------------------------------------------------- worker process


def _worker_main(spec: Any, store_dir: str | None, conn: Connection, nice: int,
                 cost: EchoCost, parent_pid: int, synthesize: Synthesize | None) -> None:
    """Body of a worker process: its own Scene, tiles through the shared store, one job at a
    time, echoes by ``synthesize`` (a module-level function: it is pickled by name); exits on
    ``None``, when the server's end of the pipe closes, or with the server's process."""
    die_with_parent(parent_pid, signal.SIGKILL)
    from hil_bridge.files.scene import load_scene
    from hil_bridge.recording.logs import load_trajectory
    from hil_bridge.server.shared_tiles import SharedTiles
    from sim_core.sonar import precull
    from sim_core.world import ball

    signal.signal(signal.SIGINT, signal.SIG_IGN)
    lower_priority(nice)
    scene = load_scene(spec, trajectory_reader=load_trajectory)
    ball.warm_up()  # the leaf gather and the pre-cull compiled (or loaded) before the first job
    precull.warm_up()
    built: list[tuple[Tile, int]] = []
    forest = None
    if store_dir is not None:
        forest = scene.forest_source
        store = SharedTiles(store_dir, forest.engine.names)
        forest.source = store.source(forest.build, built)
    planner = DeadlinePlanner(cost)
    freeze_heap(collect=True)
    conn.send(("ready", os.getpid(), None, ""))
    while True:
        try:
            msg = conn.recv()
        except (EOFError, OSError):
            return
        if msg is None:
            return
        kind, key, args, forget = msg
        for tile in forget:
            if forest is not None:
                forest.forget(tile)
        out: Any = None
        error = ""
        try:
            if kind == "echo":
                out = answer_echo(scene, args, planner, synthesize=synthesize)
            elif kind == "points":
                out = compute_points(scene, *args)
            elif kind == "build" and forest is not None:
                forest.ensure(args)
        except ValueError as exc:
            error = str(exc)
        try:
            conn.send((kind, key, out, error, list(built)))
        except (BrokenPipeError, OSError):
            return
        built.clear()


class _Slot:
    """One worker process and the job it is on."""

    def __init__(self, proc: Any, conn: Connection) -> None:
        self.proc = proc
        self.conn = conn
        self.ready = False
        self.job: tuple[str, Any] | None = None  # (kind, request or tile)
        self.forget: list[Tile] = []


class ProcessPool:
    """``n`` worker processes sharing forest tiles (module docstring); ``synthesize`` computes
    their echoes (a module-level function; None: :func:`sim_core.sonar.synthesize`)."""

    def __init__(self, scene: Scene, n: int, stop: threading.Event, *, domain: Any = None,
                 cost: EchoCost = COST, faults: Faults | None = None,
                 synthesize: Synthesize | None = None) -> None:
        from hil_bridge.bus.domain import current
        from hil_bridge.server.shared_tiles import SharedTiles
        from sim_core.world import TiledForest

        self.scene = scene
        self.n = n
        self.cost = cost
        self.synthesize = synthesize
        self.faults = faults if faults is not None else Faults("echo_pool")
        self._stop = stop
        self._ctx = multiprocessing.get_context("spawn")
        forest = scene.spec.forest
        fs = scene.forest_spec()
        self.geometry: TiledForest | None = None
        self.store: SharedTiles | None = None
        self.max_bytes = 0
        if forest is not None and fs is not None and forest.tiled and scene.spec.sonars:
            # geometry only: which tiles a region needs (no tile is built in this process)
            self.geometry = TiledForest(fs, seed=scene.forest_seed, files=scene.forest_files,
                                        tile_size_m=forest.tile_size_m)
            self.store = SharedTiles.create(domain or current(), self.geometry.engine.names)
            self.max_bytes = forest.max_cache_bytes
        self._tiles: OrderedDict[Tile, int] = OrderedDict()  # published, least recently used first
        self._building: set[Tile] = set()
        self._wake_r, self._wake_w = os.pipe()
        os.set_blocking(self._wake_r, False)
        self._selector = selectors.DefaultSelector()
        self._selector.register(self._wake_r, selectors.EVENT_READ, None)
        self._bytes = 0
        self._keys = 0
        self._restarts = 0
        self.tiles_built = 0
        self.evicted = 0
        self._slots: list[_Slot] = []
        try:
            self._slots = [self._spawn() for _ in range(n)]
        except BaseException:
            self.close()
            raise

    # -- processes --------------------------------------------------------------------------
    def _spawn(self) -> _Slot:
        mine, theirs = self._ctx.Pipe(duplex=True)
        proc = self._ctx.Process(
            target=_worker_main,
            args=(self.scene.spec, None if self.store is None else str(self.store.directory),
                  theirs, WORKER_NICE, self.cost, os.getpid(), self.synthesize),
            name=WORKER_NAME, daemon=True,
        )
        with normal_children():  # a real-time server's workers compute: never real time
            proc.start()
        theirs.close()
        slot = _Slot(proc, mine)
        self._selector.register(mine, selectors.EVENT_READ, slot)
        self._selector.register(proc.sentinel, selectors.EVENT_READ, slot)
        return slot

    def _lost(self, slot: _Slot) -> list[Reply]:
        """A worker died: report its echo, replace it (up to MAX_RESTARTS)."""
        slot.proc.join(timeout=1.0)  # its pipe may close before it is reaped: then the code
        code = slot.proc.exitcode
        self._forget_slot(slot)
        out: list[Reply] = []
        if slot.job is not None:
            kind, what = slot.job
            if kind == "build":
                self._building.discard(what)
            elif kind in ("echo", "points"):
                out.append((kind, what, None, f"echo worker exited (code {code})"))
        self.faults.report(f"echo worker {slot.proc.pid}", f"exited (code {code})")
        self._slots.remove(slot)
        if self._restarts < MAX_RESTARTS and not self._stop.is_set():
            self._restarts += 1
            self._slots.append(self._spawn())
        return out

    def _forget_slot(self, slot: _Slot) -> None:
        for obj in (slot.conn, slot.proc.sentinel):
            with contextlib.suppress(KeyError, ValueError, OSError):
                self._selector.unregister(obj)
        slot.conn.close()

    # -- scheduler surface ------------------------------------------------------------------
    def wake(self) -> None:
        with contextlib.suppress(OSError):
            os.write(self._wake_w, b"\0")

    def idle(self) -> bool:
        return any(s.ready and s.job is None for s in self._slots)

    def up(self) -> bool:
        """Every worker has started (imported, built its scene)."""
        return bool(self._slots) and all(s.ready for s in self._slots)

    def may_prefetch(self, reserve: int = 1) -> bool:
        """Whether another tile may be built ahead, keeping ``reserve`` workers off building
        (at least one may build)."""
        building = sum(1 for s in self._slots if s.job is not None and s.job[0] == "build")
        return building < max(1, len(self._slots) - reserve)

    def has_tile(self, tile: Tile) -> bool:
        """Published or being built."""
        return tile in self._tiles or tile in self._building

    def building(self, tile: Tile) -> bool:
        return tile in self._building

    def _send(self, kind: str, what: Any, args: Any) -> None:
        slot = next(s for s in self._slots if s.ready and s.job is None)
        self._keys += 1
        slot.job = (kind, what)
        forget, slot.forget = slot.forget, []
        try:
            slot.conn.send((kind, self._keys, args, forget))
        except (BrokenPipeError, OSError):
            slot.ready = False  # its death is noticed by poll()

    def echo(self, request: EchoRequest, job: EchoJob) -> None:
        self._touch(job.position, self.scene.query_radius_m(job.sonar_id))
        self._send("echo", request, job)

    def points(self, regions: Sequence[Region], limit: int) -> None:
        self._send("points", None, (tuple(regions), limit))

    def build(self, tile: Tile) -> None:
        self._building.add(tile)
        self._send("build", tile, tile)

    def _touch(self, position: Any, radius: float) -> None:
        if self.geometry is None or 2 * self._bytes < self.max_bytes:
            return  # far from the bound: the order of eviction does not matter yet
        for t in self.geometry.tiles_near(position, radius):
            if t in self._tiles:
                self._tiles.move_to_end(t)

    def _register(self, built: list[tuple[Tile, int]]) -> None:
        """Tiles a worker published: keep them within max_cache_bytes (LRU)."""
        for tile, nbytes in built:
            self._building.discard(tile)
            if tile not in self._tiles:
                self.tiles_built += 1
            self._bytes += nbytes - self._tiles.get(tile, 0)
            self._tiles[tile] = nbytes
            self._tiles.move_to_end(tile)
        while self._tiles and self._bytes > self.max_bytes and self.store is not None:
            old, nbytes = self._tiles.popitem(last=False)
            self.store.remove(old)
            self._bytes -= nbytes
            self.evicted += 1
            for slot in self._slots:
                slot.forget.append(old)

    def poll(self, timeout: float, wake: threading.Event | None = None) -> list[Reply]:
        """Replies of the workers that finished (waiting up to ``timeout`` for one or a wake)."""
        out: list[Reply] = []
        for key, _ in self._selector.select(timeout):
            slot: _Slot | None = key.data
            if slot is None:
                with contextlib.suppress(BlockingIOError, OSError):
                    while os.read(self._wake_r, 4096):
                        pass
                continue
            if slot not in self._slots:
                continue
            if key.fileobj is slot.conn:
                try:
                    msg = slot.conn.recv()
                except (EOFError, OSError):
                    out.extend(self._lost(slot))
                    continue
                out.extend(self._on_message(slot, msg))
            elif not slot.proc.is_alive():
                out.extend(self._lost(slot))
        return out

    def _on_message(self, slot: _Slot, msg: tuple[Any, ...]) -> list[Reply]:
        kind = msg[0]
        if kind == "ready":
            slot.ready = True
            return []
        _, _, out, error, built = msg
        self._register(built)
        job, slot.job = slot.job, None
        if job is None or kind == "build":
            if kind == "build" and job is not None:
                self._building.discard(job[1])
            return []
        return [(kind, job[1], out, error)]

    def stats(self) -> dict[str, int]:
        return {"worker_restarts": self._restarts, "tiles_built": self.tiles_built,
                "tile_bytes": self._bytes, "tiles_evicted": self.evicted}

    def close(self) -> None:
        """Stop every worker (terminate those still busy after STOP_TIMEOUT_S), remove the
        shared tiles (idempotent)."""
        for s in self._slots:
            with contextlib.suppress(BrokenPipeError, OSError):
                s.conn.send(None)
        reap([s.proc for s in self._slots], STOP_TIMEOUT_S)
        for s in self._slots:
            self._forget_slot(s)
        self._slots = []
        self._selector.close()
        for fd in (self._wake_r, self._wake_w):
            with contextlib.suppress(OSError):
                os.close(fd)
        self._wake_r = self._wake_w = -1
        if self.store is not None:
            self.store.remove_all()
