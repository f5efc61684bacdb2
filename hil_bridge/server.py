"""The simulation server: a launchable node that owns a Scene and the sim clock.

Topics (ids are the scene's vehicle/glider/sonar ids)::

    publishes  /clock                     every tick
               /glider/<id>/state         every tick, for every swarm glider and path vehicle
               /glider/<id>/neighbors     after every physics step, only for registered gliders
               /sonar/<id>/echo           one per answered /sonar/<id>/ping (frame_id
                                          ``glider/<mount id>``: the vehicle carrying it)
               /thermals                  latched ThermalMarkers (with a swarm)
               /forest/points             latched PointCloud of leaves around the sonars
               /diagnostics               every ``diagnostics_period_s`` of wall time
    subscribes /glider/<id>/cmd           bank_cmd (rad), airspeed_cmd (m/s)
               /sonar/<id>/ping           ping_seq, az, el (rad, body frame), beamwidth (rad)

**Registration.** A glider's autopilot registers by publishing on ``/glider/<id>/cmd`` (its first
command, even a rejected one, registers it) or by being listed in the ``autopilots`` parameter.
Only registered gliders get ``/neighbors`` and, in ``lockstep`` mode, are waited for. Gliders
without an autopilot fly the law's Boids controller (``SwarmSim.step`` with an external-command
mask).

**Commands.** A command is *rejected* (counted, the last good one held) if a value is non-finite,
``|bank_cmd| >= pi/2`` or ``airspeed_cmd`` is outside (0, 3 * forwardSpeedMax]; otherwise it is
clipped to the law's bank and speed limits (counted in ``cmd_clipped``) and held until the next
good one. The law's optional ``bankRateMax``/``speedRateMax`` rate limits are applied by the
swarm's stepping. Commands for path vehicles are counted in ``cmd_ignored``.

**Echoes.** Each ping is answered at the pose of its sonar's vehicle when the ping *arrives*
(the latest published state), with the beam boresight at world azimuth ``heading + az`` and
elevation ``el`` (bank and pitch are not applied). Pings wait in a bounded queue (``echo_queue``;
when full the oldest waiting ping is dropped and counted) served by an echo thread, off the tick
loop, so a slow echo never delays the state stream (the synthesis and the k-d tree queries
release the GIL in their heavy numpy/finufft calls; ``bench/bench_server.py`` measures the state
stream with and without echoes). ``echo_worker: process`` instead hands each ping to a spawned
worker process holding its own copy of the scene and tile cache, for scenes whose tile building
or fidelity holds the GIL for long; the launching script must then be import-safe (an
``if __name__ == "__main__"`` guard, as ``echoloop`` has).

**Time.** The server ticks at ``state_rate_hz`` of sim time. The swarm steps every ``law.dt`` of
sim time (zero-order hold of its state between steps); path vehicles are sampled at each tick.
Clock modes: ``realtime`` (ticks paced to the wall clock times ``rate``), ``fast`` (unpaced),
``lockstep`` (after each tick, :class:`hil_bridge.lockstep.LockstepGate` holds the server until
the registered autopilots answered their state steps and the sonar heads that ping on sim time
sent their due pings; ``/clock`` says ``lockstep`` so adapters drive their devices on sim
time). Within a tick, neighbour lists are published before the states of the same step. Stamps
are integer sim nanoseconds and never decrease.
"""

from __future__ import annotations

import functools
import logging
import math
import multiprocessing
import os
import queue
import signal
import threading
import time
from collections import deque
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Literal

import numpy as np

from hil_bridge.errors import HilError
from hil_bridge.lockstep import LockstepGate
from hil_bridge.logs import load_trajectory
from hil_bridge.messages import (
    Clock,
    Diagnostics,
    GliderCmd,
    GliderNeighbors,
    GliderState,
    PointCloud,
    SonarEcho,
    SonarPing,
    ThermalMarkers,
)
from sim_core.config import ConfigError, from_dict
from sim_core.scene import ClockSpec, Scene, load_scene

__all__ = ["ServerParams", "SimServer", "percentiles"]

log = logging.getLogger(__name__)


def percentiles(values: Sequence[float]) -> dict[str, float]:
    """``{"n", "p50", "p90", "p99", "max"}`` of ``values`` (NaN percentiles when empty)."""
    if not values:
        return {"n": 0, "p50": math.nan, "p90": math.nan, "p99": math.nan, "max": math.nan}
    a = np.asarray(values, dtype=np.float64)
    p50, p90, p99 = np.percentile(a, [50, 90, 99])
    return {"n": int(a.size), "p50": float(p50), "p90": float(p90), "p99": float(p99),
            "max": float(a.max())}


@dataclass(frozen=True, slots=True)
class ServerParams:
    """Validated parameters of :class:`SimServer` (launch ``params``)."""

    scene: Any
    clock: ClockSpec | None = None
    state_rate_hz: float | None = None
    embed_proxy: bool = True
    autopilots: tuple[int, ...] = ()
    sonar_heads: tuple[int, ...] = ()
    echo_queue: int = 4
    diagnostics_period_s: float = 1.0
    stop_after_s: float | None = None
    publish_thermals: bool = True
    forest_points: int = 20000
    echo_worker: Literal["thread", "process"] = "thread"

    def __post_init__(self) -> None:
        if not isinstance(self.scene, str | Mapping | Path):
            raise ValueError(f"scene: expected a YAML path or a mapping, got {self.scene!r}")
        if self.forest_points < 0:
            raise ValueError(f"forest_points: expected >= 0, got {self.forest_points}")
        if self.echo_queue < 1:
            raise ValueError(f"echo_queue: expected >= 1, got {self.echo_queue}")
        if not self.diagnostics_period_s > 0:
            raise ValueError(f"diagnostics_period_s: expected > 0, got {self.diagnostics_period_s}")
        if self.stop_after_s is not None and not self.stop_after_s > 0:
            raise ValueError(f"stop_after_s: expected > 0, got {self.stop_after_s}")
        if self.state_rate_hz is not None and not 0 < self.state_rate_hz <= 2000:
            raise ValueError(f"state_rate_hz: expected 0 < rate <= 2000, got {self.state_rate_hz}")


_REJECT_BANK = math.pi / 2


def _job_echo(
    scene: Scene, position: tuple[float, float, float], sonar_id: int, az_world: float,
    el: float, beamwidth: float,
) -> dict[str, Any]:
    """Echo of sonar ``sonar_id`` at ``position`` (m) with a world-frame beam (rad)."""
    from sim_core.sonar import Beam, synthesize

    t0 = time.monotonic()
    p = np.asarray(position, dtype=np.float64)
    beam = Beam.from_az_el(p, az_world, el, beamwidth)
    leaves = scene.leaves_near(p, scene.query_radius_m(sonar_id))
    echo = synthesize(leaves, beam, scene.echo_params(sonar_id),
                      fidelity=scene.sonar(sonar_id).fidelity)
    bound = echo.error_bound
    return {
        "samples": np.asarray(echo.samples, dtype=np.float32), "fs": float(echo.fs),
        "leaves_in_beam": int(echo.leaves_in_beam), "fidelity": str(echo.fidelity),
        "dropped": int(echo.dropped), "error_bound": math.nan if bound is None else float(bound),
        "compute_ns": int((time.monotonic() - t0) * 1e9),
    }


def _job_points(
    scene: Scene, regions: tuple[tuple[tuple[float, float, float], float], ...], limit: int
) -> dict[str, Any]:
    """Leaf centres (N, 3) and radii (N,) within the (centre, radius m) ``regions``, evenly
    decimated to at most ``limit``."""
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
    return {"points": c, "radii": rr}


_WORKER_JOBS: dict[str, Any] = {"echo": _job_echo, "points": _job_points}


def _echo_process_main(spec: Any, requests: Any, responses: Any) -> None:
    """Body of the echo worker process: its own Scene (and forest tile cache), one job at a
    time; exits on ``None`` or when its parent is gone."""
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
            responses.put((key, _WORKER_JOBS[kind](scene, *args), ""))
        except ValueError as exc:
            responses.put((key, None, str(exc)))


class _EchoProcess:
    """A spawned worker process computing echoes, so heavy numpy/tile work never holds the
    GIL of the process that runs the state stream. ``call`` blocks until its result."""

    def __init__(self, spec: Any, stop: threading.Event) -> None:
        ctx = multiprocessing.get_context("spawn")
        self._requests: Any = ctx.Queue()
        self._responses: Any = ctx.Queue()
        self._proc = ctx.Process(
            target=_echo_process_main, args=(spec, self._requests, self._responses),
            name="echoloop-echo", daemon=True,
        )
        self._proc.start()
        self._key = 0
        self._closing = stop

    def call(self, kind: str, args: tuple[Any, ...]) -> Any:
        """Run job ``kind`` in the worker; None when closing; HilError if the worker died."""
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


class SimServer:
    """Launchable simulation server (see the module docstring for topics and semantics).

    ``SimServer(name, *, bus, scene, clock=None, state_rate_hz=None, embed_proxy=True,
    autopilots=(), echo_queue=4, diagnostics_period_s=1.0, stop_after_s=None,
    publish_thermals=True, forest_points=20000, echo_worker="thread")``. ``scene`` is a
    scene YAML path or mapping (:mod:`sim_core.scene`); ``clock`` and ``state_rate_hz``
    override the scene's.
    ``stop_after_s``: stop ticking at that sim time (the node keeps answering pings).
    ``forest_points``: at most this many leaf centres around each sonar's route are published
    once (latched) on ``/forest/points`` for viewers and plots (0: none).
    """

    def __init__(self, name: str, *, bus: str, **params: Any) -> None:
        self.name = name
        self.bus = bus
        self.params = from_dict(ServerParams, params, path=f"{name}.params")
        scene_src = self.params.scene
        self.scene: Scene = load_scene(
            str(scene_src) if isinstance(scene_src, Path) else scene_src,
            trajectory_reader=load_trajectory,
        )
        spec = self.scene.spec
        self.clock_spec: ClockSpec = self.params.clock or spec.clock
        self.state_rate_hz = float(self.params.state_rate_hz or spec.state_rate_hz)
        self.tick_ns = round(1e9 / self.state_rate_hz)
        self._lock = threading.Lock()
        self._stop = threading.Event()
        self._done = threading.Event()
        self._threads: list[threading.Thread] = []
        self._started = False
        self._stopped = False
        self._c: dict[str, int] = dict.fromkeys(
            (
                "ticks", "physics_steps", "states_published", "neighbors_published",
                "clock_published", "cmd_received", "cmd_applied", "cmd_rejected", "cmd_clipped",
                "cmd_ignored", "pings_received", "pings_dropped",
                "echoes_published", "echo_errors", "late_ticks", "diagnostics_published",
                "external_steps",
            ),
            0,
        )
        self._ping_echo_ms: deque[float] = deque(maxlen=10000)
        self._echo_compute_ms: deque[float] = deque(maxlen=10000)
        self._sim_ns = 0
        self._last_echo_error = ""
        self._tick_error = ""
        self._flown_gliders: dict[int, dict[str, Any]] = {}
        # glider index (swarm) by id; path vehicles by id
        self._glider_index = {gid: i for i, gid in enumerate(self.scene.glider_ids)}
        self._vehicle_ids = set(self.scene.vehicle_ids)
        self._vehicle_specs = {v.id: v for v in spec.vehicles}
        #: vehicles under autopilot command: id -> [x, y, z, heading, bank, speed]
        self._flown: dict[int, list[float]] = {}
        self._vstates: dict[int, dict[str, float]] = {}
        self._poses: dict[int, tuple[float, float, float, float]] = {}
        self._registered: set[int] = {int(a) for a in self.params.autopilots}
        unknown = sorted(self._registered - set(self._glider_index) - self._vehicle_ids)
        if unknown:
            raise ConfigError(f"{name}.params.autopilots: unknown glider id(s) {unknown}")
        sonar_ids = {s.id for s in spec.sonars}
        bad_heads = sorted(set(self.params.sonar_heads) - sonar_ids)
        if bad_heads:
            raise ConfigError(f"{name}.params.sonar_heads: unknown sonar id(s) {bad_heads}")
        clock = self.clock_spec
        self._gate = LockstepGate(
            lockstep=clock.mode == "lockstep", timeout_s=clock.lockstep_timeout_s,
            max_stalls=clock.lockstep_max_stalls, start_timeout_s=clock.lockstep_start_timeout_s,
            autopilots=self._registered, sonars=self.params.sonar_heads,
        )
        self._good_cmd: dict[int, tuple[float, float]] = {}
        self._pings: queue.Queue[tuple[int, SonarPing, tuple[float, float, float, float], float]]
        self._pings = queue.Queue(maxsize=self.params.echo_queue)
        self._node: Any = None
        self._proxy: Any = None
        self._pubs: dict[str, Any] = {}

    # ------------------------------------------------------------------ launchable contract

    def start(self) -> None:
        """Start the proxy (if embedded), the node, the tick loop and the echo worker."""
        if self._started:
            return
        self._started = True
        from hil_bridge.clock import SimClock
        from hil_bridge.node import Node
        from hil_bridge.qos import COMMAND, LATCHED, SENSOR

        if self.params.embed_proxy:
            from hil_bridge.proxy import proxy_for

            self._proxy = proxy_for(self.bus)
            if self._proxy is not None:
                self._proxy.start()
        # The server steps the clock itself (it paces realtime ticks against the wall clock).
        self.clock = SimClock("lockstep" if self.clock_spec.mode == "lockstep" else "fast")
        self._node = Node(self.name, bus=self.bus, clock=self.clock, diagnostics_period_s=0)
        node = self._node
        self._pubs["/clock"] = node.create_publisher(Clock, "/clock", qos=SENSOR)
        self._pubs["/diagnostics"] = node.create_publisher(Diagnostics, "/diagnostics", qos=SENSOR)
        if self.scene.spec.sonars and self.params.forest_points > 0:
            self._pubs["/forest/points"] = node.create_publisher(
                PointCloud, "/forest/points", qos=LATCHED
            )
        if self.scene.spec.swarm is not None and self.params.publish_thermals:
            self._pubs["/thermals"] = node.create_publisher(
                ThermalMarkers, "/thermals", qos=LATCHED
            )
        for gid in (*self._glider_index, *sorted(self._vehicle_ids)):
            self._pubs[f"/glider/{gid}/state"] = node.create_publisher(
                GliderState, f"/glider/{gid}/state", qos=SENSOR
            )
            node.create_subscription(
                GliderCmd, f"/glider/{gid}/cmd", self._make_cmd_callback(gid), qos=COMMAND
            )
        for gid in self._glider_index:
            self._pubs[f"/glider/{gid}/neighbors"] = node.create_publisher(
                GliderNeighbors, f"/glider/{gid}/neighbors", qos=SENSOR
            )
        for sonar in self.scene.spec.sonars:
            self._pubs[f"/sonar/{sonar.id}/echo"] = node.create_publisher(
                SonarEcho, f"/sonar/{sonar.id}/echo", qos=SENSOR,
                frame_id=f"glider/{sonar.mount}",
            )
            node.create_subscription(
                SonarPing, f"/sonar/{sonar.id}/ping", self._make_ping_callback(sonar.id),
                qos=SENSOR,
            )
        # what the tick loop and the first ping need, before any callback can run
        # (lazy parts stay lazy)
        swarm = self.scene.swarm
        if self._vehicle_ids:
            _ = self.scene.trajectories
        self._step_vehicles(0, 0.0)
        self._update_poses(None if swarm is None else swarm.state)
        node.start()
        self._threads = [
            threading.Thread(target=self._tick_loop, name=f"{self.name}-tick", daemon=True),
        ]
        if self.scene.spec.sonars:
            self._threads.append(
                threading.Thread(target=self._echo_loop, name=f"{self.name}-echo", daemon=True)
            )
        for t in self._threads:
            t.start()

    def stop(self) -> None:
        """Stop ticking and echoing, join threads, close the node and proxy (idempotent)."""
        if self._stopped:
            return
        self._stopped = True
        self._stop.set()
        self._gate.interrupt()
        for t in self._threads:
            t.join()
        if self._node is not None:
            self._node.stop()
        if self._proxy is not None:
            self._proxy.stop()

    def stats(self) -> dict[str, Any]:
        """Counters, the sim time, registered autopilots and latency percentiles (ms)."""
        with self._lock:
            out: dict[str, Any] = dict(self._c)
            out["sim_time_s"] = self._sim_ns / 1e9
            out["registered"] = sorted(self._registered)
            out["last_echo_error"] = self._last_echo_error
            out["tick_error"] = self._tick_error
            out["flown"] = {str(g): dict(v) for g, v in sorted(self._flown_gliders.items())}
            ping_echo = list(self._ping_echo_ms)
            compute = list(self._echo_compute_ms)
        out.update(self._gate.stats())
        out["clock_mode"] = self.clock_spec.mode
        out["built"] = sorted(self.scene.built)
        out["ping_echo_ms"] = percentiles(ping_echo)
        out["echo_compute_ms"] = percentiles(compute)
        if self.scene.spec.swarm is not None and "swarm" in self.scene.built:
            out["gliders_alive"] = int(np.count_nonzero(self.scene.swarm.state.alive[0]))
        return out

    def wait_done(self, timeout: float | None = None) -> bool:
        """Block until the tick loop ended (``stop_after_s`` reached or stopped)."""
        return self._done.wait(timeout)

    # ------------------------------------------------------------------ callbacks (bus thread)

    def _make_cmd_callback(self, gid: int) -> Any:
        def on_cmd(msg: GliderCmd) -> None:
            self._on_cmd(gid, msg)

        return on_cmd

    def _make_ping_callback(self, sonar_id: int) -> Any:
        def on_ping(msg: SonarPing) -> None:
            self._on_ping(sonar_id, msg)

        return on_ping

    def _on_cmd(self, gid: int, msg: GliderCmd) -> None:
        with self._lock:
            self._c["cmd_received"] += 1
            vehicle = self._vehicle_specs.get(gid)
            if vehicle is not None and not vehicle.commanded:
                self._c["cmd_ignored"] += 1
                return
            self._registered.add(gid)
            checked = self._check_cmd(gid, msg.bank_cmd, msg.airspeed_cmd)
            if checked is None:
                self._c["cmd_rejected"] += 1
            else:
                bank, speed, clipped = checked
                self._good_cmd[gid] = (bank, speed)
                self._c["cmd_applied"] += 1
                self._c["cmd_clipped"] += int(clipped)
        self._gate.on_cmd(gid, int(msg.step))

    def _check_cmd(self, gid: int, bank: float, speed: float) -> tuple[float, float, bool] | None:
        """Reject (None) or clip a command to glider/vehicle ``gid``'s envelope."""
        vehicle = self._vehicle_specs.get(gid)
        if vehicle is None:
            law = self.scene.law
            bank_lo, bank_hi = float(law.bankMin), float(law.bankMax)
            v_lo, v_hi = float(law.forwardSpeedMin), float(law.forwardSpeedMax)
        else:
            bank_lo, bank_hi = -vehicle.bank_max_rad, vehicle.bank_max_rad
            v_lo, v_hi = vehicle.speed_min_mps, vehicle.speed_max_mps
        b, v = float(bank), float(speed)
        if not (math.isfinite(b) and math.isfinite(v)):
            return None
        if abs(b) >= _REJECT_BANK or not 0 < v <= 3 * v_hi:
            return None
        bc = min(max(b, bank_lo), bank_hi)
        vc = min(max(v, v_lo), v_hi)
        return bc, vc, (bc != b or vc != v)

    def _on_ping(self, sonar_id: int, msg: SonarPing) -> None:
        t_recv = time.monotonic()
        mount = self.scene.sonar(sonar_id).mount
        with self._lock:
            self._c["pings_received"] += 1
            pose = self._poses[mount]
        item = (sonar_id, msg, pose, t_recv)
        if not self._gate.on_ping(sonar_id, int(msg.stamp_ns), int(msg.next_ns)):
            return
        while True:
            try:
                self._pings.put_nowait(item)
                return
            except queue.Full:
                try:
                    dropped = self._pings.get_nowait()
                except queue.Empty:
                    continue
                self._gate.echo_done(dropped[0])
                with self._lock:
                    self._c["pings_dropped"] += 1

    # ------------------------------------------------------------------ echo worker

    def _echo_loop(self) -> None:
        """Echo thread: publish the forest points, then answer pings one at a time, computing
        in the worker process (``echo_worker: process``) or in this thread."""
        worker: _EchoProcess | None = None
        try:
            if self.params.echo_worker == "process":
                worker = _EchoProcess(self.scene.spec, self._stop)
                compute = worker.call
            else:
                scene = self.scene

                def compute(kind: str, args: tuple[Any, ...]) -> Any:
                    return _WORKER_JOBS[kind](scene, *args)

            self._publish_forest_points(compute)
            while not self._stop.is_set():
                try:
                    sonar_id, ping, pose, t_recv = self._pings.get(timeout=0.05)
                except queue.Empty:
                    continue
                try:
                    self._answer_ping(compute, sonar_id, ping, pose, t_recv)
                finally:
                    self._gate.echo_done(sonar_id)
        finally:
            if worker is not None:
                worker.close()

    def _answer_ping(
        self, compute: Any, sonar_id: int, ping: SonarPing,
        pose: tuple[float, float, float, float], t_recv: float,
    ) -> None:
        x, y, z, heading = pose
        args = ((x, y, z), sonar_id, heading + float(ping.az), float(ping.el),
                float(ping.beamwidth))
        try:
            out = compute("echo", args)
        except (ValueError, HilError) as exc:
            with self._lock:
                self._c["echo_errors"] += 1
                self._last_echo_error = f"ping {ping.ping_seq} of sonar {sonar_id}: {exc}"
            log.warning("%s: %s", self.name, self._last_echo_error)
            return
        if out is None:  # stopping
            return
        msg = SonarEcho(
            stamp_ns=self._now_ns(),
            ping_seq=int(ping.ping_seq),
            fs=out["fs"],
            samples=out["samples"],
            leaves_in_beam=out["leaves_in_beam"],
            fidelity=out["fidelity"],
            sonar_id=sonar_id,
            dropped=out["dropped"],
            error_bound=out["error_bound"],
            compute_ns=out["compute_ns"],
        )
        self._pubs[f"/sonar/{sonar_id}/echo"].publish(msg)
        t2 = time.monotonic()
        with self._lock:
            self._c["echoes_published"] += 1
            self._echo_compute_ms.append(out["compute_ns"] / 1e6)
            self._ping_echo_ms.append((t2 - t_recv) * 1e3)

    # ------------------------------------------------------------------ tick loop

    def _now_ns(self) -> int:
        with self._lock:
            return self._sim_ns

    def _update_poses(self, st: Any) -> None:
        """Refresh ``_poses`` (id -> x, y, z, heading) from the swarm state and the paths."""
        poses: dict[int, tuple[float, float, float, float]] = {}
        if st is not None:
            for gid, i in self._glider_index.items():
                poses[gid] = (
                    float(st.x[0, i]), float(st.y[0, i]), float(st.z[0, i]),
                    float(st.heading[0, i]),
                )
        for vid, vs in self._vstates.items():
            poses[vid] = (vs["x"], vs["y"], vs["z"], vs["heading"])
        with self._lock:
            self._poses = poses

    def _step_vehicles(self, t_ns: int, dt_s: float) -> None:
        """Vehicle states at ``t_ns``: path samples, or unicycle flight on the held command."""
        from sim_core.scene import unicycle_step

        states: dict[int, dict[str, float]] = {}
        if not self._vehicle_ids:
            return
        t_s = t_ns / 1e9
        with self._lock:
            cmds = {v: self._good_cmd[v] for v in self._vehicle_ids if v in self._good_cmd}
        for vid, traj in self.scene.trajectories.items():
            flown = self._flown.get(vid)
            if flown is None and vid in cmds:
                s = traj.sample(t_s)
                flown = [float(s[k]) for k in ("x", "y", "z", "heading", "bank", "airspeed")]
                self._flown[vid] = flown
                dt_s = 0.0
            if flown is None:
                s = traj.sample(t_s)
                states[vid] = {k: float(v) for k, v in s.items()}
                continue
            bank, speed = cmds[vid]
            if dt_s > 0:
                nx, ny, nh = unicycle_step(
                    np.array([flown[0]]), np.array([flown[1]]), np.array([flown[3]]),
                    np.array([flown[4]]), np.array([flown[5]]), dt=dt_s,
                )
                flown[0], flown[1], flown[3] = float(nx[0]), float(ny[0]), float(nh[0])
            flown[4], flown[5] = bank, speed
            states[vid] = {"x": flown[0], "y": flown[1], "z": flown[2], "heading": flown[3],
                           "bank": bank, "airspeed": speed, "vz": 0.0}
        self._vstates = states

    def _commands_for_step(self) -> Any:
        """The held good commands as :class:`sim_core.soaring.Commands`, or None if none."""
        from sim_core.soaring import Commands

        n = self.scene.swarm.state.x.shape[1]
        bank = np.zeros((1, n))
        speed = np.zeros((1, n))
        mask = np.zeros((1, n), dtype=bool)
        with self._lock:
            for gid, (b, v) in self._good_cmd.items():
                i = self._glider_index.get(gid)
                if i is not None:
                    bank[0, i], speed[0, i], mask[0, i] = b, v, True
        if not mask.any():
            return None
        return Commands(bank_cmd=bank, airspeed_cmd=speed, mask=mask)

    def _record_flown(self, commands: Any) -> None:
        """Per externally commanded glider: the command of the last step and the state it gave."""
        st = self.scene.swarm.state
        flown: dict[int, dict[str, Any]] = {}
        for gid, i in self._glider_index.items():
            if commands.mask[0, i]:
                flown[gid] = {
                    "step": int(self.scene.swarm.step_count),
                    "bank_cmd": float(commands.bank_cmd[0, i]), "bank": float(st.bank[0, i]),
                    "airspeed_cmd": float(commands.airspeed_cmd[0, i]),
                    "airspeed": float(st.speed[0, i]), "alive": bool(st.alive[0, i]),
                }
        with self._lock:
            self._c["external_steps"] += len(flown)
            self._flown_gliders.update(flown)

    def _publish_tick(self, t_ns: int, st: Any, physics_stepped: bool, tick: int) -> None:
        """/clock, then the neighbour lists of a new physics step, then every state (so a
        consumer acting on a state already has the neighbours of the same step)."""
        pubs = self._pubs
        lockstep = self.clock_spec.mode == "lockstep"
        pubs["/clock"].publish(Clock(stamp_ns=t_ns, lockstep=lockstep))
        n_states = 0
        if st is not None:
            step = int(self.scene.swarm.step_count)
            if physics_stepped:
                self._publish_neighbors(t_ns, st, step)
            for gid, i in self._glider_index.items():
                alive = bool(st.alive[0, i])
                pubs[f"/glider/{gid}/state"].publish(GliderState(
                    stamp_ns=t_ns, x=float(st.x[0, i]), y=float(st.y[0, i]),
                    z=float(st.z[0, i]), heading=float(st.heading[0, i]),
                    bank=float(st.bank[0, i]), airspeed=float(st.speed[0, i]),
                    vz=float(st.vz[0, i]), alive=alive, glider_id=gid, step=step,
                ))
                self._gate.published(gid, step, alive=alive, every_tick=False)
                n_states += 1
        for vid, vs in self._vstates.items():
            pubs[f"/glider/{vid}/state"].publish(GliderState(
                stamp_ns=t_ns, x=vs["x"], y=vs["y"], z=vs["z"], heading=vs["heading"],
                bank=vs["bank"], airspeed=vs["airspeed"], vz=vs["vz"], alive=True,
                glider_id=vid, step=tick,
            ))
            self._gate.published(vid, tick, alive=True, every_tick=True)
            n_states += 1
        with self._lock:
            self._c["clock_published"] += 1
            self._c["states_published"] += n_states

    def _publish_neighbors(self, t_ns: int, st: Any, step: int) -> None:
        with self._lock:
            targets = sorted(g for g in self._registered if g in self._glider_index)
        if not targets:
            return
        swarm = self.scene.swarm
        gids = np.array(list(self._glider_index), dtype=np.int32)
        for gid in targets:
            idx = np.asarray(swarm.neighbors(self._glider_index[gid]), dtype=np.intp)
            self._pubs[f"/glider/{gid}/neighbors"].publish(GliderNeighbors(
                stamp_ns=t_ns, glider_id=gid, ids=gids[idx], x=st.x[0, idx], y=st.y[0, idx],
                z=st.z[0, idx], heading=st.heading[0, idx], bank=st.bank[0, idx],
                airspeed=st.speed[0, idx], vz=st.vz[0, idx], step=step,
            ))
        with self._lock:
            self._c["neighbors_published"] += len(targets)

    def _publish_thermals(self, t_ns: int) -> None:
        if "/thermals" not in self._pubs:
            return
        th = self.scene.swarm.thermals
        ok = th.valid[0]
        self._pubs["/thermals"].publish(ThermalMarkers(
            stamp_ns=t_ns, x=th.x[0, ok], y=th.y[0, ok], radius=th.radius[0, ok],
            w_max=th.w_max[0, ok],
        ))

    def _publish_forest_points(self, compute: Any) -> None:
        """Leaf centres around each sonar's mount (its path's extent, or its start), decimated
        evenly to ``forest_points``, as one latched PointCloud (intensity = leaf radius, m),
        stamped 0 like ``/thermals``: it describes the scene, not a moment of it."""
        pub = self._pubs.get("/forest/points")
        if pub is None:
            return
        regions: list[tuple[tuple[float, float, float], float]] = []
        for sonar in self.scene.spec.sonars:
            r = self.scene.query_radius_m(sonar.id)
            traj = self.scene.trajectories.get(sonar.mount) if self._vehicle_ids else None
            if traj is not None:
                lo, hi = traj.xyz.min(axis=0), traj.xyz.max(axis=0)
                c = (lo + hi) / 2.0
                r += float(np.linalg.norm(hi - lo)) / 2.0
                regions.append(((float(c[0]), float(c[1]), float(c[2])), r))
            else:
                x, y, z, _ = self._poses[sonar.mount]
                regions.append(((x, y, z), r))
        try:
            out = compute("points", (tuple(regions), self.params.forest_points))
        except (ValueError, HilError) as exc:
            log.warning("%s: no forest points: %s", self.name, exc)
            return
        if out is not None:
            pub.publish(PointCloud(stamp_ns=0, points=out["points"],
                                   intensity=out["radii"], label="leaves"))

    def _publish_diagnostics(self, t_ns: int) -> None:
        stats = self.stats()
        counters: dict[str, int | float] = {
            k: v for k, v in stats.items() if isinstance(v, int | float) and not isinstance(v, bool)
        }
        for key in ("ping_echo_ms", "echo_compute_ms"):
            for p in ("p50", "p99"):
                val = stats[key][p]
                if math.isfinite(val):
                    counters[f"{key}_{p}"] = val
        node = self._node.stats()
        for key in ("sent", "received", "dropped", "decode_errors", "callback_errors"):
            counters[f"bus_{key}"] = int(node[key])
        self._pubs["/diagnostics"].publish(
            Diagnostics(stamp_ns=t_ns, node=self.name, counters=counters)
        )
        with self._lock:
            self._c["diagnostics_published"] += 1

    def _tick_loop(self) -> None:
        try:
            self._run_ticks()
        except Exception as exc:  # a bug must not vanish with its thread: report it in stats
            log.exception("%s: tick loop failed", self.name)
            with self._lock:
                self._tick_error = f"{type(exc).__name__}: {exc}"
        finally:
            self._done.set()

    def _run_ticks(self) -> None:
        mode: Literal["realtime", "lockstep", "fast"] = self.clock_spec.mode
        swarm = self.scene.swarm
        phys_ns = round(float(self.scene.law.dt) * 1e9) if swarm is not None else 0
        stop_s = self.params.stop_after_s
        stop_ns = None if stop_s is None else round(stop_s * 1e9)
        wall0 = time.monotonic()
        next_diag = wall0
        tick = 0
        last: tuple[int, Any, bool, int] | None = None
        if swarm is not None:
            self._publish_thermals(0)
        while not self._stop.is_set():
            t_ns = tick * self.tick_ns
            if stop_ns is not None and t_ns > stop_ns:
                break
            if mode == "lockstep" and last is not None:
                self._gate.wait(
                    last[0], resend=functools.partial(self._publish_tick, *last),
                    physics_due=swarm is not None and (swarm.step_count + 1) * phys_ns <= t_ns,
                )
                if self._stop.is_set():
                    return
            stepped = False
            if swarm is not None:
                while (swarm.step_count + 1) * phys_ns <= t_ns:
                    commands = self._commands_for_step()
                    swarm.step(commands)
                    with self._lock:
                        self._c["physics_steps"] += 1
                    if commands is not None:
                        self._record_flown(commands)
                    stepped = True
            st = swarm.state if swarm is not None else None
            with self._lock:
                self._sim_ns = max(self._sim_ns, t_ns)
            if t_ns > self.clock.now_ns():
                self.clock.set_ns(t_ns)
            self._step_vehicles(t_ns, self.tick_ns / 1e9 if tick > 0 else 0.0)
            self._update_poses(st)
            self._publish_tick(t_ns, st, stepped, tick)
            last = (t_ns, st, stepped, tick)
            with self._lock:
                self._c["ticks"] += 1
            tick += 1
            now = time.monotonic()
            if now >= next_diag:
                self._publish_diagnostics(t_ns)
                next_diag = now + self.params.diagnostics_period_s
            if mode == "realtime":
                target = wall0 + (tick * self.tick_ns / 1e9) / self.clock_spec.rate
                remaining = target - time.monotonic()
                if remaining > 0:
                    self._stop.wait(remaining)
                elif remaining < -self.tick_ns / 1e9:
                    with self._lock:
                        self._c["late_ticks"] += 1
