"""The DroneCAN node: echoloop as a set of DroneCAN peripherals of a stock flight controller.

``DroneCanNode(name, *, bus, interface=None, node_id=None, ...)`` is a launchable node (its own
process in a launch) on one CAN interface (:mod:`drivers.dronecan.interfaces`; by default
``mcast:N``, N the run's domain number: two runs never share a bus). On the ``dronecan``
package (its DSDL and transfers):

- **a node**: ``NodeStatus`` at 1 Hz, ``GetNodeInfo`` answered (name ``org.echoloop.sim``, a
  unique ID of the node's name, vehicle and domain); its node ID ``node_id``, or by dynamic
  allocation as a client (:mod:`drivers.dronecan.allocation`) preferring
  ``preferred_node_id``; nothing but allocation requests is sent before it has one;
- **range finders**: each echo of a sonar of ``ranges`` becomes one
  ``uavcan.equipment.range_sensor.Measurement`` per ear (``sensor_id`` = the sonar's
  ``sensor_id`` + the ear), the range by echoloop's one rule (the first return above a
  threshold, by time of flight: :mod:`sim_core.sensors.echo_range`);
- **air data and GNSS** where asked (``air_data_hz``, ``gnss``): the 6-DoF vehicle's pitot
  (``RawAirData``), barometer (``StaticPressure``, ``StaticTemperature``) and fix (``Fix2``,
  at its receiver's rate), read by :class:`sim_core.sensors.SensorSuite` from
  ``/glider/<id>/fdm``;
- **actuators in**: ``uavcan.equipment.actuator.ArrayCommand`` (and the throttle of
  ``esc.RawCommand``) become the 6-DoF vehicle's surfaces on ``/glider/<id>/surfaces``
  (``actuators``: ArduPilot's servo order by default), or, with ``profile: pointmass``,
  commanded bank and airspeed (``/glider/<id>/cmd``: the aileron's [-1, 1] times
  ``bank_max_rad``, a positive aileron rolling right, so to a negative bank: echoloop's bank,
  the seed's, is positive in a left turn; the elevator's across ``airspeed_mps``).

A transfer that cannot be taken (a multi-frame CRC that fails, a toggle or transfer-id error,
an unknown data type, a payload that does not decode) is dropped and counted by its reason
(``transfers_bad``); a datagram of ``mcast:`` that is not a frame is counted by the driver.
``echo_to_can_us``: the node's time from an echo's arrival to its last ``Measurement`` written
(the rule runs in the bus callback that receives the echo: no thread hand-off);
``echo_cpu_us``: the CPU time of that thread meanwhile (the rest is waiting for a core or
for the interpreter).
"""

from __future__ import annotations

import hashlib
import logging
import math
import random
import threading
import time
from collections import deque
from dataclasses import dataclass, field
from typing import Any, Literal

import numpy as np

from drivers.dronecan.allocation import Allocatee
from drivers.dronecan.interfaces import open_can
from drivers.dronecan.messages import (
    ServoMap,
    fix2,
    measurement,
    raw_air_data,
    static_pressure,
    static_temperature,
    surfaces_from_array,
    surfaces_from_esc,
)
from hil_bridge.bus.domain import current as current_domain
from hil_bridge.bus.faults import Faults
from hil_bridge.bus.messages import fdm_truth
from sim_core.config import ConfigError, from_dict
from sim_core.sensors import RangeRule, SensorSpec, SensorSuite, echo_ranges

__all__ = ["DroneCanNode", "DroneCanParams", "SonarSensor"]

log = logging.getLogger(__name__)


@dataclass(frozen=True, slots=True)
class SonarSensor:
    """A sonar as DroneCAN range finder(s): ear e is ``sensor_id + e`` (ArduPilot matches it
    to ``RNGFNDx_ADDR``), its beam's ``fov_deg``."""

    sonar_id: int = 0
    sensor_id: int = 1
    fov_deg: float = 40.0

    def __post_init__(self) -> None:
        if not 0 <= self.sensor_id <= 250:
            raise ValueError(f"sensor_id: expected 0..250, got {self.sensor_id}")
        if not 0 <= self.fov_deg < 180:
            raise ValueError(f"fov_deg: expected 0 <= fov < 180, got {self.fov_deg}")


@dataclass(frozen=True, slots=True)
class PointMass:
    """What commands mean to a point-mass vehicle: bank = −aileron × ``bank_max_rad`` (a
    positive aileron rolls right; the bus's bank is positive to the left),
    airspeed from ``airspeed_mps[0]`` (elevator -1) to ``airspeed_mps[1]`` (+1)."""

    bank_max_rad: float = 0.6
    airspeed_mps: tuple[float, float] = (9.0, 16.0)

    def __post_init__(self) -> None:
        lo, hi = self.airspeed_mps
        if not (0 < self.bank_max_rad < 1.5 and 0 < lo < hi):
            raise ValueError(f"pointmass: expected 0 < bank_max_rad < 1.5 and 0 < lo < hi, got "
                             f"{self.bank_max_rad}, {list(self.airspeed_mps)}")


@dataclass(frozen=True, slots=True)
class DroneCanParams:
    """Validated parameters of :class:`DroneCanNode` (module docstring)."""

    vehicle_id: int
    interface: str | None = None
    node_id: int | None = None
    preferred_node_id: int = 0
    ranges: tuple[SonarSensor, ...] = (SonarSensor(),)
    threshold_db: float = -100.0
    relative_db: float = -25.0
    sound_speed: float = 340.0
    min_distance_m: float = 0.2
    max_distance_m: float = 10.0
    air_data_hz: float = 0.0
    gnss: bool = False
    sensors: SensorSpec = field(default_factory=SensorSpec)
    seed: int = 0
    actuators: ServoMap = field(default_factory=ServoMap)
    profile: Literal["sixdof", "pointmass"] = "sixdof"
    pointmass: PointMass = field(default_factory=PointMass)

    def __post_init__(self) -> None:
        if self.node_id is not None and not 1 <= self.node_id <= 125:
            raise ValueError(f"node_id: expected 1..125 (null: dynamic allocation), got "
                             f"{self.node_id}")
        if not 0 <= self.air_data_hz <= 200:
            raise ValueError(f"air_data_hz: expected 0..200 (0: none), got {self.air_data_hz}")
        if self.profile == "pointmass" and (self.air_data_hz or self.gnss):
            raise ValueError("profile: a point-mass vehicle has no sensor truth (no "
                             "/glider/<id>/fdm): give air_data_hz 0 and gnss false")
        if not 0 <= self.min_distance_m < self.max_distance_m:
            raise ValueError(f"min_distance_m, max_distance_m: expected 0 <= min < max, got "
                             f"{self.min_distance_m}, {self.max_distance_m}")


_COUNTERS = ("frames_in", "transfers_in", "transfers_bad", "measurements_sent",
             "measurements_unsent", "air_data_sent", "gnss_sent", "array_commands",
             "esc_commands", "commands_bad", "surfaces_published", "cmds_published",
             "allocation_requests", "echoes")


class _Relay:
    """A ``dronecan`` driver in front of the real one: the CAN thread reads frames off the
    interface with no lock held and queues them here, and ``Node.spin(0)``, under the node's
    lock, takes them from the queue; writes go straight through."""

    def __init__(self, driver: Any) -> None:
        self.driver = driver
        self.queue: deque[Any] = deque()

    def receive(self, timeout: float | None = None) -> Any:
        return self.queue.popleft() if self.queue else None

    def send(self, message_id: int, message: bytes, extended: bool = False,
             canfd: bool = False) -> None:
        self.driver.send(message_id, message, extended=extended, canfd=canfd)

    def close(self) -> None:
        self.driver.close()


class DroneCanNode:
    """Launchable DroneCAN node (see the module docstring)."""

    def __init__(self, name: str, *, bus: str, **params: Any) -> None:
        self.name = name
        self.bus = bus
        self.params = p = from_dict(DroneCanParams, params, path=f"{name}.params")
        domain = current_domain()  # the run's, while the launcher builds
        if p.interface is not None:
            self.interface = p.interface
        elif domain.number is not None:
            self.interface = f"mcast:{domain.number}"
        else:
            raise ConfigError(f"{name}.params.interface: a private domain has no CAN bus; give "
                              "one (e.g. mcast:0)")
        seed = hashlib.sha256(f"{domain.token}/{name}/{p.vehicle_id}".encode()).digest()
        self.unique_id = seed[:16]
        self.faults = Faults(name)
        self._rule = RangeRule(threshold_db=p.threshold_db, relative_db=p.relative_db,
                               sound_speed=p.sound_speed, min_range_m=p.min_distance_m)
        self._sonars = {s.sonar_id: s for s in p.ranges}
        self._suite = SensorSuite(p.sensors, 1, seed=p.seed, key=(p.vehicle_id,))
        self._lock = threading.Lock()  # the dronecan node and the counters
        self._stop = threading.Event()
        self._c = dict.fromkeys(_COUNTERS, 0)
        self._bad: dict[str, int] = {}
        self._echo_us: deque[float] = deque(maxlen=100_000)
        self._cpu_us: deque[float] = deque(maxlen=100_000)
        self._surfaces = (0.0, 0.0, 0.0, 0.0)
        self._outgoing: Any = None  # the newest command to publish
        self._state: Any = None
        self._air_next_ns = 0
        self._node: Any = None
        self._bus_node: Any = None
        self._relay: _Relay | None = None
        self._allocatee: Allocatee | None = None
        self._threads: list[threading.Thread] = []
        self._measurements: dict[tuple[int, int], Any] = {}  # filled again for every echo

    # ------------------------------------------------------------------ lifecycle

    def start(self) -> None:
        import dronecan

        from hil_bridge.bus.messages import FdmState, GliderCmd, SonarEcho, SurfaceCmd
        from hil_bridge.bus.node import Node
        from hil_bridge.bus.qos import COMMAND, SENSOR

        p = self.params
        driver = open_can(self.interface)
        self._relay = _Relay(driver)
        info = dronecan.uavcan.protocol.GetNodeInfo.Response()
        info.name = "org.echoloop.sim"
        info.software_version.major, info.software_version.minor = 0, 1
        info.hardware_version.unique_id = list(self.unique_id)
        self._node = dronecan.node.Node(self._relay, node_id=p.node_id, node_info=info,
                                        mode=dronecan.uavcan.protocol.NodeStatus().MODE_OPERATIONAL)
        if p.node_id is None:
            self._allocatee = Allocatee(self.unique_id, p.preferred_node_id,
                                        rng=random.Random(self.unique_id), now=time.monotonic())
        uc = dronecan.uavcan.equipment
        self._node.add_handler(dronecan.uavcan.protocol.dynamic_node_id.Allocation,
                               self._on_allocation)
        self._node.add_handler(uc.actuator.ArrayCommand, self._on_array)
        self._node.add_handler(uc.esc.RawCommand, self._on_esc)
        self._bus_node = Node(self.name, bus=self.bus, faults=self.faults)
        vid = p.vehicle_id
        if p.profile == "sixdof":
            self._pub = self._bus_node.create_publisher(SurfaceCmd, f"/glider/{vid}/surfaces",
                                                        qos=COMMAND)
            self._bus_node.create_subscription(FdmState, f"/glider/{vid}/fdm", self._on_state,
                                               qos=SENSOR)
        else:
            self._pub = self._bus_node.create_publisher(GliderCmd, f"/glider/{vid}/cmd",
                                                        qos=COMMAND)
        for sonar in p.ranges:
            self._bus_node.create_subscription(SonarEcho, f"/sonar/{sonar.sonar_id}/echo",
                                               self._on_echo, qos=SENSOR)
        self._bus_node.start()
        echo_ranges(np.zeros((1, 64)), 4e5)  # the rule's code loaded before the first echo
        for where, body in (("CAN", self._can_loop),):
            t = threading.Thread(target=self.faults.guarded(where, body),
                                 name=f"{self.name}-{where.lower()}", daemon=True)
            self._threads.append(t)
            t.start()
        log.info("%s: DroneCAN node on %s (%s)", self.name, self.interface,
                 f"node ID {p.node_id}" if p.node_id else "dynamic node ID")

    def stop(self) -> None:
        self._stop.set()
        for t in self._threads:
            t.join()
        self._threads = []
        if self._bus_node is not None:
            self._bus_node.stop()
            self._bus_node = None
        if self._relay is not None:
            self._relay.close()

    @property
    def node_id(self) -> int | None:
        """The node ID, once it has one."""
        return None if self._node is None else self._node.node_id or None

    def counters(self) -> dict[str, Any]:
        with self._lock:
            out: dict[str, Any] = dict(self._c)
            out["transfers_bad_by"] = dict(self._bad)
        out["node_id"] = self.node_id
        out["interface"] = self.interface
        if self._relay is not None and hasattr(self._relay.driver, "counts"):
            out["driver"] = dict(self._relay.driver.counts)
        return out

    def stats(self) -> dict[str, Any]:
        from hil_bridge.bus.stats import percentiles

        out = self.counters()
        with self._lock:
            lat = list(self._echo_us)
        out["echo_to_can_us"] = percentiles(lat)
        out["echo_cpu_us"] = percentiles(list(self._cpu_us))
        return out

    def failure(self, *, final: bool = False) -> str | None:
        """Why the node failed (a thread or a bus callback raised), or None."""
        return self.faults.failure(final=final)

    # ------------------------------------------------------------------ the CAN thread

    def _can_loop(self) -> None:
        from dronecan.transport import TransferError

        relay = self._relay
        assert relay is not None
        while not self._stop.is_set():
            frame = relay.driver.receive(0.02)
            with self._lock:
                if frame is not None:
                    relay.queue.append(frame)
                    self._c["frames_in"] += 1
                    while (more := relay.driver.receive(0)) is not None:
                        relay.queue.append(more)
                        self._c["frames_in"] += 1
                while True:
                    try:
                        self._node.spin(0)  # the queued frames, NodeStatus when due
                        break
                    except TransferError as exc:
                        self._count_bad(str(exc))
                    except (ValueError, IndexError, KeyError, OverflowError) as exc:
                        self._count_bad(f"malformed payload: {exc}")
                self._allocate()
                outgoing, self._outgoing = self._outgoing, None
            if outgoing is not None:  # the newest of the batch, with the node's lock free
                self._pub.publish(outgoing)
                with self._lock:
                    self._c["surfaces_published" if self.params.profile == "sixdof"
                            else "cmds_published"] += 1

    def _count_bad(self, why: str) -> None:
        """Count a transfer dropped (under the lock), by the first words of its reason."""
        key = " ".join(why.split()[:2]).rstrip(":").lower()
        self._c["transfers_bad"] += 1
        self._bad[key] = self._bad.get(key, 0) + 1

    def _allocate(self) -> None:
        """Send what the allocation protocol asks for now (under the lock)."""
        import dronecan
        from dronecan import transport

        a = self._allocatee
        if a is None or a.node_id is not None:
            return
        req = a.poll(time.monotonic())
        if req is None:
            return
        msg = dronecan.uavcan.protocol.dynamic_node_id.Allocation()
        msg.node_id, msg.first_part_of_unique_id = req.node_id, req.first_part
        msg.unique_id = list(req.unique_id)
        tr = transport.Transfer(payload=msg, source_node_id=0, transfer_id=0,
                                transfer_priority=30, service_not_message=False,
                                discriminator=int.from_bytes(hashlib.sha256(
                                    bytes(req.unique_id)).digest()[:2], "little") & 0x3FFF)
        for f in tr.to_frames():
            self._relay.send(f.message_id, f.bytes, extended=True)  # type: ignore[union-attr]
        self._c["allocation_requests"] += 1

    def _on_allocation(self, e: Any) -> None:
        """An allocator's answer (dronecan handler, on the CAN thread, under the lock)."""
        a = self._allocatee
        if a is None or e.transfer.source_node_id == 0 or a.node_id is not None:
            return
        a.on_message(int(e.message.node_id), bytes(e.message.unique_id), time.monotonic())
        if a.node_id is not None:
            self._node.node_id = a.node_id
            log.info("%s: allocated node ID %d by node %d", self.name, a.node_id,
                     e.transfer.source_node_id)

    def _on_array(self, e: Any) -> None:
        self._c["array_commands"] += 1
        out = surfaces_from_array(e.message.commands, self.params.actuators, self._surfaces)
        self._command(out)

    def _on_esc(self, e: Any) -> None:
        self._c["esc_commands"] += 1
        self._command(surfaces_from_esc(e.message.cmd, self.params.actuators, self._surfaces))

    def _command(self, out: tuple[float, float, float, float] | None) -> None:
        """Take the surfaces (or a point mass's command) the actuators now say (under the lock,
        on the CAN thread, which publishes the newest once it has let go of the lock)."""
        from hil_bridge.bus.messages import GliderCmd, SurfaceCmd

        if out is None:
            self._c["commands_bad"] += 1
            return
        self._surfaces = out
        state = self._state
        stamp, step = (0, 0) if state is None else (int(state.stamp_ns), int(state.step))
        a, e, t, r = out
        vid = self.params.vehicle_id
        if self.params.profile == "sixdof":
            self._outgoing = SurfaceCmd(stamp_ns=stamp, aileron=a, elevator=e, throttle=t,
                                        rudder=r, glider_id=vid, step=step)
        else:
            pm = self.params.pointmass
            lo, hi = pm.airspeed_mps
            self._outgoing = GliderCmd(stamp_ns=stamp, bank_cmd=-a * pm.bank_max_rad,
                                       airspeed_cmd=lo + (e + 1.0) / 2.0 * (hi - lo),
                                       glider_id=vid, step=step)

    def _broadcast(self, msgs: list[Any], counter: str, unsent: str | None = None) -> bool:
        """Broadcast ``msgs`` (counted in ``counter``) once the node has an ID; before, count
        them in ``unsent`` if given."""
        with self._lock:
            if not self._node.node_id:
                if unsent is not None:
                    self._c[unsent] += len(msgs)
                return False
            for m in msgs:
                self._node.broadcast(m)
            self._c[counter] += len(msgs)
            return True

    # ------------------------------------------------------------------ the bus

    def _on_state(self, msg: Any) -> None:
        """A 6-DoF state: the sensors' truth, the step commands answer."""
        self._state = msg
        p = self.params
        if not (p.air_data_hz or p.gnss):
            return
        t_ns = int(msg.stamp_ns)
        readings = self._suite.sample(t_ns, fdm_truth([msg]))
        out: list[Any] = []
        if p.air_data_hz and t_ns >= self._air_next_ns:
            period = round(1e9 / p.air_data_hz)
            self._air_next_ns = (t_ns // period + 1) * period
            out += [m for m in (raw_air_data(readings), static_pressure(
                readings, sigma_pa=p.sensors.baro_noise_pa), static_temperature(readings))
                    if m is not None]
        if out:
            self._broadcast(out, "air_data_sent")
        fix = self._suite.gps_fix(t_ns) if p.gnss else None
        if fix is not None:
            m = fix2(t_ns // 1000, fix, sigma_v=p.sensors.gps.velocity_sigma_mps)
            if m is not None:
                self._broadcast([m], "gnss_sent")

    def _on_echo(self, msg: Any) -> None:
        """An echo of a listed sonar: its Measurements, from this callback (no hand-off)."""
        arrived = time.monotonic_ns()
        cpu0 = time.thread_time_ns()
        p = self.params
        sonar = self._sonars.get(int(msg.sonar_id))
        if sonar is None:
            return
        with self._lock:
            self._c["echoes"] += 1
        try:
            ranges = echo_ranges(msg.samples, float(msg.fs), self._rule).range_m
        except ValueError:
            with self._lock:
                self._count_bad("echo unreadable")
            return
        axis = np.asarray(msg.boresight_body, dtype=np.float64)
        t_us = int(msg.emit_ns or msg.stamp_ns) // 1000
        msgs = [measurement(t_us, sonar.sensor_id + ear, float(r), axis,
                            min_m=p.min_distance_m, max_m=p.max_distance_m,
                            fov_rad=math.radians(sonar.fov_deg),
                            into=self._measurements.get((sonar.sonar_id, ear)))
                for ear, r in enumerate(ranges.tolist())]
        for ear, m in enumerate(msgs):
            self._measurements[(sonar.sonar_id, ear)] = m
        if self._broadcast(msgs, "measurements_sent", "measurements_unsent"):
            with self._lock:
                self._echo_us.append((time.monotonic_ns() - arrived) / 1e3)
                self._cpu_us.append((time.thread_time_ns() - cpu0) / 1e3)
