"""The echo service of the simulation server: a ping and its sonar's pose at emission in, an echo
out.

:func:`compute_echo` is the whole computation (a pure function of the scene): the ping's beam at
the sonar's world pose (:func:`sim_core.sonar.mount.ping_beam`: az/el in the sonar frame, so
the beam rolls and pitches with the vehicle), the sonar's ears turned the same way, the leaves
around the sonar and :func:`sim_core.sonar.synthesize`.

:class:`EchoService` runs it off the server's tick loop. :meth:`EchoService.submit` takes an
:class:`EchoRequest` (the ping, the sonar's :class:`SonarPose` at the ping's emission, its
arrival time) into a bounded queue (``queue_size``; when full the oldest waiting request is
dropped, counted and handed to ``on_drop(request)``) and returns at once; one worker answers
requests in order and hands each result to ``on_echo(request, result)`` (``on_error(request,
message)`` when the scene refuses it). The worker is a thread of the server process
(``worker="thread"``: the synthesis and k-d tree queries release the GIL in their heavy
numpy/finufft calls) or a spawned process with its own copy of the scene and tile cache
(``"process"``, for scenes whose tile building or fidelity holds the GIL for long; the launching
script must then be import-safe). Requests and results are plain data, so another scheduler (a
pool, deadlines) can replace the worker behind the same ``submit`` / ``on_echo`` interface.
"""

from __future__ import annotations

import dataclasses
import logging
import math
import multiprocessing
import os
import queue
import signal
import threading
import time
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any, Literal

import numpy as np
from numpy.typing import NDArray

from hil_bridge.errors import HilError
from hil_bridge.messages import SonarPing
from sim_core.scene import Scene

__all__ = [
    "EchoRequest",
    "EchoResult",
    "EchoService",
    "SonarPose",
    "compute_echo",
    "compute_points",
]

log = logging.getLogger(__name__)

F8 = NDArray[np.float64]


@dataclass(frozen=True, slots=True)
class SonarPose:
    """Where a sonar is at ``t_ns`` (sim ns): ``position`` (3,) m world ENU, ``orientation``
    (4,) world-from-sonar ``[w, x, y, z]``."""

    t_ns: int
    position: F8
    orientation: F8


@dataclass(frozen=True, slots=True)
class EchoRequest:
    """One ping to answer: its sonar, the ping, the sonar's pose at emission and the
    ``time.monotonic()`` of its arrival (for the ping → echo latency)."""

    sonar_id: int
    ping: SonarPing
    pose: SonarPose
    received: float


@dataclass(frozen=True, slots=True)
class EchoResult:
    """An echo: ``samples`` float32 (n,) or (channels, n) at ``fs`` Hz, what the synthesiser
    reports, the beam's world ``boresight`` (3,) and the compute time, ns."""

    samples: NDArray[np.float32]
    fs: float
    leaves_in_beam: int
    fidelity: str
    dropped: int
    error_bound: float
    boresight: F8
    compute_ns: int


def compute_echo(
    scene: Scene, sonar_id: int, position: F8, orientation: F8, az: float, el: float,
    beamwidth: float,
) -> EchoResult:
    """The echo of sonar ``sonar_id`` pinging at ``az``, ``el`` (rad, sonar frame) with
    ``beamwidth`` (rad) from ``position`` (3,) m and world-from-sonar ``orientation`` (4,)."""
    from sim_core.sonar import synthesize
    from sim_core.sonar.mount import ears_for_ping, ping_beam

    t0 = time.monotonic()
    p = np.asarray(position, dtype=np.float64)
    q = np.asarray(orientation, dtype=np.float64)
    beam = ping_beam(p, q, az, el, beamwidth)
    params = scene.echo_params(sonar_id)
    sonar = scene.sonar(sonar_id)
    if sonar.ears:
        ears = ears_for_ping(beam, q, [e.position_m for e in sonar.ears],
                             [e.axis for e in sonar.ears], [e.beamwidth_rad for e in sonar.ears])
        params = dataclasses.replace(params, ears=ears)
    leaves = scene.leaves_near(p, scene.query_radius_m(sonar_id))
    echo = synthesize(leaves, beam, params, fidelity=sonar.fidelity)
    bound = echo.error_bound
    return EchoResult(
        samples=np.asarray(echo.samples, dtype=np.float32), fs=float(echo.fs),
        leaves_in_beam=int(echo.leaves_in_beam), fidelity=str(echo.fidelity),
        dropped=int(echo.dropped), error_bound=math.nan if bound is None else float(bound),
        boresight=np.asarray(beam.boresight, dtype=np.float64),
        compute_ns=int((time.monotonic() - t0) * 1e9),
    )


def compute_points(
    scene: Scene, regions: tuple[tuple[tuple[float, float, float], float], ...], limit: int
) -> tuple[NDArray[np.float32], NDArray[np.float32]]:
    """Leaf centres (N, 3) and radii (N,) within the (centre, radius m) ``regions``, evenly
    decimated to at most ``limit`` (what the server publishes on ``/forest/points``)."""
    centers, radii = [], []
    for center, r in regions:
        leaves = scene.leaves_near(np.asarray(center, dtype=np.float64), r)
        centers.append(np.asarray(leaves.centers, dtype=np.float32))
        radii.append(np.asarray(leaves.radii, dtype=np.float32))
    c = np.concatenate(centers) if centers else np.zeros((0, 3), np.float32)
    rr = np.concatenate(radii) if radii else np.zeros(0, np.float32)
    if len(c) > limit:
        keep = np.linspace(0, len(c) - 1, limit).astype(np.intp)
        c, rr = c[keep], rr[keep]
    return c, rr


_JOBS: dict[str, Callable[..., Any]] = {"echo": compute_echo, "points": compute_points}


def _process_main(spec: Any, requests: Any, responses: Any) -> None:
    """Body of the worker process: its own Scene (and forest tile cache), one job at a time;
    exits on ``None`` or when its parent is gone."""
    from hil_bridge.logs import load_trajectory

    signal.signal(signal.SIGINT, signal.SIG_IGN)
    parent = os.getppid()
    scene = Scene(spec, trajectory_reader=load_trajectory)
    while True:
        try:
            job = requests.get(timeout=1.0)
        except queue.Empty:
            if os.getppid() != parent:
                return
            continue
        if job is None:
            return
        key, kind, args = job
        try:
            responses.put((key, _JOBS[kind](scene, *args), ""))
        except ValueError as exc:
            responses.put((key, None, str(exc)))


class _WorkerProcess:
    """A spawned process running jobs; ``call`` blocks until its result (None when closing,
    ``HilError`` if the process died, ``ValueError`` for a job the scene refused)."""

    def __init__(self, spec: Any, stop: threading.Event) -> None:
        ctx = multiprocessing.get_context("spawn")
        self._requests: Any = ctx.Queue()
        self._responses: Any = ctx.Queue()
        self._proc = ctx.Process(
            target=_process_main, args=(spec, self._requests, self._responses),
            name="echoloop-echo", daemon=True,
        )
        self._proc.start()
        self._key = 0
        self._closing = stop

    def call(self, kind: str, args: tuple[Any, ...]) -> Any:
        self._key += 1
        self._requests.put((self._key, kind, args))
        while not self._closing.is_set():
            try:
                key, result, error = self._responses.get(timeout=0.1)
            except queue.Empty:
                if not self._proc.is_alive():
                    raise HilError(f"echo worker exited (code {self._proc.exitcode})") from None
                continue
            if key != self._key:
                continue
            if error:
                raise ValueError(error)
            return result
        return None

    def close(self) -> None:
        if self._proc.is_alive():
            self._requests.put(None)
            self._proc.join(timeout=5.0)
            if self._proc.is_alive():
                self._proc.terminate()
                self._proc.join()
        self._requests.close()
        self._responses.close()
        self._requests.join_thread()
        self._responses.join_thread()


Points = tuple[tuple[tuple[tuple[float, float, float], float], ...], int]


class EchoService:
    """Answers pings at given sonar poses on one worker (see the module docstring).

    ``EchoService(scene, *, worker="thread", queue_size=4, on_echo, on_error, on_drop=None,
    points=None, on_points=None)``: ``points`` = (regions, limit) asks the worker, before the
    first ping, for the leaf points of :func:`compute_points`, handed to ``on_points(centres,
    radii)``. ``start()`` starts the worker; ``close()`` (idempotent) stops it.
    """

    def __init__(
        self,
        scene: Scene,
        *,
        worker: Literal["thread", "process"] = "thread",
        queue_size: int = 4,
        on_echo: Callable[[EchoRequest, EchoResult], None],
        on_error: Callable[[EchoRequest, str], None],
        on_drop: Callable[[EchoRequest], None] | None = None,
        points: Points | None = None,
        on_points: Callable[[NDArray[np.float32], NDArray[np.float32]], None] | None = None,
    ) -> None:
        if queue_size < 1:
            raise ValueError(f"queue_size: expected >= 1, got {queue_size}")
        self.scene = scene
        self.worker = worker
        self._queue: queue.Queue[EchoRequest] = queue.Queue(maxsize=queue_size)
        self._on_echo, self._on_error, self._on_drop = on_echo, on_error, on_drop
        self._points, self._on_points = points, on_points
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self._lock = threading.Lock()
        self._c = {"requests": 0, "dropped": 0, "answered": 0, "errors": 0}
        self._compute_ms: deque[float] = deque(maxlen=10000)

    def start(self) -> None:
        if self._thread is None:
            self._thread = threading.Thread(target=self._run, name="echo-service", daemon=True)
            self._thread.start()

    def close(self) -> None:
        self._stop.set()
        if self._thread is not None:
            self._thread.join()
            self._thread = None

    def submit(self, request: EchoRequest) -> bool:
        """Queue ``request``; False when the queue was full and its oldest request was dropped
        to make room (counted)."""
        dropped = False
        with self._lock:
            self._c["requests"] += 1
        while True:
            try:
                self._queue.put_nowait(request)
                return not dropped
            except queue.Full:
                try:
                    oldest = self._queue.get_nowait()
                except queue.Empty:
                    continue
                dropped = True
                with self._lock:
                    self._c["dropped"] += 1
                if self._on_drop is not None:
                    self._on_drop(oldest)

    def stats(self) -> dict[str, Any]:
        """``requests``, ``dropped``, ``answered``, ``errors`` and the compute times (ms)."""
        with self._lock:
            out: dict[str, Any] = dict(self._c)
            out["compute_ms"] = list(self._compute_ms)
        return out

    def _run(self) -> None:
        worker: _WorkerProcess | None = None
        try:
            if self.worker == "process":
                worker = _WorkerProcess(self.scene.spec, self._stop)
                call = worker.call
            else:
                scene = self.scene

                def call(kind: str, args: tuple[Any, ...]) -> Any:
                    return _JOBS[kind](scene, *args)

            self._send_points(call)
            while not self._stop.is_set():
                try:
                    request = self._queue.get(timeout=0.05)
                except queue.Empty:
                    continue
                self._answer(call, request)
        finally:
            if worker is not None:
                worker.close()

    def _send_points(self, call: Callable[[str, tuple[Any, ...]], Any]) -> None:
        if self._points is None or self._on_points is None:
            return
        try:
            out = call("points", self._points)
        except (ValueError, HilError) as exc:
            log.warning("no forest points: %s", exc)
            return
        if out is not None:
            self._on_points(*out)

    def _answer(self, call: Callable[[str, tuple[Any, ...]], Any], req: EchoRequest) -> None:
        ping = req.ping
        args = (req.sonar_id, req.pose.position, req.pose.orientation, float(ping.az),
                float(ping.el), float(ping.beamwidth))
        try:
            result = call("echo", args)
        except (ValueError, HilError) as exc:
            with self._lock:
                self._c["errors"] += 1
            self._on_error(req, str(exc))
            return
        if result is None:  # closing
            return
        with self._lock:
            self._c["answered"] += 1
            self._compute_ms.append(result.compute_ns / 1e6)
        self._on_echo(req, result)
