"""The MAVLink range-finder node: a sonar's echoes as range finders of any MAVLink autopilot.

``MavlinkRangefinder(name, *, bus, link=None, ranges={...}, system=1, component=158,
heartbeat_hz=1.0)`` is a launchable node (its own process in a launch). It subscribes to the
echoes of the sonars of ``ranges`` (:class:`~drivers.mavlink.ranges.RangeFinderSpec`) and sends
each as ``DISTANCE_SENSOR`` per ear (and ``OBSTACLE_DISTANCE`` where a sonar asks), with a
``HEARTBEAT`` at ``heartbeat_hz``, on one :mod:`MAVLink link <drivers.mavlink.link>`:

- by default ``tcp://127.0.0.1:{5762 + 10 N}``: ArduPilot SITL instance N's SERIAL1 (MAVLink 2
  by default), N the run's domain number (``-I N``), connected again whenever SITL restarts;
- ``link:`` any other (a flight controller's telemetry port ``serial:///dev/ttyUSB0?baud=57600``,
  a MAVProxy output ``udp://127.0.0.1:14551``).

ArduPilot takes it as ``RNGFND1_TYPE`` 10 (MAVLink) with ``RNGFND1_ORIENT`` equal to the
orientation sent (25 for a sonar looking down) and ``PRX1_TYPE`` 2 for ``OBSTACLE_DISTANCE``
(``docs/ardupilot.md``); it logs them as ``RFND`` and ``PRX``. The ids it sends with must not
be the autopilot's own system *and* component (ArduPilot drops its own as a loop). What the
autopilot sends back is read and counted (``messages_in``), never acted on.
"""

from __future__ import annotations

import logging
import threading
import time
from dataclasses import dataclass, field
from typing import Any

from drivers.mavlink.link import MavlinkLink, mavlink, open_mavlink
from drivers.mavlink.ranges import RangeFinderSpec, RangeSender
from hil_bridge.bus.domain import current as current_domain
from hil_bridge.bus.faults import Faults
from sim_core.config import ConfigError, from_dict

__all__ = ["MavlinkRangefinder", "RangefinderParams"]

log = logging.getLogger(__name__)


@dataclass(frozen=True, slots=True)
class RangefinderParams:
    """Validated parameters of :class:`MavlinkRangefinder` (module docstring)."""

    link: str | None = None
    ranges: RangeFinderSpec = field(default_factory=RangeFinderSpec)
    system: int = 1
    component: int = 158
    heartbeat_hz: float = 1.0

    def __post_init__(self) -> None:
        if not 0 < self.heartbeat_hz <= 50:
            raise ValueError(f"heartbeat_hz: expected 0 < rate <= 50, got {self.heartbeat_hz}")


class MavlinkRangefinder:
    """Launchable MAVLink range-finder node (see the module docstring)."""

    def __init__(self, name: str, *, bus: str, **params: Any) -> None:
        self.name = name
        self.bus = bus
        self.params = from_dict(RangefinderParams, params, path=f"{name}.params")
        if self.params.link is not None:
            self.url = self.params.link
        else:
            port = current_domain().ardupilot_serial1_port  # the run's, while built
            if port is None:
                raise ConfigError(f"{name}.params.link: a private domain has no ArduPilot SITL "
                                  "port; give the link's URL (e.g. tcp://127.0.0.1:5762)")
            self.url = f"tcp://127.0.0.1:{port}"
        self.faults = Faults(name)
        self._ranges = RangeSender(self.params.ranges, name)
        self._link: MavlinkLink | None = None
        self._node: Any = None
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self._lock = threading.Lock()
        self._c = {"heartbeats_sent": 0, "autopilot_connects": 0, "autopilot_disconnects": 0}

    def start(self) -> None:
        from hil_bridge.bus.messages import SonarEcho
        from hil_bridge.bus.node import Node
        from hil_bridge.bus.qos import SENSOR

        p = self.params
        self._link = open_mavlink(self.url, system=p.system, component=p.component)
        self._node = Node(self.name, bus=self.bus, faults=self.faults)
        for sonar in p.ranges.sonars:
            self._node.create_subscription(SonarEcho, f"/sonar/{sonar.sonar_id}/echo",
                                           self._ranges.submit, qos=SENSOR)
        self._ranges.start(self._link, self.faults)
        self._node.start()
        self._thread = threading.Thread(target=self.faults.guarded("MAVLink link", self._loop),
                                        name=f"{self.name}-link", daemon=True)
        self._thread.start()
        log.info("%s: range finders of sonar(s) %s on %s", self.name,
                 [s.sonar_id for s in p.ranges.sonars], self.url)

    def stop(self) -> None:
        self._stop.set()
        if self._thread is not None:
            self._thread.join()
            self._thread = None
        self._ranges.stop()
        if self._node is not None:
            self._node.stop()
            self._node = None
        if self._link is not None:
            self._link.close()

    def stats(self) -> dict[str, Any]:
        with self._lock:
            out: dict[str, Any] = dict(self._c)
        out["url"] = self.url
        out.update(self._ranges.counters())
        if self._link is not None:
            out["link"] = self._link.stats()
        return out

    def failure(self, *, final: bool = False) -> str | None:
        """Why the node failed (its link thread, the range thread or a bus callback), or
        None."""
        return self.faults.failure(final=final)

    def _loop(self) -> None:
        """Keep the link up, read (and drop) what the autopilot says, beat the heart."""
        link = self._link
        assert link is not None
        period = 1.0 / self.params.heartbeat_hz
        next_beat = time.monotonic()
        was = False
        while not self._stop.is_set():
            link.recv(min(0.1, max(0.0, next_beat - time.monotonic())))
            if link.connected != was:
                was = link.connected
                with self._lock:
                    self._c["autopilot_connects" if was else "autopilot_disconnects"] += 1
                log.info("%s: autopilot %s on %s", self.name,
                         "connected" if was else "gone", self.url)
            if time.monotonic() >= next_beat:
                next_beat = time.monotonic() + period
                if link.connected and link.send(mavlink.MAVLink_heartbeat_message(
                        mavlink.MAV_TYPE_GENERIC, mavlink.MAV_AUTOPILOT_INVALID, 0, 0,
                        mavlink.MAV_STATE_ACTIVE, 3)):
                    with self._lock:
                        self._c["heartbeats_sent"] += 1
