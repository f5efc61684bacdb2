"""The simulation server: a launchable node that owns a Scene and the sim clock.

Topics (ids are the scene's vehicle/glider/sonar ids)::

    publishes  /clock                     every tick
               /glider/<id>/state         every tick, for every swarm glider and vehicle
               /glider/<id>/neighbors     after every control step, only for registered gliders
               /sonar/<id>/echo           one per answered /sonar/<id>/ping (frame_id
                                          ``glider/<mount id>``: the vehicle carrying it)
               /thermals                  latched ThermalMarkers (with a swarm)
               /forest/points             latched PointCloud of leaves around the sonars
               /diagnostics               every ``diagnostics_period_s`` of wall time
               /glider/<id>/fdm           every tick, for every 6-DoF vehicle (its sensors' truth)
    subscribes /glider/<id>/cmd           bank_cmd (rad), airspeed_cmd (m/s)
               /glider/<id>/surfaces      a 6-DoF vehicle's control surfaces
               /sonar/<id>/ping           ping_seq, az, el (rad, sonar frame), beamwidth (rad)

**Flight** (:mod:`hil_bridge.server.fleet`). Every tick is a new physics state: the vehicles are
integrated from the previous tick (``physics_rate_hz`` sets the sub-steps) on the commands held
when the tick starts, so a command received before tick k is flown in the state of tick k.
Swarm gliders fly :mod:`sim_core.flight`; those without an autopilot follow the law's Boids
controller, which decides every ``law.dt`` (its commands held in between); commanded vehicles
fly the same model once taken over; path vehicles follow their path with the bank and pitch it
implies. Every state carries the full attitude (roll, pitch, yaw, quaternion, body rates).

**Registration.** A glider's autopilot registers by publishing on ``/glider/<id>/cmd`` (its first
command, even a rejected one, registers it) or by being listed in the ``autopilots`` parameter.
Only registered gliders get ``/neighbors`` and, in ``lockstep`` mode, are waited for.

**Commands** and a 6-DoF vehicle's control surfaces are checked, clipped, held and counted by
:class:`hil_bridge.server.commands.AutopilotInputs` (``cmd_*``, ``surfaces_*``;
``cmd_effect_ticks``: 1 when an input is in effect at the next tick, 2 when it arrived while
that tick was being computed; ``cmd_apply_ms``: its arrival to the publish of the first state
that flies it).

**Echoes**: every ping is answered at its sonar's world pose at the ping's emission, off the
tick loop, on a thread, a pool of worker processes or echo nodes, within deadlines in
``realtime`` mode: :mod:`hil_bridge.server.sonars` (its docstring says how).

**Time.** The server ticks at ``state_rate_hz`` of sim time. Clock modes: ``realtime`` (ticks
paced to the wall clock times ``rate``), ``fast`` (unpaced), ``lockstep`` (after each tick,
:class:`hil_bridge.server.lockstep.LockstepGate` holds the server until the registered autopilots
answered their state steps and the sonar heads that ping on sim time sent their due pings; a
swarm glider's answer to a control step is needed before the period it governs is flown;
``/clock`` says ``lockstep`` so adapters drive their devices on sim time). Neighbour lists
precede the states of their step. Stamps are integer sim nanoseconds and never decrease. In
``realtime`` mode the tick thread runs at ``tick_nice`` (-10) where the OS allows it
(``tick_priority`` in stats), ahead of the loop's other processes when the cores are short;
in a real-time node host (the launch file's ``realtime``, :mod:`hil_bridge.priority`) it runs
``SCHED_FIFO`` one above the server's other threads (and
leaves real time in ``fast`` and ``lockstep``, which do not sleep between ticks).
"""

from __future__ import annotations

import functools
import logging
import math
import threading
import time
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any, ClassVar, Literal

import numpy as np

from hil_bridge.bus.domain import current as current_domain
from hil_bridge.bus.faults import Faults
from hil_bridge.bus.messages import (
    Clock,
    Diagnostics,
    FdmState,
    GliderCmd,
    GliderNeighbors,
    GliderState,
    SurfaceCmd,
    ThermalMarkers,
)
from hil_bridge.bus.stats import percentiles
from hil_bridge.files.scene import load_scene
from hil_bridge.priority import can_raise, loop_priority
from hil_bridge.recording.logs import load_trajectory
from hil_bridge.server.commands import AutopilotInputs
from hil_bridge.server.echo_nodes import EchoNodes
from hil_bridge.server.echo_pool import WORKER_NICE
from hil_bridge.server.fleet import Fleet, FleetStates
from hil_bridge.server.lockstep import LockstepGate, Pacer, runs_lockstep, speed_params
from hil_bridge.server.sonars import ServerSonars
from sim_core.config import ConfigError, from_dict
from sim_core.scene import ClockSpec, Scene

__all__ = ["ServerParams", "SimServer"]


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
    echo_worker: Literal["auto", "thread", "process", "pool", "nodes"] = "auto"
    echo_workers: int | None = None
    echo_deadlines: bool = True
    echo_budget_ms: float | None = None
    pose_history_s: float = 2.0
    pose_wait_ticks: float = 2.0
    tick_nice: int = -10

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
        if not self.pose_history_s > 0:
            raise ValueError(f"pose_history_s: expected > 0, got {self.pose_history_s}")
        if not 0 <= self.pose_wait_ticks <= 100:
            raise ValueError(f"pose_wait_ticks: expected 0 <= ticks <= 100, got "
                             f"{self.pose_wait_ticks}")
        if not -20 <= self.tick_nice <= 0:
            raise ValueError(f"tick_nice: expected -20 <= nice <= 0, got {self.tick_nice}")
        if self.echo_budget_ms is not None and not self.echo_budget_ms > 0:
            raise ValueError(f"echo_budget_ms: expected > 0 or null (no budget), got "
                             f"{self.echo_budget_ms}")
        if self.echo_workers is not None and self.echo_workers < 1:
            raise ValueError(f"echo_workers: expected >= 1 or null (one per core), got "
                             f"{self.echo_workers}")


log = logging.getLogger(__name__)

#: seconds the server waits at start for its bus endpoint to know the subscriptions already
#: made (:meth:`~hil_bridge.bus.transport.base.Transport.sync`) before its first tick
BUS_SYNC_S = 10.0

_COUNTERS = (
    "ticks", "physics_steps", "control_steps", "states_published", "neighbors_published",
    "clock_published", "late_ticks", "diagnostics_published", "external_steps", "fdm_published",
)


class SimServer:
    """Launchable simulation server (see the module docstring for topics and semantics).

    ``SimServer(name, *, bus, scene, clock=None, state_rate_hz=None, embed_proxy=True,
    autopilots=(), echo_queue=4, diagnostics_period_s=1.0, stop_after_s=None,
    publish_thermals=True, forest_points=20000, echo_worker="auto", echo_workers=None,
    echo_deadlines=True, echo_budget_ms=None, pose_history_s=2.0, pose_wait_ticks=2.0,
    tick_nice=-10)``.
    ``scene`` is a scene YAML path or mapping (:mod:`sim_core.scene`); ``clock`` and
    ``state_rate_hz`` override the scene's. ``stop_after_s``: stop ticking at that sim time
    (the node keeps answering pings). ``forest_points``: at most this many leaf centres around
    the sonars' routes are published once (latched) on ``/forest/points`` for viewers and plots
    (0: none). ``pose_history_s``: how far back (or ahead of the newest tick) a ping's emission
    stamp may reach; ``pose_wait_ticks``: how long (tick periods of sim time) a ping stamped
    after the newest tick waits for the tick that covers it (0: extrapolated at once; module
    docstring, "Echoes").
    ``echo_worker``, ``echo_workers``, ``echo_deadlines``, ``echo_budget_ms``: see the module
    docstring.
    ``tick_nice``: in ``realtime`` mode the tick thread asks for this nice (-20..0; 0: as
    started), so that on short cores it preempts the other processes of the loop; where the OS
    does not allow it the thread runs on as started (:func:`hil_bridge.priority.raise_priority`).
    Stats say which as ``tick_priority``.
    """

    #: ``embed_proxy`` (default true) runs the bus's proxy in this node's process; a launch
    #: runs it itself instead (:func:`hil_bridge.launch.spec.launch_proxy`)
    EMBEDS_PROXY: ClassVar[bool] = True
    lockstep_host = staticmethod(runs_lockstep)  # hil_bridge.launch.spec.compose_lockstep
    speed_params = staticmethod(speed_params)  # hil_bridge.launch.spec.with_speed

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
        physics_hz = max(self.state_rate_hz, float(spec.physics_rate_hz or 0.0))
        self.substeps = max(1, math.ceil(physics_hz / self.state_rate_hz - 1e-9))
        self._lock = threading.Lock()
        self._stop = threading.Event()
        self._done = threading.Event()
        self._reached_end = threading.Event()
        self._threads: list[threading.Thread] = []
        self._started = False
        self._stopped = False
        self._c: dict[str, int] = dict.fromkeys(_COUNTERS, 0)
        self._sim_ns = 0
        self._tick_cpu_s = 0.0
        self._tick_wall = (0.0, 0.0)  # monotonic time of the first and of the last tick
        self._tick_error = ""
        self._tick_priority = "unchanged"
        #: what went wrong: the tick loop, bus callbacks, the echo service and its workers
        self.faults = Faults(name)
        self._flown_gliders: dict[int, dict[str, Any]] = {}
        self._glider_index = {gid: i for i, gid in enumerate(self.scene.glider_ids)}
        registered = {int(a) for a in self.params.autopilots}
        unknown = sorted(registered - set(self._glider_index) - {v.id for v in spec.vehicles})
        if unknown:
            raise ConfigError(f"{name}.params.autopilots: unknown glider id(s) {unknown}")
        bad_heads = sorted(set(self.params.sonar_heads) - {s.id for s in spec.sonars})
        if bad_heads:
            raise ConfigError(f"{name}.params.sonar_heads: unknown sonar id(s) {bad_heads}")
        clock = self.clock_spec
        self._gate = LockstepGate(
            lockstep=clock.mode == "lockstep", timeout_s=clock.lockstep_timeout_s,
            max_stalls=clock.lockstep_max_stalls, start_timeout_s=clock.lockstep_start_timeout_s,
            autopilots=registered, sonars=self.params.sonar_heads,
        )
        self._inputs = AutopilotInputs(self.scene, registered, self._ticks_now)
        self.fleet = Fleet(
            self.scene, tick_ns=self.tick_ns, substeps=self.substeps,
            history_s=self.params.pose_history_s, history_ids={s.mount for s in spec.sonars},
        )
        # echo nodes yield to the tick loop (nice WORKER_NICE) unless the tick thread will hold
        # a raised priority of its own: then they compete as equals with the other nodes (a
        # pool keeps yielding: its scheduler thread shares the tick loop's interpreter)
        self._raises_tick = (self.clock_spec.mode == "realtime" and self.params.tick_nice < 0
                             and can_raise(self.params.tick_nice))
        self._sonars = ServerSonars(
            name, self.scene, self.fleet.history, self.tick_ns, self._gate, self.clock_spec,
            self.params, self._now_ns,
            current_domain(),  # the run's: active while the launcher builds nodes
            node_nice=0 if self._raises_tick else WORKER_NICE,
        )
        self._node: Any = None
        self._proxy: Any = None
        self._pubs: dict[str, Any] = {}

    # ------------------------------------------------------------------ launchable contract

    def start(self) -> None:
        """Start the proxy (if embedded), the node, the tick loop and the echo service."""
        if self._started:
            return
        self._started = True
        from hil_bridge.bus.clock import SimClock
        from hil_bridge.bus.node import Node
        from hil_bridge.bus.qos import COMMAND, LATCHED, SENSOR

        if self.params.embed_proxy:
            from hil_bridge.bus.proxy import proxy_for

            self._proxy = proxy_for(self.bus)
            if self._proxy is not None:
                self._proxy.start()
        # The server steps the clock itself (it paces realtime ticks against the wall clock).
        self.clock = SimClock("lockstep" if self.clock_spec.mode == "lockstep" else "fast")
        self._node = Node(self.name, bus=self.bus, clock=self.clock, diagnostics_period_s=0,
                          faults=self.faults)
        node = self._node
        self._pubs["/clock"] = node.create_publisher(Clock, "/clock", SENSOR, exclusive=True)
        self._pubs["/diagnostics"] = node.create_publisher(Diagnostics, "/diagnostics", qos=SENSOR)
        if self.scene.spec.swarm is not None and self.params.publish_thermals:
            self._pubs["/thermals"] = node.create_publisher(
                ThermalMarkers, "/thermals", qos=LATCHED
            )
        for gid in self.fleet.ids:
            self._pubs[f"/glider/{gid}/state"] = node.create_publisher(
                GliderState, f"/glider/{gid}/state", qos=SENSOR, exclusive=True
            )
            node.create_subscription(
                GliderCmd, f"/glider/{gid}/cmd", functools.partial(self._on_cmd, gid),
                qos=COMMAND, priority=True, inline=True,
            )
        for gid in self.fleet.sixdof_ids:
            self._pubs[f"/glider/{gid}/fdm"] = node.create_publisher(
                FdmState, f"/glider/{gid}/fdm", qos=SENSOR, exclusive=True
            )
            node.create_subscription(
                SurfaceCmd, f"/glider/{gid}/surfaces", functools.partial(self._on_surfaces, gid),
                qos=COMMAND, priority=True, inline=True,
            )
        for gid in self._glider_index:
            self._pubs[f"/glider/{gid}/neighbors"] = node.create_publisher(
                GliderNeighbors, f"/glider/{gid}/neighbors", qos=SENSOR, exclusive=True
            )
        if self.fleet.flies:
            # the flight kernels loaded now, not on the tick that first flies a vehicle
            from sim_core.flight import warm_up

            warm_up()
        # the state of tick 0 before any callback can run: the first ping has a pose
        first = self.fleet.states()
        nodes_ok = self.clock_spec.mode != "lockstep" and not self.bus.startswith("mem://")
        self._sonars.attach(node, first, EchoNodes.spawn if nodes_ok else None)
        node.start()
        self._sonars.start()
        # the first tick reaches every subscriber that was there before the server started
        # (the echo nodes among them)
        if not node.transport.sync(BUS_SYNC_S):
            log.warning("%s: bus %s not in sync after %g s: subscribers may miss the first "
                        "ticks", self.name, self.bus, BUS_SYNC_S)
        self._threads = [
            threading.Thread(target=self._tick_loop, name=f"{self.name}-tick", daemon=True),
        ]
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
        self._sonars.close()
        if self._node is not None:
            self._node.stop()
        if self._proxy is not None:
            self._proxy.stop()

    def stats(self) -> dict[str, Any]:
        """Counters, the sim time, registered autopilots and latency percentiles (ms)."""
        sonars = self._sonars.stats()
        with self._lock:
            out: dict[str, Any] = dict(self._c)
            out["sim_time_s"] = self._sim_ns / 1e9
            out["tick_cpu_s"] = self._tick_cpu_s
            wall = self._tick_wall[1] - self._tick_wall[0]
            out["tick_wall_s"] = wall
            out["rate_achieved"] = self._sim_ns / 1e9 / wall if wall > 0 else math.nan
            out["tick_error"] = self._tick_error
            out["tick_priority"] = self._tick_priority
            out["echo_worker_nice"] = self._sonars.worker_nice
            out["flown"] = {str(g): dict(v) for g, v in sorted(self._flown_gliders.items())}
        out.update(self._inputs.stats())
        out.update(self._gate.stats())
        out.update(sonars)
        out["clock_mode"] = self.clock_spec.mode
        out["built"] = sorted(self.scene.built)
        out["ping_echo_ms"] = percentiles(sonars["ping_echo_ms"])
        out["ping_wait_ms"] = percentiles(sonars["ping_wait_ms"])
        out["ping_extrapolated_ms"] = percentiles(sonars["ping_extrapolated_ms"])
        out["echo_compute_ms"] = percentiles(sonars["echo_compute_ms"])
        if self.scene.spec.swarm is not None and "swarm" in self.scene.built:
            out["gliders_alive"] = int(np.count_nonzero(self.fleet.swarm.alive[0]))
        out["vehicles_down"] = self.fleet.vehicles_down
        return out

    def failure(self, *, final: bool = False) -> str | None:
        """Why the server failed (its tick loop died, a bus callback raised, the echo service
        or one of its workers died), or None (:mod:`hil_bridge.bus.faults`)."""
        return self.faults.failure(final=final)

    def finished(self) -> bool | None:
        """``stop_after_s`` reached and every ping echoed (None: no ``stop_after_s``)."""
        if self.params.stop_after_s is None:
            return None
        return self._reached_end.is_set() and self._gate.pending() == 0

    def wait_done(self, timeout: float | None = None) -> bool:
        """Block until the tick loop ended (``stop_after_s`` reached or stopped)."""
        return self._done.wait(timeout)

    # ------------------------------------------------------------------ commands (bus thread)

    def _on_cmd(self, gid: int, msg: GliderCmd) -> None:
        if self._inputs.on_cmd(gid, msg):
            self._gate.on_cmd(gid, int(msg.step))

    def _on_surfaces(self, gid: int, msg: SurfaceCmd) -> None:
        self._inputs.on_surfaces(gid, msg)
        self._gate.on_cmd(gid, int(msg.step))

    def _ticks_now(self) -> int:
        with self._lock:
            return self._c["ticks"]

    # ------------------------------------------------------------------ tick loop

    def _now_ns(self) -> int:
        with self._lock:
            return self._sim_ns

    def _record_flown(self, commands: Mapping[int, tuple[float, float]]) -> None:
        """Per externally commanded glider, at a control step: its held command and state."""
        st = self.fleet.swarm.state
        flown: dict[int, dict[str, Any]] = {}
        for gid, (bank_cmd, speed_cmd) in commands.items():
            i = self._glider_index.get(gid)
            if i is None:
                continue
            flown[gid] = {
                "step": int(self.fleet.swarm.step_count), "bank_cmd": float(bank_cmd),
                "bank": float(st.bank[0, i]), "airspeed_cmd": float(speed_cmd),
                "airspeed": float(st.speed[0, i]), "alive": bool(st.alive[0, i]),
            }
        with self._lock:
            self._c["external_steps"] += len(flown)
            self._flown_gliders.update(flown)

    def _publish_tick(self, st: FleetStates, decided: bool) -> None:
        """/clock, then the neighbour lists of a control step, then every state (so a consumer
        acting on a state already has the neighbours of the same step)."""
        pubs = self._pubs
        t_ns = st.t_ns
        pubs["/clock"].publish(Clock(stamp_ns=t_ns, lockstep=self.clock_spec.mode == "lockstep"))
        if decided:
            self._publish_neighbors(t_ns)
        gliders = self._glider_index
        rows = zip(
            st.ids, st.position.tolist(), st.heading.tolist(), st.bank.tolist(),
            st.airspeed.tolist(), st.vz.tolist(), st.alive.tolist(), st.step.tolist(),
            st.roll.tolist(), st.pitch.tolist(), st.yaw.tolist(), st.quat.tolist(),
            st.rates.tolist(), strict=True,
        )
        for gid, p, hdg, bank, v, vz, alive, step, roll, pitch, yaw, q, w in rows:
            pubs[f"/glider/{gid}/state"].publish(GliderState(
                stamp_ns=t_ns, x=p[0], y=p[1], z=p[2], heading=hdg, bank=bank, airspeed=v,
                vz=vz, alive=alive, glider_id=gid, step=step, roll=roll, pitch=pitch, yaw=yaw,
                qw=q[0], qx=q[1], qy=q[2], qz=q[3], roll_rate=w[0], pitch_rate=w[1],
                yaw_rate=w[2],
            ))
            self._gate.published(gid, step, alive=alive, every_tick=gid not in gliders)
        fdm = self.fleet.sixdof_outputs()
        if fdm is not None:
            rows6 = zip(self.fleet.sixdof_ids, fdm.position.tolist(), fdm.velocity.tolist(),
                        fdm.quat.tolist(), fdm.rates.tolist(), fdm.specific_force.tolist(),
                        fdm.airspeed.tolist(), fdm.geodetic.tolist(), strict=True)
            for gid, p, v, q, w, f, tas, g in rows6:
                pubs[f"/glider/{gid}/fdm"].publish(FdmState(
                    stamp_ns=t_ns, glider_id=gid, step=self.fleet.tick, x=p[0], y=p[1], z=p[2],
                    vx=v[0], vy=v[1], vz=v[2], qw=q[0], qx=q[1], qy=q[2], qz=q[3], p=w[0],
                    q=w[1], r=w[2], fx=f[0], fy=f[1], fz=f[2], airspeed=tas, lat=g[0], lon=g[1],
                    alt=g[2],
                ))
        with self._lock:
            self._c["clock_published"] += 1
            self._c["states_published"] += len(st.ids)
            self._c["fdm_published"] += 0 if fdm is None else len(self.fleet.sixdof_ids)

    def _publish_neighbors(self, t_ns: int) -> None:
        targets = [g for g in self._inputs.registered() if g in self._glider_index]
        if not targets:
            return
        swarm = self.fleet.swarm
        st = swarm.state
        step = int(swarm.step_count)
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
        th = self.fleet.swarm.thermals
        ok = th.valid[0]
        self._pubs["/thermals"].publish(ThermalMarkers(
            stamp_ns=t_ns, x=th.x[0, ok], y=th.y[0, ok], radius=th.radius[0, ok],
            w_max=th.w_max[0, ok],
        ))

    def _publish_diagnostics(self, t_ns: int) -> None:
        stats = self.stats()
        counters: dict[str, int | float] = {
            k: v for k, v in stats.items() if isinstance(v, int | float) and not isinstance(v, bool)
        }
        for key in ("ping_echo_ms", "ping_wait_ms", "ping_extrapolated_ms", "echo_compute_ms",
                    "cmd_effect_ticks", "cmd_apply_ms"):
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
        except Exception as exc:  # a bug must not vanish with its thread: a failure, in stats
            self.faults.report("tick loop", exc)
            with self._lock:
                self._tick_error = f"{type(exc).__name__}: {exc}"
        finally:
            self._sonars.ticks_ended()
            self._done.set()

    def _run_ticks(self) -> None:
        mode: Literal["realtime", "lockstep", "fast"] = self.clock_spec.mode
        fleet = self.fleet
        stop_s = self.params.stop_after_s
        stop_ns = None if stop_s is None else round(stop_s * 1e9)
        wall0 = time.monotonic()
        next_diag = wall0
        tick = 0
        decided = False
        last: tuple[FleetStates, bool] | None = None  # the last published tick
        if fleet.swarm is not None:
            self._publish_thermals(0)
        self._tick_priority = loop_priority(paced=mode == "realtime", nice=self.params.tick_nice)
        if "not permitted" in self._tick_priority:
            log.info("%s: tick thread at %s; see docs/server.md, Tick priority", self.name,
                     self._tick_priority)
        speed = self.clock_spec.rate if mode == "realtime" else self.clock_spec.max_speed
        pacer = None if speed is None else Pacer(speed, self.tick_ns, self._stop,
                                                 catch_up=mode == "realtime")
        cpu0 = time.thread_time()
        while not self._stop.is_set():
            t_ns = tick * self.tick_ns
            if stop_ns is not None and t_ns > stop_ns:
                if mode == "lockstep" and last is not None:  # a head's ping due at the end
                    self._gate.wait(last[0].t_ns, physics_due=False, sonars_only=True,
                                    resend=functools.partial(self._publish_tick, *last))
                self._reached_end.set()
                break
            if tick > 0:
                if mode == "lockstep" and last is not None:
                    # the one place lockstep waits: before flying from the last published tick,
                    # for what it owes (a swarm glider's answer to a control step is needed
                    # before the period that step governs is flown)
                    self._gate.wait(
                        last[0].t_ns, resend=functools.partial(self._publish_tick, *last),
                        physics_due=last[1],
                    )
                    if self._stop.is_set():
                        return
                fleet.advance(*self._inputs.for_tick(tick))
                with self._lock:
                    self._c["physics_steps"] += self.substeps
            decided = fleet.control_due()
            if decided:
                commands, _ = self._inputs.for_tick(tick)
                fleet.decide(commands)
                with self._lock:
                    self._c["control_steps"] += 1
                self._record_flown(commands)
            states = fleet.states()
            with self._lock:
                self._sim_ns = max(self._sim_ns, t_ns)
            if t_ns > self.clock.now_ns():
                self.clock.set_ns(t_ns)
            self._publish_tick(states, decided)
            last = (states, decided)
            cpu = time.thread_time()
            published_ns = time.monotonic_ns()
            self._inputs.published(published_ns)
            with self._lock:
                self._c["ticks"] += 1
                self._tick_cpu_s += cpu - cpu0
                self._tick_wall = (wall0, published_ns / 1e9)
            cpu0 = cpu
            tick += 1
            now = time.monotonic()
            if now >= next_diag:
                self._publish_diagnostics(t_ns)
                next_diag = now + self.params.diagnostics_period_s
            if pacer is not None and pacer.wait(tick * self.tick_ns) and pacer.catch_up:
                with self._lock:
                    self._c["late_ticks"] += 1
