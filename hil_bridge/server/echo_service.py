"""The echo service of the simulation server: a ping and its sonar's pose at emission in, an echo
out, on a thread or a pool of processes, within the ping's deadline.

What one echo is and how it is computed (:func:`~hil_bridge.server.echo_compute.compute_echo`,
a pure function of the scene) lives in :mod:`hil_bridge.server.echo_compute`.

:class:`EchoService` runs it off the server's tick loop. :meth:`EchoService.submit` takes an
:class:`EchoRequest` (the ping, the sonar's :class:`SonarPose` at the ping's emission, its
arrival time and its *deadline*) and returns at once; a scheduler thread hands each request to
an idle worker, earliest deadline first, and gives the result to ``on_echo(request, result)``
(``on_error(request, message)`` when the scene refuses it). Workers (``worker=``):

- ``"thread"``: the scheduler thread computes in the server process (the synthesis and the
  compiled leaf gather release the GIL in their heavy calls; tile building does not);
- ``"pool"``: ``workers`` spawned processes (default: one per usable core), each with its own
  copy of the scene, sharing the forest's tiles through shared memory
  (:mod:`hil_bridge.server.shared_tiles`), at a lower CPU priority than the server's tick loop
  (:mod:`hil_bridge.server.echo_pool`); ``"process"`` is a pool of one. The launching script must be
  import-safe.

**Deadlines.** A request's deadline (``time.monotonic()``) is when its sonar's next ping is due:
given by the server for heads that ping on sim time, otherwise estimated here from the median
interval of the sonar's last pings (none for its first ones), or ``budget_s`` after the ping arrived
when that is earlier (a latency bound the consumer of the echoes sets); ``deadlines=False``
(lockstep, fast) gives none. A ping whose echo cannot be ready by then is not queued: a newer ping
of the same sonar replaces a waiting one, a request whose time is up is dropped before it starts,
and the worker, once it knows the leaves in range, predicts the scene fidelity's time with the cost
model (:data:`sim_core.sonar.cost.COST`, scaled by its measured ratio): if it does not fit, the echo
is *degraded* to ``realtime`` with the time left as its budget (its ``error_bound`` says what that
cost), or dropped when not even that fits. Every case is counted (:meth:`stats`). Without a deadline
requests wait in arrival order, at most ``queue_size`` per sonar (its oldest dropped).

**Ahead of the pings.** Every :data:`LOOKAHEAD_S` the scheduler asks ``lookahead()`` for the
regions the sonars will reach (the server's prediction along each vehicle's motion) and has
idle workers build those tiles, so a ping seldom waits for a tile: before the service is
ready (:meth:`EchoService.wait_ready`, which a server waits for before its first tick) every
worker builds the tiles of the first lookahead; afterwards, in a pool of two or more, a
missing tile ahead takes one worker before a waiting echo (an echo whose tile is missing
would build it anyway, past its deadline), the others answering pings. ``points=(regions, limit)``
asks for the leaf points of
:func:`~hil_bridge.server.echo_compute.compute_points` once, handed to ``on_points(centres,
radii)``: its tiles are built first, one job each, then the points are gathered from them.
Both run at a lower priority than echoes, and with a process worker neither holds the
server's interpreter.
"""

from __future__ import annotations

import dataclasses
import logging
import math
import statistics
import threading
import time
from collections import OrderedDict, deque
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Any, Literal

import numpy as np
from numpy.typing import NDArray

from hil_bridge.bus.faults import Faults
from hil_bridge.server.echo_compute import (
    MAX_POINT_TILES,
    PUBLISH_MARGIN_S,
    EchoJob,
    EchoRequest,
    EchoResult,
    Region,
    Synthesize,
    region_tiles,
)
from hil_bridge.server.echo_pool import ProcessPool, ThreadWorker, usable_cores
from sim_core.scene import Scene
from sim_core.sonar.cost import COST, EchoCost

__all__ = ["LOOKAHEAD_S", "EchoService"]

log = logging.getLogger(__name__)

#: how often (wall s) the scheduler asks where the sonars are going
LOOKAHEAD_S = 0.25
#: pings whose interval is remembered per sonar (for the deadline of the next one)
PERIOD_WINDOW = 5


Points = tuple[tuple[Region, ...], int]


@dataclass(slots=True)
class _Waiting:
    request: EchoRequest
    deadline: float | None


class EchoService:
    """Answers pings at given sonar poses on a thread or a process pool (module docstring).

    ``EchoService(scene, *, worker="thread", workers=None, queue_size=4, deadlines=True,
    budget_s=None, on_echo, on_error, on_drop=None, points=None, on_points=None, lookahead=None,
    domain=None, cost=COST, synthesize=None)``: ``on_drop(request)`` for every ping dropped
    unanswered (full queue or deadline); ``lookahead() -> regions`` the sonars will reach;
    ``domain`` names the pool's shared memory (default: the current one); ``cost`` the cost
    model the deadlines are planned with; ``synthesize`` what computes each echo (a
    module-level function for a pool; None: :func:`sim_core.sonar.synthesize`);
    ``faults`` where a scheduler thread or a worker process that dies is reported (the server's;
    default a record of its own). ``start()`` starts the workers; ``close()`` (idempotent) stops
    them and removes their shared memory.
    """

    def __init__(
        self,
        scene: Scene,
        *,
        worker: Literal["thread", "process", "pool"] = "thread",
        workers: int | None = None,
        queue_size: int = 4,
        deadlines: bool = True,
        budget_s: float | None = None,
        on_echo: Callable[[EchoRequest, EchoResult], None],
        on_error: Callable[[EchoRequest, str], None],
        on_drop: Callable[[EchoRequest], None] | None = None,
        points: Points | None = None,
        on_points: Callable[[NDArray[np.float32], NDArray[np.float32]], None] | None = None,
        lookahead: Callable[[], Sequence[Region]] | None = None,
        domain: Any = None,
        cost: EchoCost = COST,
        faults: Faults | None = None,
        synthesize: Synthesize | None = None,
    ) -> None:
        if queue_size < 1:
            raise ValueError(f"queue_size: expected >= 1, got {queue_size}")
        if worker not in ("thread", "process", "pool"):
            raise ValueError(f"worker: expected 'thread', 'process' or 'pool', got {worker!r}")
        if workers is not None and workers < 1:
            raise ValueError(f"workers: expected >= 1 or None (one per core), got {workers}")
        if budget_s is not None and not budget_s > 0:
            raise ValueError(f"budget_s: expected > 0 or None, got {budget_s}")
        self.scene = scene
        self.worker = worker
        self.n_workers = 0 if worker == "thread" else (
            1 if worker == "process" else (workers or usable_cores()))
        self.queue_size = queue_size
        self.deadlines = deadlines
        self.budget_s = budget_s
        self._on_echo, self._on_error, self._on_drop = on_echo, on_error, on_drop
        self._points, self._on_points = points, on_points
        self._lookahead = lookahead
        self._domain = domain
        self.cost = cost
        self.synthesize = synthesize
        self.faults = faults if faults is not None else Faults("echo_service")
        self._stop = threading.Event()
        self._wake = threading.Event()
        self._ready = threading.Event()
        self._thread: threading.Thread | None = None
        self._lock = threading.Lock()
        self._waiting: list[_Waiting] = []
        self._arrivals: dict[int, deque[float]] = {}
        self._c = {"requests": 0, "dropped": 0, "answered": 0, "errors": 0, "expired": 0,
                   "degraded": 0, "late": 0, "tiles_prefetched": 0}
        self._compute_ms: deque[float] = deque(maxlen=10000)
        self._pool: Any = None
        self._wanted: OrderedDict[tuple[int, int], None] = OrderedDict()

    # ------------------------------------------------------------------ public

    def start(self) -> None:
        if self._thread is None:
            self._thread = threading.Thread(target=self._run, name="echo-service", daemon=True)
            self._thread.start()

    def wait_ready(self, timeout: float | None = None) -> bool:
        """Block until the workers are up and the tiles the sonars reach first are built
        (:meth:`start` first); False on timeout. A server calls it before its first tick, so
        neither the workers' start nor those tiles compete with its tick loop."""
        return self._ready.wait(timeout)

    def close(self) -> None:
        self._stop.set()
        self._notify()
        if self._thread is not None:
            self._thread.join()
            self._thread = None

    def submit(self, request: EchoRequest) -> bool:
        """Queue ``request``; False when a waiting request of its sonar was dropped for it (the
        previous ping, whose deadline this one is, or the oldest of the sonar's full queue;
        counted and handed to ``on_drop``)."""
        deadline = request.deadline if self.deadlines else None
        dropped: list[tuple[EchoRequest, str]] = []
        with self._lock:
            self._c["requests"] += 1
            if self.deadlines and deadline is None:
                deadline = self._estimate_deadline(request.sonar_id, request.received)
            if self.deadlines and self.budget_s is not None:
                deadline = min(math.inf if deadline is None else deadline,
                               request.received + self.budget_s)
            same = [w for w in self._waiting if w.request.sonar_id == request.sonar_id]
            if self.deadlines:
                for w in same:
                    self._waiting.remove(w)
                    dropped.append((w.request, "expired"))
            elif len(same) >= self.queue_size:
                self._waiting.remove(same[0])
                dropped.append((same[0].request, "dropped"))
            self._waiting.append(_Waiting(request, deadline))
            for _, why in dropped:
                self._c[why] += 1
        for req, _ in dropped:
            if self._on_drop is not None:
                self._on_drop(req)
        self._notify()
        return not dropped

    def stats(self) -> dict[str, Any]:
        """``requests``, ``answered``, ``dropped`` (full queue), ``expired`` (deadline),
        ``degraded``, ``late`` (published after their deadline), ``errors``, the compute
        times (ms), and the pool's ``workers``, ``worker_restarts``, ``tiles_built``,
        ``tiles_prefetched``, ``tile_bytes``."""
        with self._lock:
            out: dict[str, Any] = dict(self._c)
            out["compute_ms"] = list(self._compute_ms)
        pool = self._pool
        out["workers"] = self.n_workers
        out.update(pool.stats() if pool is not None else
                   {"worker_restarts": 0, "tiles_built": 0, "tile_bytes": 0})
        return out

    # ------------------------------------------------------------------ scheduling

    def _notify(self) -> None:
        self._wake.set()
        pool = self._pool
        if pool is not None:
            pool.wake()

    def _estimate_deadline(self, sonar_id: int, received: float) -> float | None:
        """The sonar's next ping is due one median interval after this one (None until two
        pings have been seen)."""
        arrivals = self._arrivals.setdefault(sonar_id, deque(maxlen=PERIOD_WINDOW + 1))
        arrivals.append(received)
        if len(arrivals) < 2:
            return None
        gaps = [b - a for a, b in zip(arrivals, list(arrivals)[1:], strict=False)]
        return received + float(statistics.median(gaps))

    def _next_request(self, now: float) -> EchoRequest | None:
        """Earliest deadline first (then arrival); requests whose time is up are dropped."""
        expired: list[EchoRequest] = []
        chosen = None
        with self._lock:
            for w in list(self._waiting):
                if w.deadline is not None and now >= w.deadline - PUBLISH_MARGIN_S:
                    self._waiting.remove(w)
                    self._c["expired"] += 1
                    expired.append(w.request)
            if self._waiting:
                best = min(self._waiting, key=lambda w: (
                    math.inf if w.deadline is None else w.deadline, w.request.received))
                self._waiting.remove(best)
                chosen = dataclasses.replace(best.request, deadline=best.deadline)
        for req in expired:
            if self._on_drop is not None:
                self._on_drop(req)
        return chosen

    def _job(self, req: EchoRequest) -> EchoJob:
        ping = req.ping
        return EchoJob(req.sonar_id, req.pose.position, req.pose.orientation, float(ping.az),
                       float(ping.el), float(ping.beamwidth), req.deadline, req.pose.velocity)

    def _refresh_wanted(self) -> None:
        """Tiles of the regions the sonars will reach, nearest in time first."""
        if self._lookahead is None or not self._tiled():
            return
        try:
            regions = self._lookahead()
        except (ValueError, KeyError) as exc:
            log.warning("echo lookahead failed: %s", exc)
            return
        self._wanted = OrderedDict.fromkeys(region_tiles(self._geometry(), regions))

    def _tiled(self) -> bool:
        forest = self.scene.spec.forest
        return forest is not None and forest.tiled and bool(self.scene.spec.sonars)

    def _geometry(self) -> Any:
        """Which tiles a region needs (the pool's geometry: no tile built in this process)."""
        return self._pool.geometry if self._pool is not None else self.scene.forest_source

    def _finish(self, req: EchoRequest, result: EchoResult | None, error: str) -> None:
        """Account for one request's outcome and hand it on."""
        if error:
            with self._lock:
                self._c["errors"] += 1
            self._on_error(req, error)
            return
        if result is None:
            with self._lock:
                self._c["expired"] += 1
            if self._on_drop is not None:
                self._on_drop(req)
            return
        late = req.deadline is not None and time.monotonic() > req.deadline
        with self._lock:
            self._c["answered"] += 1
            self._c["degraded"] += int(result.degraded)
            self._c["late"] += int(late)
            self._compute_ms.append(result.compute_ns / 1e6)
        self._on_echo(req, result)

    def _run(self) -> None:
        try:
            if self.worker == "thread":
                from sim_core.sonar import precull
                from sim_core.world import ball

                ball.warm_up()  # the leaf gather and the pre-cull compiled (or loaded) before
                precull.warm_up()  # the first ping
                self._serve(ThreadWorker(self.scene, self.cost, self.synthesize))
            else:
                self._pool = ProcessPool(self.scene, self.n_workers, self._stop,
                                         domain=self._domain, cost=self.cost,
                                         faults=self.faults, synthesize=self.synthesize)
                try:
                    self._serve(self._pool)
                finally:
                    self._pool.close()
        except Exception as exc:  # a scheduler bug must not vanish with its thread
            self.faults.report("echo service", exc)
            with self._lock:
                self._c["errors"] += 1
        finally:
            self._ready.set()  # nobody waits for a service that ended

    def _serve(self, workers: Any) -> None:
        """The scheduler: replies in, then idle workers get, in order: until ready, the tiles
        the sonars reach first (every worker); a tile ahead of the sonars when another worker
        is free for pings (a pool of two or more: an echo whose tile is missing would build it
        anyway, past its deadline); the most urgent echo; a tile ahead of the sonars; a tile of
        the points; else (those built once) the points. Every tile is its own job, so a ping
        never waits behind a whole ``/forest/points``."""
        next_look = time.monotonic()
        points = self._points if self._on_points is not None else None
        point_tiles: list[tuple[int, int]] = []
        if points is not None and self._tiled():
            point_tiles = region_tiles(self._geometry(), points[0], MAX_POINT_TILES)
        # consumed once: a tile evicted again before the points job is rebuilt by that job
        points_ahead = OrderedDict.fromkeys(point_tiles)
        self._refresh_wanted()
        first_tiles = list(self._wanted)
        tiles_first = self.n_workers > 1
        while not self._stop.is_set():
            replies = workers.poll(0.05, self._wake)
            self._wake.clear()
            for reply in replies:
                self._reply(reply)
            now = time.monotonic()
            if now >= next_look:
                self._refresh_wanted()
                next_look = now + LOOKAHEAD_S
            warming = not self._ready.is_set()
            while not self._stop.is_set() and workers.idle():
                if warming and self._prefetch_one(workers, self._wanted, reserve=0):
                    continue
                if tiles_first and self._prefetch_one(workers, self._wanted):
                    continue
                req = self._next_request(time.monotonic())
                if req is not None:
                    workers.echo(req, self._job(req))
                elif warming:
                    break  # the points once ticking: the first tick waits for the tiles only
                elif self._prefetch_one(workers, self._wanted):
                    continue
                elif points is None:
                    break
                elif self._prefetch_one(workers, points_ahead):
                    continue
                elif points_ahead or any(map(workers.building, point_tiles)):
                    break
                else:
                    workers.points(*points)
                    points = None
            if warming and workers.up() and all(
                    workers.has_tile(t) and not workers.building(t) for t in first_tiles):
                self._ready.set()

    def _prefetch_one(
        self, workers: Any, wanted: OrderedDict[tuple[int, int], None], reserve: int = 1
    ) -> bool:
        """Give one tile of ``wanted`` (consumed in order) to an idle worker, keeping
        ``reserve`` workers free for pings."""
        while wanted:
            tile, _ = wanted.popitem(last=False)
            if workers.has_tile(tile):
                continue
            if not workers.may_prefetch(reserve):
                wanted[tile] = None
                wanted.move_to_end(tile, last=False)
                return False
            workers.build(tile)
            with self._lock:
                self._c["tiles_prefetched"] += 1
            return True
        return False

    def _reply(self, reply: tuple[str, Any, Any, str]) -> None:
        kind, req, out, error = reply
        if kind == "echo":
            self._finish(req, out, error)
        elif kind == "points":
            if error:
                log.warning("no forest points: %s", error)
            elif self._on_points is not None:
                self._on_points(*out)
