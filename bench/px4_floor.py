"""The floor of a Python PX4 HIL node, for ``bench/bench_px4.py``: the bus in and out and PX4's
socket, no sensors and no message building.

:class:`Px4Floor` is a launchable node in :class:`drivers.mavlink.px4.Px4Hil`'s place, with
its path and nothing else: the same bus subscription (``/glider/<id>/fdm``, SENSOR QoS,
priority), the same publisher (``/glider/<id>/surfaces``, COMMAND QoS), a TCP server on the
same port that PX4 (the double) connects to, one reader thread. Each state becomes one
``HIL_SENSOR`` of fixed values with the state's time; each ``HIL_ACTUATOR_CONTROLS`` (any
bytes read) one ``SurfaceCmd`` answering the state last sent. What the node does beyond this
(its sensor model, its messages, its bookkeeping) is what this floor leaves out: no Python
node on this machine answers faster. ``added_latency_us`` is measured as the node measures
its own.
"""

from __future__ import annotations

import select
import socket
import threading
import time
from collections import deque
from typing import Any

from pymavlink.dialects.v20 import common as mavlink

from hil_bridge.bus.domain import current
from hil_bridge.bus.faults import Faults


class Px4Floor:
    """Launchable floor node (module docstring)."""

    def __init__(self, name: str, *, bus: str, vehicle_id: int = 7) -> None:
        self.name, self.bus, self.vehicle_id = name, bus, vehicle_id
        self.faults = Faults(name)
        number = current().number
        self.port = 0 if number is None else 4560 + number
        self._enc = mavlink.MAVLink(None, srcSystem=1, srcComponent=158)
        self._lock = threading.Lock()
        self._peer: socket.socket | None = None
        self._last: Any = None
        self._before = 0
        self._added: deque[float] = deque(maxlen=100_000)
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self._node: Any = None
        self._pub: Any = None

    def start(self) -> None:
        from hil_bridge.bus.messages import FdmState, SurfaceCmd
        from hil_bridge.bus.node import Node
        from hil_bridge.bus.qos import COMMAND, SENSOR

        self._listener = socket.socket()
        self._listener.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        self._listener.bind(("127.0.0.1", self.port))
        self._listener.listen(1)
        self._node = Node(self.name, bus=self.bus, faults=self.faults)
        self._pub = self._node.create_publisher(SurfaceCmd, f"/glider/{self.vehicle_id}/surfaces",
                                                qos=COMMAND)
        self._node.create_subscription(FdmState, f"/glider/{self.vehicle_id}/fdm",
                                       self._on_state, qos=SENSOR, priority=True)
        self._node.start()
        self._thread = threading.Thread(target=self.faults.guarded("link", self._loop),
                                        daemon=True)
        self._thread.start()

    def _sensor(self, msg: Any) -> bytes:
        with self._lock:
            return bytes(mavlink.MAVLink_hil_sensor_message(
                msg.stamp_ns // 1000, 0.0, 0.0, -9.8, 0.0, 0.0, 0.0, 0.2, 0.0, 0.4, 960.0, 2.4,
                400.0, 12.0, 0x1FFF, 0).pack(self._enc))

    def _on_state(self, msg: Any) -> None:
        t0 = time.monotonic_ns()
        with self._lock:
            if self._last is not None and msg.step <= self._last.step:
                return  # a tick the server sends again while it waits
            self._last, peer = msg, self._peer
        if peer is not None:
            peer.sendall(self._sensor(msg))
            self._before = time.monotonic_ns() - t0

    def _loop(self) -> None:
        from hil_bridge.bus.messages import SurfaceCmd

        while not select.select([self._listener], [], [], 0.1)[0]:
            if self._stop.is_set():
                return
        peer, _ = self._listener.accept()
        peer.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
        with self._lock:
            self._peer, last = peer, self._last
        if last is not None:
            peer.sendall(self._sensor(last))
        while not self._stop.is_set():
            ready, _, _ = select.select([peer], [], [], 0.1)
            if not ready:
                continue
            data = peer.recv(65536)
            if not data:
                break
            t_in = time.monotonic_ns()
            with self._lock:
                last = self._last
            if last is None or len(data) < 20:  # a heartbeat: nothing to answer
                continue
            self._pub.publish(SurfaceCmd(stamp_ns=last.stamp_ns, aileron=0.0, elevator=-0.15,
                                         throttle=0.0, rudder=0.0, glider_id=self.vehicle_id,
                                         step=last.step))
            self._added.append((self._before + time.monotonic_ns() - t_in) / 1e3)
        with self._lock:
            self._peer = None
        peer.close()

    def stop(self) -> None:
        self._stop.set()
        if self._thread is not None:
            self._thread.join()
        self._listener.close()
        if self._node is not None:
            self._node.stop()

    def stats(self) -> dict[str, Any]:
        from hil_bridge.bus.stats import percentiles

        return {"added_latency_us": percentiles(list(self._added))}

    def failure(self, *, final: bool = False) -> str | None:
        return self.faults.failure(final=final)
