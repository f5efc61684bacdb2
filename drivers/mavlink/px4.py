"""The PX4 HIL node: a stock PX4 flies a 6-DoF glider of the scene over MAVLink ``HIL_*``.

``Px4Hil(name, *, bus, vehicle_id, link=None, port=None, lockstep="auto", ...)`` is a launchable
node (its own process in a launch). It serves PX4's simulator interface (``docs/px4.md``,
:mod:`drivers.mavlink.hil`) on one :mod:`MAVLink link <drivers.mavlink.link>`:

- SITL (default): ``tcpin://127.0.0.1:{4560 + N}``, N the run's domain number, which is what
  ``px4 -i N`` connects to (``port`` overrides the port; a private domain, the pytest fixture,
  listens on a free one); HITL: ``link: serial:///dev/ttyACM0?baud=921600`` (a Pixhawk's USB
  with ``SYS_HITL`` 1), or a UDP URL;
- every ``/glider/<id>/fdm`` state becomes sensors (:class:`sim_core.sensors.SensorSuite`, its
  noise seeded by ``seed``, or none with ``sensors: {noise: false}``): one ``HIL_SENSOR``
  (``time_usec`` = the state's sim time: PX4's clock in lockstep), a ``HIL_GPS`` when the
  receiver's fix is due (10 Hz, late by its latency), a ``HIL_STATE_QUATERNION`` (the truth)
  at ``ground_truth_hz``; a state with a non-finite value is never sent
  (``states_nonfinite``);
- each sonar of ``ranges`` becomes ``DISTANCE_SENSOR`` (and optionally
  ``OBSTACLE_DISTANCE``) from its echoes (:mod:`drivers.mavlink.ranges`), on the same link;
- every ``HIL_ACTUATOR_CONTROLS`` becomes the glider's control surfaces (``actuators``,
  :class:`~drivers.mavlink.hil.ActuatorMap`), published on ``/glider/<id>/surfaces``;
- ``HEARTBEAT`` at ``heartbeat_hz`` (PX4 on USB starts its MAVLink instance on one).

How the server's ticks follow PX4 (a ``lockstep`` server lists the vehicle in ``autopilots``
and waits for one ``SurfaceCmd`` answering each state):

- **lockstep** (``lockstep: auto`` on a SITL link once PX4's controls carry flag bit 0, or
  ``on``): each ``HIL_ACTUATOR_CONTROLS`` answers the state last sent, so the server flies
  exactly one tick per message and never sends the next ``HIL_SENSOR`` before it came;
- **paced** otherwise (HITL, ``lockstep: off``, and a SITL PX4 booting, before its first
  controls, as PX4's Gazebo runs before its first): each state is answered with the newest
  surfaces (neutral before any) at its due time on the wall clock, sim time at ``speed`` times
  real time, so PX4 flies in real time; an answer more than a tick late counts in
  ``pace_late`` and one more than 0.1 s late moves the pace on (``pace_slips``).

Nothing moves before PX4 first connects. A PX4 that disconnects (``px4_disconnects``) is
served again when it connects (``px4_connects``), paced until its first controls; the glider
flies on meanwhile on the last surfaces. A malformed message is dropped and counted
(``messages_bad``; a frame that fails its checksum: the link's ``bad``), as is one this node
does not take (``messages_ignored``).

``added_latency_us``: the node's own time per lockstep step, from a state's arrival to its
``HIL_SENSOR`` written (``sensor_latency_us``) plus from the ``HIL_ACTUATOR_CONTROLS``'
arrival to its surfaces published (``controls_latency_us``).
"""

from __future__ import annotations

import logging
import math
import threading
import time
from collections import deque
from dataclasses import dataclass, field
from typing import Any, ClassVar, Literal

from drivers.mavlink.hil import (
    ActuatorMap,
    Clip,
    hil_gps,
    hil_sensor,
    hil_state_quaternion,
    surfaces_from_controls,
)
from drivers.mavlink.link import MavlinkLink, mavlink, open_mavlink
from drivers.mavlink.ranges import RangeFinderSpec, RangeSender
from hil_bridge.bus.domain import current as current_domain
from hil_bridge.bus.faults import Faults
from hil_bridge.bus.messages import SurfaceCmd, fdm_truth
from sim_core.config import from_dict
from sim_core.sensors import SensorSpec, SensorSuite

__all__ = ["Px4Hil", "Px4Params"]

log = logging.getLogger(__name__)

_PACE_SLIP_S = 0.1


@dataclass(frozen=True, slots=True)
class Px4Params:
    """Validated parameters of :class:`Px4Hil` (module docstring)."""

    vehicle_id: int
    link: str | None = None
    port: int | None = None
    host: str = "127.0.0.1"
    lockstep: Literal["auto", "on", "off"] = "auto"
    speed: float = 1.0
    actuators: ActuatorMap = field(default_factory=ActuatorMap)
    sensors: SensorSpec = field(default_factory=SensorSpec)
    seed: int = 0
    ground_truth_hz: float | None = None
    ranges: RangeFinderSpec | None = None
    heartbeat_hz: float = 1.0
    system: int = 1
    component: int = 158

    def __post_init__(self) -> None:
        if self.vehicle_id < 0:
            raise ValueError(f"vehicle_id: expected >= 0, got {self.vehicle_id}")
        if self.port is not None and not 0 <= self.port <= 65535:
            raise ValueError(f"port: expected 0..65535 (0: any free port), got {self.port}")
        if self.port is not None and self.link is not None:
            raise ValueError("port: give a port or a link URL, not both")
        if not 0.01 <= self.speed <= 100:
            raise ValueError(f"speed: expected 0.01..100 times real time, got {self.speed}")
        if self.ground_truth_hz is not None and not 0 <= self.ground_truth_hz <= 1000:
            raise ValueError(f"ground_truth_hz: expected 0..1000, got {self.ground_truth_hz}")
        if not 0 < self.heartbeat_hz <= 50:
            raise ValueError(f"heartbeat_hz: expected 0 < rate <= 50, got {self.heartbeat_hz}")
        if self.seed < 0:
            raise ValueError(f"seed: expected >= 0, got {self.seed}")


_COUNTERS = ("states", "sensors_sent", "gps_sent", "ground_truth_sent",
             "states_nonfinite", "values_clipped", "actuators",
             "surfaces_published", "surfaces_paced", "messages_bad", "messages_ignored",
             "interval_requests",
             "px4_connects", "px4_disconnects", "heartbeats_sent", "pace_late", "pace_slips")


@dataclass(slots=True)
class _Step:
    """The state last sent to PX4: its step, sim time, when it arrived (monotonic ns), the
    node's time on it before its sensors left and after PX4's controls came (ns; -1: not
    yet, both under the node's lock)."""

    step: int
    stamp_ns: int
    arrived_ns: int
    before_ns: int = -1
    after_ns: int = -1


class Px4Hil:
    """Launchable PX4 HIL node (see the module docstring)."""

    #: a launch puts it in one process with a lockstep server (docs/launch.md, Composition)
    LOCKSTEP_PARTNER: ClassVar[bool] = True

    @staticmethod
    def speed_params(params: dict[str, Any], speed: float | None) -> dict[str, Any]:
        """``params`` with the paced phase at ``speed`` (``echoloop launch --speed``; ``max``:
        100, the highest; in lockstep PX4 and the server set the pace)."""
        return {**params, "speed": 100.0 if speed is None else speed}

    def __init__(self, name: str, *, bus: str, **params: Any) -> None:
        self.name = name
        self.bus = bus
        self.params = from_dict(Px4Params, params, path=f"{name}.params")
        p = self.params
        if p.link is not None:
            self.url = p.link
        else:
            default = current_domain().px4_sitl_port  # the run's, while the launcher builds
            port = p.port if p.port is not None else (0 if default is None else default)
            self.url = f"tcpin://{p.host}:{port}"
        self.sitl = self.url.startswith(("tcp", "udp"))
        #: HIL_STATE_QUATERNION's rate: 50 Hz on a SITL link, none on HITL's (there PX4 would
        #: take it for its own state), or what PX4 asks with MAV_CMD_SET_MESSAGE_INTERVAL
        self.ground_truth_hz = p.ground_truth_hz if p.ground_truth_hz is not None else (
            50.0 if self.sitl else 0.0)
        self._gt_default = self.ground_truth_hz
        self.faults = Faults(name)
        self._suite = SensorSuite(p.sensors, 1, seed=p.seed, key=(p.vehicle_id,))
        self._ranges = RangeSender(p.ranges, name) if p.ranges is not None else None
        self._clip = Clip()
        self._lock = threading.Lock()
        self._wake = threading.Condition(self._lock)
        self._stop = threading.Event()
        self._c = dict.fromkeys(_COUNTERS, 0)
        self._added_us: deque[float] = deque(maxlen=100_000)
        self._parts_us: tuple[deque[float], deque[float]] = (deque(maxlen=100_000),
                                                             deque(maxlen=100_000))
        self._link: MavlinkLink | None = None
        self._node: Any = None
        self._pub: Any = None
        self._threads: list[threading.Thread] = []
        # the conversation (under the lock)
        self._connected_once = False
        self._lockstep = False
        self._controls_seen = False
        self._surfaces = (0.0, 0.0, 0.0, 0.0)
        self._last: _Step | None = None
        self._newest: Any = None  # the newest state, sent or not
        self._answered = -1
        #: (peer generation, step) of the newest sensors written (each peer is sent each once)
        self._written = (-1, -1)
        self._paced: deque[_Step] = deque()
        self._pace0: tuple[float, int] | None = None  # (monotonic s, sim ns) of the pace
        self._gt_next_ns = 0

    @property
    def port(self) -> int | None:
        """The port the link listens on (a ``tcpin``/``udpin`` link, once started)."""
        return getattr(self._link, "port", None)

    # ------------------------------------------------------------------ lifecycle

    def start(self) -> None:
        from hil_bridge.bus.messages import FdmState, SonarEcho
        from hil_bridge.bus.node import Node
        from hil_bridge.bus.qos import COMMAND, SENSOR
        from sim_core.sensors.kernels import warm_up

        warm_up()  # the sensor kernels compiled or loaded now, not in the first state's callback
        p = self.params
        self._link = open_mavlink(self.url, system=p.system, component=p.component)
        self._node = Node(self.name, bus=self.bus, faults=self.faults)
        self._pub = self._node.create_publisher(SurfaceCmd, f"/glider/{p.vehicle_id}/surfaces",
                                                qos=COMMAND, exclusive=True)  # PX4 flies it
        self._node.create_subscription(FdmState, f"/glider/{p.vehicle_id}/fdm", self._on_state,
                                       qos=SENSOR, priority=True, inline=True)
        if self._ranges is not None:
            for sonar in self._ranges.ranger.spec.sonars:
                self._node.create_subscription(SonarEcho, f"/sonar/{sonar.sonar_id}/echo",
                                               self._ranges.submit, qos=SENSOR)
            self._ranges.start(self._link, self.faults)
        self._node.start()
        for where, body in (("PX4 link", self._read_loop), ("pacer", self._pace_loop)):
            t = threading.Thread(target=self.faults.guarded(where, body),
                                 name=f"{self.name}-{where.split()[-1]}", daemon=True)
            self._threads.append(t)
            t.start()
        log.info("%s: serving PX4 HIL for vehicle %d on %s", self.name, p.vehicle_id,
                 self.url if self.port is None else f"{self.url} (port {self.port})")

    def stop(self) -> None:
        self._stop.set()
        with self._wake:
            self._wake.notify_all()
        for t in self._threads:
            t.join()
        self._threads = []
        if self._ranges is not None:
            self._ranges.stop()
        if self._node is not None:
            self._node.stop()
            self._node = None
        if self._link is not None:
            self._link.close()

    def stats(self) -> dict[str, Any]:
        from hil_bridge.bus.stats import percentiles

        out = self.counters()
        with self._lock:
            lat = list(self._added_us)
            parts = [list(d) for d in self._parts_us]
        out["added_latency_us"] = percentiles(lat)
        out["sensor_latency_us"] = percentiles(parts[0])
        out["controls_latency_us"] = percentiles(parts[1])
        return out

    def counters(self) -> dict[str, Any]:
        with self._lock:
            out: dict[str, Any] = dict(self._c)
            out["values_clipped"] = self._clip.count
            out["lockstep"] = self._lockstep
        out["url"] = self.url
        out["port"] = self.port
        if self._link is not None:
            out["link"] = self._link.stats()
        if self._ranges is not None:
            out["ranges"] = self._ranges.counters()
        return out

    def failure(self, *, final: bool = False) -> str | None:
        """Why the node failed (a thread or a bus callback raised), or None."""
        return self.faults.failure(final=final)

    # ------------------------------------------------------------------ states (bus thread)

    def _on_state(self, msg: Any) -> None:
        arrived = time.monotonic_ns()
        with self._lock:
            if self._newest is not None and msg.step <= self._newest.step:
                return  # a tick sent again while the server waits
            self._newest = msg
            self._c["states"] += 1
            if not self._connected_once:
                return  # nothing moves before PX4 is there: sent once it connects
        self._serve(msg, arrived)

    def _serve(self, msg: Any, arrived: int) -> None:
        """Send ``msg``'s sensors to PX4; answer it now (paced) or on PX4's controls."""
        link = self._link
        assert link is not None
        t_ns = int(msg.stamp_ns)
        readings = self._suite.sample(t_ns, fdm_truth([msg]))
        sensor = hil_sensor(t_ns // 1000, readings)
        step = _Step(int(msg.step), t_ns, arrived)
        generation = link.generation
        with self._wake:
            if (generation, step.step) <= self._written:
                return  # sent to this peer already (it came meanwhile)
            self._written = (generation, step.step)
            self._last = step  # before the sensors leave: PX4's answer may come at once
            if not self._lockstep and step.step > self._answered:
                self._paced.append(step)
                self._wake.notify_all()
            self._c["states_nonfinite"] += sensor is None
        if sensor is not None and link.send_many((sensor,), generation):
            before = time.monotonic_ns() - arrived
            with self._lock:
                self._c["sensors_sent"] += 1
                step.before_ns = before
                self._parts_us[0].append(before / 1e3)
                if step.after_ns >= 0:
                    self._added_us.append((before + step.after_ns) / 1e3)
        # the rest of this step's time, after the HIL_SENSOR that runs PX4's step: PX4 reads
        # each as it comes, on its clock of that step (the truth is for its logs alone)
        out: list[tuple[str, Any]] = []
        fix = self._suite.gps_fix(t_ns)
        if fix is not None:
            gps = hil_gps(t_ns // 1000, fix, self._clip)
            if gps is not None:
                out.append(("gps_sent", gps))
        gt_hz = self.ground_truth_hz
        if gt_hz > 0 and t_ns >= self._gt_next_ns:
            period = round(1e9 / gt_hz)
            self._gt_next_ns = (t_ns // period + 1) * period
            truth = hil_state_quaternion(t_ns // 1000, msg, readings, self._clip)
            if truth is not None:
                out.append(("ground_truth_sent", truth))
        if out and link.send_many([m for _, m in out], generation):
            with self._lock:
                for name, _ in out:
                    self._c[name] += 1

    # ------------------------------------------------------------------ PX4 (link thread)

    def _read_loop(self) -> None:
        link = self._link
        assert link is not None
        beat_period = 1.0 / self.params.heartbeat_hz
        next_beat = time.monotonic()
        was = False
        while not self._stop.is_set():
            now = time.monotonic()
            if now >= next_beat:
                next_beat = now + beat_period
                if link.connected and link.send(mavlink.MAVLink_heartbeat_message(
                        mavlink.MAV_TYPE_GENERIC, mavlink.MAV_AUTOPILOT_INVALID, 0, 0,
                        mavlink.MAV_STATE_ACTIVE, 3)):
                    with self._lock:
                        self._c["heartbeats_sent"] += 1
            messages = link.recv(min(0.05, max(0.0, next_beat - time.monotonic())))
            t_in = time.monotonic_ns()
            if link.connected != was:
                was = link.connected
                self._on_connection(was)
            for m in messages:
                kind = m.get_type()
                if kind == "HIL_ACTUATOR_CONTROLS":
                    self._on_controls(m, t_in)
                elif kind == "COMMAND_LONG" and m.command == mavlink.MAV_CMD_SET_MESSAGE_INTERVAL:
                    self._on_interval(m)
                elif kind != "HEARTBEAT":
                    with self._lock:
                        self._c["messages_ignored"] += 1

    def _on_connection(self, up: bool) -> None:
        with self._wake:
            if up:
                self._c["px4_connects"] += 1
                first = not self._connected_once
                self._connected_once = True
                self._controls_seen = False
                self._lockstep = False
                self._pace0 = None
                newest = self._newest
                resend = newest is not None
            else:
                self._c["px4_disconnects"] += 1
                self._lockstep = False
                self._controls_seen = False
                self._pace0 = None
                last = self._last
                if last is not None and last.step > self._answered:
                    self._paced.append(last)  # the step PX4 left unanswered
                self._wake.notify_all()
                log.warning("%s: PX4 disconnected (vehicle %d flies on)", self.name,
                            self.params.vehicle_id)
                return
        log.info("%s: PX4 connected%s", self.name, "" if first else " again")
        if resend:  # the newest state, unless sent to this peer meanwhile
            self._serve(newest, time.monotonic_ns())

    def _on_interval(self, m: Any) -> None:
        """PX4 asks for ``HIL_STATE_QUATERNION`` at an interval (µs; -1 none, 0 the default);
        any other message is refused (``MAV_RESULT_UNSUPPORTED``)."""
        link = self._link
        assert link is not None
        ok = int(m.param1) == mavlink.MAVLINK_MSG_ID_HIL_STATE_QUATERNION and math.isfinite(
            m.param2)
        if ok:
            interval = float(m.param2)
            self.ground_truth_hz = (self._gt_default if interval == 0 else 0.0 if interval < 0
                                    else min(1e6 / interval, self.params.sensors.rate_hz))
            log.info("%s: PX4 asks for HIL_STATE_QUATERNION at %.0f Hz", self.name,
                     self.ground_truth_hz)
        with self._lock:
            self._c["interval_requests"] += 1
        link.send(mavlink.MAVLink_command_ack_message(
            m.command, mavlink.MAV_RESULT_ACCEPTED if ok else mavlink.MAV_RESULT_UNSUPPORTED))

    def _on_controls(self, m: Any, t_in: int) -> None:
        controls = m.controls
        surfaces = surfaces_from_controls(controls, self.params.actuators) if len(
            controls) == 16 else None
        if surfaces is None:
            with self._lock:
                self._c["messages_bad"] += 1
            return
        with self._wake:
            self._c["actuators"] += 1
            self._surfaces = surfaces
            if not self._controls_seen:
                self._controls_seen = True
                mode = self.params.lockstep
                self._lockstep = mode == "on" or (mode == "auto" and self.sitl and
                                                  bool(int(m.flags) & 1))
                if self._lockstep:
                    self._paced.clear()  # these controls answer the state last sent
                log.info("%s: PX4's first controls: %s", self.name,
                         "lockstep" if self._lockstep else "paced in real time")
            last = self._last
            if not self._lockstep or last is None:
                return
            first = last.step > self._answered
            self._answered = max(self._answered, last.step)
            self._c["surfaces_published"] += 1
        self._publish(last, surfaces)
        if first:
            after = time.monotonic_ns() - t_in
            with self._lock:
                last.after_ns = after
                self._parts_us[1].append(after / 1e3)
                if last.before_ns >= 0:
                    self._added_us.append((last.before_ns + after) / 1e3)

    def _publish(self, step: _Step, surfaces: tuple[float, float, float, float]) -> None:
        """Answer ``step`` with ``surfaces`` (counted by the caller)."""
        a, e, t, r = surfaces
        self._pub.publish(SurfaceCmd(stamp_ns=step.stamp_ns, aileron=a, elevator=e, throttle=t,
                                     rudder=r, glider_id=self.params.vehicle_id, step=step.step))

    # ------------------------------------------------------------------ paced answers

    def _pace_loop(self) -> None:
        """Answer paced states at their due time on the wall clock (module docstring)."""
        speed = self.params.speed
        while not self._stop.is_set():
            with self._wake:
                while not self._paced and not self._stop.is_set():
                    self._wake.wait(0.5)
                if self._stop.is_set():
                    return
                step = self._paced[0]
                if self._pace0 is None:
                    self._pace0 = (time.monotonic(), step.stamp_ns)
                t0, s0 = self._pace0
                due = t0 + (step.stamp_ns - s0) / 1e9 / speed
                left = due - time.monotonic()
                if left > 0:
                    self._wake.wait(left)
                    continue  # look again: stopped, lockstep begun or a newer state
                self._paced.popleft()
                if self._lockstep or step.step <= self._answered:
                    continue
                late = -left
                self._c["pace_late"] += late > 1.0 / self.params.sensors.rate_hz
                if late > _PACE_SLIP_S:
                    self._c["pace_slips"] += 1
                    self._pace0 = (time.monotonic(), step.stamp_ns)
                self._answered = step.step
                self._c["surfaces_paced"] += 1
                self._c["surfaces_published"] += 1
                surfaces = self._surfaces
            self._publish(step, surfaces)
