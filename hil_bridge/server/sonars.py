"""The simulation server's sonar side: pings in, echoes out (:mod:`hil_bridge.server.sim_server`).

**Echoes** (this module, :mod:`hil_bridge.server.emission`,
:mod:`hil_bridge.server.echo_service`). A ping is answered at its sonar's world pose at the
ping's *emission*: the ping's ``stamp_ns`` when the sender gives one (> 0), else its arrival
(the latest tick), the vehicle's pose interpolated between ticks from a ``pose_history_s``
history, composed with the sonar's mount. A stamp after the latest tick waits (off the tick
loop, at most ``pose_wait_ticks`` tick periods) for the tick that covers it
(``ping_stamp_waited``), or is extrapolated from the latest tick when that tick is late
(``ping_stamp_extrapolated``); stamps more than ``pose_history_s`` after the latest tick, or
before the history, use the newest or oldest pose (``ping_stamp_future``, ``ping_stamp_old``).
Echoes are computed off the tick loop by :class:`hil_bridge.server.echo_service.EchoService`: on a
thread, or ``echo_worker: pool``, ``echo_workers`` processes (default one per core) sharing the
forest's tiles in shared memory at a lower CPU priority than the tick loop (``process``: a pool of
one), or, with ``echo_worker: nodes`` (``auto``'s choice for several sonars on several cores), by
echo nodes: processes that take the pings from the bus and publish the echoes themselves, at poses
the server shares in memory (:mod:`hil_bridge.server.echo_nodes`); the server's process then never
sees a ping. The launching script must be import-safe for any of the processes. In ``realtime`` mode
a ping's echo is due before its sonar's next ping (``echo_deadlines``): one that cannot be ready by
then is degraded to the ``realtime`` fidelity within the time left (``echoes_degraded``) or dropped
(``pings_dropped_deadline``) instead of queuing; ``echo_budget_ms`` makes an echo due that long
after its ping arrived when that comes first (a consumer's latency bound). Without deadlines pings
wait in a bounded queue per sonar (``echo_queue``; when full its oldest is dropped,
``pings_dropped``). The tiles each sonar will reach along its vehicle's motion (the next
:data:`~hil_bridge.server.sonars.LOOKAHEAD_HORIZON_S` s of wall time) are built ahead of its pings;
the first tick waits until the workers are up and the tiles of that first horizon are built (at most
:data:`~hil_bridge.server.sonars.ECHO_READY_TIMEOUT_S`).

:class:`ServerSonars` subscribes to its sonars' ``/sonar/<id>/ping``, answers each at its
sonar's world pose and velocity at the ping's emission (the carrying vehicle's, from a pose
history, found by :class:`hil_bridge.server.emission.EmissionPoses`: a ping stamped just after
the newest tick waits for the tick that covers it; composed with the sonar's mount) through
:class:`hil_bridge.server.echo_service.EchoService`, and
publishes ``/sonar/<id>/echo`` (frame ``glider/<mount id>``) and the latched
``/forest/points``. It tells the echo service where the sonars are going (:meth:`lookahead`)
so the tiles they will reach are built ahead, and which regions ``/forest/points`` covers
(:meth:`points_request`). Its counters join the server's summary (:meth:`stats`).

In the server (:meth:`ServerSonars.attach`) it serves every sonar from the fleet's history, in
the server's process, or hands them to echo nodes (:mod:`hil_bridge.server.echo_nodes`), each
of which runs a :class:`ServerSonars` of its share of the sonars (:meth:`ServerSonars.serve`)
on the history it copies from the server's pose ring.
"""

from __future__ import annotations

import logging
import threading
import time
from collections import deque
from collections.abc import Callable, Sequence
from typing import Any, Literal, cast

import numpy as np

from hil_bridge.bus.messages import PointCloud, SonarEcho, SonarPing
from hil_bridge.lifetime import stopping, wait_unless_stopping
from hil_bridge.server.echo_compute import EchoRequest, EchoResult, Region, SonarPose
from hil_bridge.server.echo_pool import WORKER_NICE, usable_cores
from hil_bridge.server.echo_service import EchoService
from hil_bridge.server.emission import EMISSION_COUNTERS, EmissionPoses
from hil_bridge.server.fleet import FleetStates
from hil_bridge.server.lockstep import LockstepGate
from hil_bridge.server.pose_history import PoseHistory, VehiclePose
from hil_bridge.server.pose_ring import PoseRing
from sim_core.config import ConfigError
from sim_core.pose import cross, direction_from_az_el, pose_compose, quat_from_euler, quat_rotate
from sim_core.scene import ClockSpec, Scene

__all__ = ["ECHO_COUNTERS", "ECHO_READY_TIMEOUT_S", "LOOKAHEAD_HORIZON_S", "LOOKAHEAD_STEPS",
           "ServerSonars"]

log = logging.getLogger(__name__)

#: how far ahead (wall s) the tiles a sonar will reach are built
LOOKAHEAD_HORIZON_S = 2.0
#: points per second of that horizon at which the path ahead is sampled
LOOKAHEAD_STEPS = 2
#: how long start() waits for the echo workers and the tiles the sonars reach first (s)
ECHO_READY_TIMEOUT_S = 60.0

#: EchoService stats -> server counters
ECHO_COUNTERS = {
    "dropped": "pings_dropped", "expired": "pings_dropped_deadline",
    "degraded": "echoes_degraded", "late": "echoes_late", "errors": "echo_errors",
    "workers": "echo_workers", "worker_restarts": "echo_worker_restarts",
    "tiles_built": "echo_tiles_built", "tiles_prefetched": "echo_tiles_prefetched",
    "tile_bytes": "echo_tile_bytes",
}


Worker = Literal["thread", "process", "pool", "nodes"]


def choose_worker(asked: str, sonars: int, cores: int, *, nodes_ok: bool = True) -> Worker:
    """The echo worker ``echo_worker: auto`` means: echo nodes when several sonars ping and
    there is a core for each of two (their echoes then compute side by side, off the server's
    interpreter), a pool where nodes cannot serve (``nodes_ok`` false: a lockstep clock or an
    in-process bus), else a thread (one sonar's echoes never overlap, and a thread costs no
    start-up); any other choice as asked."""
    if asked == "nodes" and not nodes_ok:
        raise ConfigError("echo_worker: nodes needs a realtime or fast clock and a bus other "
                          "processes reach (not lockstep, not mem://); use pool or thread")
    if asked in ("thread", "process", "pool", "nodes"):
        return cast(Worker, asked)
    if asked != "auto":
        raise ConfigError(f"echo_worker: expected auto, thread, process, pool or nodes, got "
                          f"{asked!r}")
    if sonars >= 2 and cores >= 2:
        return "nodes" if nodes_ok else "pool"
    return "thread"


class ServerSonars:
    """The sonars of ``scene`` (those of ``sonar_ids``, default all) served by the server (or
    echo node) ``name`` (module docstring), at the poses of ``history``, recorded every
    ``tick_ns``.

    ``now_ns()`` is the latest tick (sim ns): a ping without an emission stamp was emitted
    then, and echoes are stamped with it. ``params`` are the server's
    :class:`hil_bridge.server.sim_server.ServerParams` (``forest_points``, ``echo_*``).
    ``pose_refresh`` (an echo node's) brings ``history`` up to date before a ping is placed and
    every ``pose_refresh_s`` while one waits for its tick (:class:`~hil_bridge.server.
    emission.EmissionPoses`).
    """

    def __init__(self, name: str, scene: Scene, history: PoseHistory, tick_ns: int,
                 gate: LockstepGate, clock: ClockSpec, params: Any, now_ns: Any, domain: Any,
                 *, sonar_ids: Sequence[int] | None = None,
                 node_nice: int = WORKER_NICE, pose_refresh: Callable[[], None] | None = None,
                 pose_refresh_s: float = 0.001) -> None:
        self.name = name
        self.node_nice = node_nice
        self.scene = scene
        self.history = history
        self._sonar_specs = [s for s in scene.spec.sonars
                             if sonar_ids is None or s.id in sonar_ids]
        self._gate = gate
        self._clock = clock
        self._params = params
        self._now_ns = now_ns
        self._domain = domain
        self._tick_ns = tick_ns
        self._vehicle_specs = {v.id: v for v in scene.spec.vehicles}
        self._mounts = {
            s.id: (s.mount, np.asarray(s.mount_offset_m, dtype=np.float64),
                   quat_from_euler(*s.mount_rpy_rad))
            for s in self._sonar_specs
        }
        self._lock = threading.Lock()
        self._c = dict.fromkeys(("pings_received", "echoes_published"), 0)
        wait_s = 0.0  # pose_wait_ticks 0: extrapolated at once
        if params.pose_wait_ticks > 0 and clock.mode == "realtime":
            wait_s = params.pose_wait_ticks * tick_ns / 1e9 / clock.rate
        elif params.pose_wait_ticks > 0:  # ticks not on the wall clock: a step's patience
            wait_s = clock.lockstep_timeout_s
        self.emission = EmissionPoses(history, horizon_ns=round(params.pose_history_s * 1e9),
                                      wait_s=wait_s, on_pose=self._answer,
                                      refresh=pose_refresh, refresh_s=pose_refresh_s,
                                      on_error=self._pose_failed)
        self._ping_echo_ms: deque[float] = deque(maxlen=10000)
        self._last_error = ""
        self._pubs: dict[str, Any] = {}
        self.service: EchoService | None = None
        self.nodes: Any = None  # hil_bridge.server.echo_nodes.EchoNodes
        self.ring: PoseRing | None = None
        self.worker: str = ""

    @property
    def worker_nice(self) -> int | None:
        """The nice the echo workers add to theirs: ``node_nice`` for echo nodes,
        :data:`~hil_bridge.server.echo_pool.WORKER_NICE` for a pool, 0 for the thread (it runs
        at the server's), None before :meth:`attach` (or without sonars)."""
        if not self.worker:
            return None
        return {"nodes": self.node_nice, "thread": 0}.get(self.worker, WORKER_NICE)

    def attach(self, node: Any, first: FleetStates,
               spawn_nodes: Callable[..., Any] | None) -> None:
        """The server's sonars on ``node``: echo nodes (``echo_worker: nodes``, started by
        ``spawn_nodes``, :meth:`hil_bridge.server.echo_nodes.EchoNodes.spawn`; None where
        nodes cannot serve: see :func:`choose_worker`) or publishers, ping subscriptions and
        the (not yet started) echo service in this process; ``first`` is the fleet's state of
        tick 0 (where the points' routes start, and the echo nodes' first poses)."""
        if not self._sonar_specs:
            return
        p = self._params
        self.worker = choose_worker(p.echo_worker, len(self._sonar_specs), usable_cores(),
                                    nodes_ok=spawn_nodes is not None)
        points = self.points_request(first) if p.forest_points > 0 else None
        if self.worker != "nodes" or spawn_nodes is None:
            self.serve(node, self.worker, points)
            return
        from hil_bridge.bus.domain import current

        self.ring = PoseRing.create(self._domain or current(), self.history.ids)
        rows = [first.ids.index(v) for v in self.history.ids]
        self.ring.write(first.t_ns, first.position[rows], first.velocity[rows],
                        first.quat[rows], first.rates[rows])
        self.history.mirror_to(self.ring)
        self.nodes = spawn_nodes(
            p.echo_workers or usable_cores(), node.faults, server=self.name,
            scene=self.scene.spec, bus=node.bus, params=p, clock=self._clock,
            tick_ns=self._tick_ns, sonar_ids=tuple(s.id for s in self._sonar_specs),
            ring=str(self.ring.path), points=points, nice=self.node_nice,
        )

    def serve(self, node: Any, worker: Worker,
              points: tuple[tuple[Region, ...], int] | None) -> None:
        """Publishers, ping subscriptions and the (not yet started) echo service of
        ``worker`` on ``node``, in this process; ``points``: the latched ``/forest/points``
        request, or None."""
        from hil_bridge.bus.qos import LATCHED, SENSOR

        self.worker = worker
        if points is not None:
            self._pubs["/forest/points"] = node.create_publisher(
                PointCloud, "/forest/points", qos=LATCHED)
        for sonar in self._sonar_specs:
            self._pubs[f"/sonar/{sonar.id}/echo"] = node.create_publisher(
                SonarEcho, f"/sonar/{sonar.id}/echo", qos=SENSOR,
                frame_id=f"glider/{sonar.mount}",
            )
            node.create_subscription(
                SonarPing, f"/sonar/{sonar.id}/ping", self._make_ping_callback(sonar.id),
                qos=SENSOR,
            )
        p = self._params
        self.service = EchoService(
            self.scene, worker=cast(Literal["thread", "process", "pool"], worker),
            workers=p.echo_workers, queue_size=p.echo_queue,
            deadlines=p.echo_deadlines and self._clock.mode == "realtime",
            budget_s=None if p.echo_budget_ms is None else p.echo_budget_ms / 1e3,
            on_echo=self._publish_echo, on_error=self._echo_failed,
            on_drop=lambda req: self._gate.echo_done(req.sonar_id),
            points=points, on_points=self._publish_points, lookahead=self.lookahead,
            domain=self._domain, faults=node.faults,
        )

    def start(self) -> None:
        """Start the echo service and wait (at most :data:`ECHO_READY_TIMEOUT_S`) until its
        workers (or echo nodes) are up and the first tiles built: the server ticks after
        this."""
        nodes = self.nodes
        if nodes is not None:
            self._ready("echo nodes", lambda s: nodes.wait_ready(s) or nodes.settled(),
                        lambda: nodes.wait_ready(0.0))
            return
        service = self.service
        if service is None:
            return
        self.emission.start(service.faults)
        service.start()
        self._ready("echo workers", service.wait_ready, lambda: service.wait_ready(0.0))

    def _ready(self, what: str, settled: Callable[[float], bool],
               ready: Callable[[], bool]) -> None:
        """Wait (``settled(seconds)``: True once there is nothing more to wait for) until
        ``what`` is ``ready()``; go on, saying so, after ECHO_READY_TIMEOUT_S or once the
        process was asked to stop (:func:`hil_bridge.lifetime.wait_unless_stopping`: its host
        stops this server next, which removes its tile store or pose ring)."""
        wait_unless_stopping(settled, ECHO_READY_TIMEOUT_S)
        if ready():
            return
        if stopping():
            log.info("%s: asked to stop before the %s were ready", self.name, what)
        else:
            log.warning("%s: %s not ready (waited up to %.0f s); ticking anyway", self.name,
                        what, ECHO_READY_TIMEOUT_S)

    def ticks_ended(self) -> None:
        """The server stopped ticking: no ping waits for a tick any more."""
        self.emission.ticks_ended()

    def close(self) -> None:
        self.emission.close()
        if self.service is not None:
            self.service.close()
        if self.nodes is not None:
            self.nodes.close()
        if self.ring is not None:
            self.ring.remove()

    def stats(self) -> dict[str, Any]:
        """Ping and echo counters, the emission poses' counters
        (:data:`hil_bridge.server.emission.EMISSION_COUNTERS`, ``pings_waiting_tick``),
        ``last_echo_error``, the echo service's counters (named as in :data:`ECHO_COUNTERS`)
        and the raw ``ping_echo_ms`` / ``ping_wait_ms`` / ``ping_extrapolated_ms`` /
        ``echo_compute_ms`` lists; with echo nodes, theirs merged
        (:meth:`hil_bridge.server.echo_nodes.EchoNodes.stats`)."""
        if self.nodes is not None:  # zeros until each node's first counters arrive
            merged: dict[str, Any] = dict.fromkeys(
                ("pings_received", "echoes_published", "pings_waiting_tick",
                 *EMISSION_COUNTERS, *ECHO_COUNTERS.values()), 0)
            merged.update(self.nodes.stats())
            return merged
        echo = self.service.stats() if self.service is not None else {}
        with self._lock:
            out: dict[str, Any] = dict(self._c)
            out["last_echo_error"] = self._last_error
            out["echo_worker"] = self.worker
            out["ping_echo_ms"] = list(self._ping_echo_ms)
        out.update(self.emission.stats())
        for key, name in ECHO_COUNTERS.items():
            out[name] = int(echo.get(key, 0))
        out["echo_compute_ms"] = echo.get("compute_ms", [])
        return out

    # ------------------------------------------------------------------ pings and echoes

    def _make_ping_callback(self, sonar_id: int) -> Any:
        def on_ping(msg: SonarPing) -> None:
            self._on_ping(sonar_id, msg)

        return on_ping

    def _on_ping(self, sonar_id: int, msg: SonarPing) -> None:
        """Ask for the ping's pose at emission (bus thread); :meth:`_answer` queues it."""
        t_recv = time.monotonic()
        with self._lock:
            self._c["pings_received"] += 1
        now = self._now_ns()
        if not self._gate.on_ping(sonar_id, int(msg.stamp_ns), int(msg.next_ns)):
            return
        if self.service is None:
            self._gate.echo_done(sonar_id)
            return
        emit = int(msg.stamp_ns) if msg.stamp_ns > 0 else now
        deadline = None
        if msg.next_ns > msg.stamp_ns > 0 and self._clock.mode == "realtime":
            # a head on sim time says when its next ping is due
            deadline = t_recv + (msg.next_ns - msg.stamp_ns) / 1e9 / self._clock.rate
        self.emission.request(self._mounts[sonar_id][0], emit, (sonar_id, msg, deadline), t_recv)

    def _answer(self, payload: Any, pose: VehiclePose, received: float) -> None:
        """Queue a ping at its sonar's world pose and velocity (the vehicle's ``pose`` at
        emission composed with the mount; the mount's offset adds the turn's lever arm)."""
        sonar_id, msg, deadline = payload
        _, offset, rotation = self._mounts[sonar_id]
        position, orientation = pose_compose(pose.position, pose.orientation, offset, rotation)
        velocity = pose.velocity + quat_rotate(pose.orientation, cross(pose.rates, offset))
        assert self.service is not None  # only pings for a service are asked for
        self.service.submit(EchoRequest(
            sonar_id, msg, SonarPose(pose.t_ns, position, orientation, velocity), received,
            deadline))

    def _publish_echo(self, req: EchoRequest, out: EchoResult) -> None:
        msg = SonarEcho(
            stamp_ns=self._now_ns(), ping_seq=int(req.ping.ping_seq), fs=out.fs,
            samples=out.samples, leaves_in_beam=out.leaves_in_beam, fidelity=out.fidelity,
            sonar_id=req.sonar_id, dropped=out.dropped, error_bound=out.error_bound,
            compute_ns=out.compute_ns, position=req.pose.position,
            orientation=req.pose.orientation, boresight=out.boresight, emit_ns=req.pose.t_ns,
            boresight_body=quat_rotate(self._mounts[req.sonar_id][2], direction_from_az_el(
                float(req.ping.az), float(req.ping.el))),
        )
        self._pubs[f"/sonar/{req.sonar_id}/echo"].publish(msg)
        self._gate.echo_done(req.sonar_id)
        t2 = time.monotonic()
        with self._lock:
            self._c["echoes_published"] += 1
            self._ping_echo_ms.append((t2 - req.received) * 1e3)

    def _pose_failed(self, payload: Any, error: str) -> None:
        """A held ping whose pose could not be found: no echo comes, so nothing (a lockstep
        gate, a run that ends once every ping is answered) waits for one."""
        sonar_id, msg, _ = payload
        self._gate.echo_done(sonar_id)
        with self._lock:
            self._last_error = f"ping {msg.ping_seq} of sonar {sonar_id}: {error}"

    def _echo_failed(self, req: EchoRequest, error: str) -> None:
        self._gate.echo_done(req.sonar_id)
        with self._lock:
            self._last_error = f"ping {req.ping.ping_seq} of sonar {req.sonar_id}: {error}"
        log.warning("%s: %s", self.name, self._last_error)

    # ------------------------------------------------------------------ where the sonars go

    def points_request(self, first: FleetStates) -> tuple[tuple[Region, ...], int]:
        """Balls along each sonar's route (a path vehicle's whole path, sampled every half
        query radius; any other vehicle's start), the routes interleaved, for the latched
        ``/forest/points``."""
        index = {vid: k for k, vid in enumerate(first.ids)}
        routes: list[list[Region]] = []
        for sonar in self._sonar_specs:
            r = self.scene.query_radius_m(sonar.id)
            traj = self.scene.trajectories.get(sonar.mount) if self._vehicle_specs else None
            if traj is not None:
                xyz = traj.xyz
                arc = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(xyz, axis=0),
                                                                      axis=1))])
                keep = np.searchsorted(arc, np.arange(0.0, arc[-1] + 1e-9, r / 2.0))
                pts = xyz[np.unique(np.minimum(keep, len(xyz) - 1))]
            else:
                pts = first.position[index[sonar.mount]][None]
            routes.append([((float(p[0]), float(p[1]), float(p[2])), r) for p in pts])
        regions = [route[k] for k in range(max(map(len, routes), default=0))
                   for route in routes if k < len(route)]
        return tuple(regions), self._params.forest_points

    def lookahead(self) -> list[Region]:
        """Where each sonar will be over the next LOOKAHEAD_HORIZON_S s of wall time (its
        path, for a vehicle on one; else straight on at its velocity), soonest first."""
        rate = self._clock.rate if self._clock.mode == "realtime" else 1.0
        steps = round(LOOKAHEAD_HORIZON_S * LOOKAHEAD_STEPS)
        taus = np.linspace(0.0, LOOKAHEAD_HORIZON_S * rate, steps + 1)
        per_sonar: list[list[Region]] = []
        for sonar in self._sonar_specs:
            latest = self.history.latest(sonar.mount)
            if latest is None:
                continue
            t_ns, p, v = latest
            vehicle = self._vehicle_specs.get(sonar.mount)
            if vehicle is not None and not vehicle.commanded:
                s = self.scene.trajectories[sonar.mount].sample(t_ns / 1e9 + taus)
                xyz = np.column_stack([s["x"], s["y"], s["z"]])
            else:
                xyz = p[None, :] + taus[:, None] * v[None, :]
            r = self.scene.query_radius_m(sonar.id)
            per_sonar.append([((float(a), float(b), float(c)), r) for a, b, c in xyz])
        return [regions[k] for k in range(steps + 1) for regions in per_sonar]

    def _publish_points(self, points: Any, radii: Any) -> None:
        """Leaf centres as one latched PointCloud (intensity = leaf radius, m), stamped 0 like
        ``/thermals``: it describes the scene, not a moment of it."""
        self._pubs["/forest/points"].publish(PointCloud(
            stamp_ns=0, points=points, intensity=radii, label="leaves"))
