"""Live view: a Foxglove WebSocket server (foxglove-sdk) on loopback showing the bus.

Off by default; ``echoloop launch FILE --live`` or ``live: true`` in a launch file starts it
(open https://app.foxglove.dev, "Open connection", ``ws://127.0.0.1:8765`` in domain 0,
``8765 + 10 N`` in domain N, :mod:`hil_bridge.bus.domain`). Topics served:

- ``/live/gliders`` (``foxglove.SceneUpdate``): one arrow per glider/vehicle at its pose (world
  frame ``world``, ENU metres) and attitude (:func:`hil_bridge.bus.messages.state_quaternion`:
  the state's quaternion, or for a publisher that gives none the attitude the flight model
  gives a glider at its heading, bank and airspeed, as every exporter does), dead gliders grey;
- ``/live/beams`` (``SceneUpdate``): the beam of each sonar's latest echo, a translucent cone
  ``beam_length_m`` long from the sonar's position at emission along its boresight, as wide as
  the ping's beamwidth;
- ``/live/trails`` (``SceneUpdate``): the last ``trail_points`` positions of each vehicle;
- ``/live/thermals`` (``SceneUpdate``): a translucent cylinder per thermal (radius R, 200 m);
- ``/live/forest`` (``foxglove.PointCloud``): the server's ``/forest/points`` leaf centres
  (already decimated by the server to ``forest_points``);
- ``/live/echo/<sonar id>`` (JSON): every ``echo_every``-th echo, its envelope decimated to at
  most ``echo_points`` samples (``range_m``, ``amplitude``) for a Plot panel.

It reads the bus with one raw prefix subscription per family (``/glider/``, ``/thermals``,
``/forest/``, ``/sonar/``), so it sees gliders it was not told about (and each ping's
beamwidth, for its echo's cone). Scene updates are sent at
``rate_hz`` (wall clock). The server binds 127.0.0.1 only: ``host`` must be a loopback address.
"""

from __future__ import annotations

import math
import threading
import time
from collections import deque
from typing import Any

import numpy as np
from numpy.typing import NDArray

from hil_bridge.bus.faults import Faults
from sim_core.pose import quat_between

__all__ = ["LiveView", "beam_cone"]

#: pings remembered per sonar topic, to find the beamwidth of an echo's ping
_PINGS_KEPT = 64


def beam_cone(
    position: NDArray[np.float64], boresight: NDArray[np.float64], beamwidth: float,
    length: float,
) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64]]:
    """A beam as a cone for a Foxglove ``CylinderPrimitive`` with ``bottom_scale = 0``: the
    cylinder's centre (3,) m, its orientation (4,) ``[w, x, y, z]`` (local +z along the
    boresight, so the apex, at local −z, sits at ``position``) and its size (3,) m (the base is
    ``2 length tan(beamwidth / 2)`` across, at the −3 dB edge)."""
    axis = np.asarray(boresight, dtype=np.float64)
    axis = axis / np.linalg.norm(axis)
    centre = np.asarray(position, dtype=np.float64) + axis * (length / 2.0)
    width = 2.0 * length * math.tan(beamwidth / 2.0)
    return centre, quat_between([0.0, 0.0, 1.0], axis), np.array([width, width, length])


class LiveView:
    """Launchable Foxglove bridge: ``LiveView(name, *, bus, host="127.0.0.1", port=None,
    rate_hz=10.0, trail_points=200, echo_every=1, echo_points=2000, beam_length_m=3.0)``.

    ``port`` None is the domain's live-view port; ``port=0`` picks a free port (read
    :attr:`port` after :meth:`start`).
    """

    def __init__(
        self,
        name: str,
        *,
        bus: str,
        host: str = "127.0.0.1",
        port: int | None = None,
        rate_hz: float = 10.0,
        trail_points: int = 200,
        echo_every: int = 1,
        echo_points: int = 2000,
        beam_length_m: float = 3.0,
    ) -> None:
        from hil_bridge.bus.domain import current as current_domain
        from hil_bridge.bus.security import is_loopback_host

        if port is None:
            port = current_domain().live_port
        if not is_loopback_host(host):
            raise ValueError(f"host: the live view binds loopback only, got {host!r}")
        if not 0 <= port <= 65535:
            raise ValueError(f"port: expected 0..65535, got {port}")
        if not rate_hz > 0:
            raise ValueError(f"rate_hz: expected > 0, got {rate_hz}")
        if not beam_length_m > 0:
            raise ValueError(f"beam_length_m: expected > 0, got {beam_length_m}")
        if trail_points < 2 or echo_every < 1 or echo_points < 2:
            raise ValueError(
                "trail_points >= 2, echo_every >= 1 and echo_points >= 2 expected, got "
                f"{trail_points}, {echo_every}, {echo_points}"
            )
        self.name = name
        self.bus = bus
        self.host = host
        self.requested_port = port
        self.period_s = 1.0 / rate_hz
        self.trail_points = trail_points
        self.echo_every = echo_every
        self.echo_points = echo_points
        self.beam_length_m = beam_length_m
        self.port: int | None = None
        self._server: Any = None
        self._ctx: Any = None
        self._channels: dict[str, Any] = {}
        self._transport: Any = None
        self._stop = threading.Event()
        self._threads: list[threading.Thread] = []
        self._lock = threading.Lock()
        self._poses: dict[int, tuple[float, float, float, NDArray[np.float64], bool]] = {}
        self._beamwidths: dict[str, dict[int, float]] = {}
        self._beams: dict[str, tuple[NDArray[np.float64], NDArray[np.float64], float]] = {}
        self._trails: dict[int, deque[tuple[float, float, float]]] = {}
        self._thermals: Any = None
        self._thermals_dirty = False
        self._forest: Any = None
        self._echo_count = 0
        self._c = {"received": 0, "bad": 0, "scene_updates": 0, "echoes_sent": 0,
                   "forest_sent": 0, "thermals_sent": 0, "beams_sent": 0}
        #: its threads' end by an exception (a failure of the run)
        self.faults = Faults(name)

    # ------------------------------------------------------------------ launchable contract

    def start(self) -> None:
        import foxglove
        from foxglove.channels import PointCloudChannel, SceneUpdateChannel

        from hil_bridge.bus.transport import open_transport

        self._ctx = foxglove.Context()
        self._channels = {
            "gliders": SceneUpdateChannel("/live/gliders", context=self._ctx),
            "trails": SceneUpdateChannel("/live/trails", context=self._ctx),
            "beams": SceneUpdateChannel("/live/beams", context=self._ctx),
            "thermals": SceneUpdateChannel("/live/thermals", context=self._ctx),
            "forest": PointCloudChannel("/live/forest", context=self._ctx),
        }
        self._server = foxglove.start_server(
            name=f"echoloop {self.name}", host=self.host, port=self.requested_port,
            context=self._ctx,
        )
        self.port = int(self._server.port)
        self._transport = open_transport(self.bus)
        for prefix in (b"/glider/", b"/thermals\0", b"/forest/points\0", b"/sonar/"):
            self._transport.subscribe(prefix)
        self._threads = [
            threading.Thread(target=self.faults.guarded("receive loop", self._rx_loop),
                             name=f"{self.name}-rx", daemon=True),
            threading.Thread(target=self.faults.guarded("send loop", self._send_loop),
                             name=f"{self.name}-send", daemon=True),
        ]
        for t in self._threads:
            t.start()

    def stop(self) -> None:
        self._stop.set()
        if self._transport is not None:
            self._transport.wakeup()
        for t in self._threads:
            t.join()
        self._threads = []
        if self._transport is not None:
            self._transport.close()
            self._transport = None
        if self._server is not None:
            self._server.stop()
            self._server = None

    def poses(self) -> dict[int, tuple[float, float, float, NDArray[np.float64], bool]]:
        """The vehicles as ``/live/gliders`` draws them: id -> ``(x, y, z, quat, alive)``
        (``quat`` world-from-body ``[w, x, y, z]``)."""
        with self._lock:
            return dict(self._poses)

    def failure(self, *, final: bool = False) -> str | None:
        """Why the live view failed (one of its threads died), or None."""
        return self.faults.failure(final=final)

    def stats(self) -> dict[str, Any]:
        with self._lock:
            out: dict[str, Any] = dict(self._c)
            out["vehicles"] = len(self._poses)
        out["port"] = self.port
        return out

    # ------------------------------------------------------------------ bus side

    def _rx_loop(self) -> None:
        from hil_bridge.bus.codec import decode
        from hil_bridge.bus.messages import (
            GliderState,
            PointCloud,
            SonarEcho,
            SonarPing,
            ThermalMarkers,
            state_quaternion,
        )
        from hil_bridge.errors import CodecError, HilError

        while not self._stop.is_set():
            try:
                frames = self._transport.recv(timeout=0.1)
            except HilError:
                return
            if frames is None:
                continue
            try:
                envelope = decode(frames)
            except CodecError:
                with self._lock:
                    self._c["bad"] += 1
                continue
            topic = envelope.topic
            msg: Any = envelope.msg
            parts = topic.split("/")
            with self._lock:
                self._c["received"] += 1
                # a foreign type or non-numeric id under these topics is received, not shown
                if (isinstance(msg, GliderState) and parts[1] == "glider"
                        and parts[-1] == "state" and parts[2].isdigit()):
                    gid = int(parts[2])
                    self._poses[gid] = (msg.x, msg.y, msg.z, state_quaternion(msg), msg.alive)
                    trail = self._trails.setdefault(gid, deque(maxlen=self.trail_points))
                    if not trail or math.dist(trail[-1], (msg.x, msg.y, msg.z)) > 0.05:
                        trail.append((msg.x, msg.y, msg.z))
                elif isinstance(msg, ThermalMarkers) and topic == "/thermals":
                    self._thermals, self._thermals_dirty = msg, True
                elif isinstance(msg, PointCloud) and topic == "/forest/points":
                    self._forest = msg
                elif (isinstance(msg, SonarPing) and parts[1] == "sonar"
                      and parts[-1] == "ping"):
                    widths = self._beamwidths.setdefault(topic[: -len("/ping")], {})
                    widths[int(msg.ping_seq)] = float(msg.beamwidth)
                    while len(widths) > _PINGS_KEPT:
                        del widths[next(iter(widths))]
                elif (isinstance(msg, SonarEcho) and parts[1] == "sonar"
                      and parts[-1] == "echo"):
                    self._note_beam(topic[: -len("/echo")], msg)
                    self._echo_count += 1
                    if (self._echo_count - 1) % self.echo_every == 0:
                        self._send_echo(topic, msg)

    def _note_beam(self, sonar: str, msg: Any) -> None:
        """Keep the beam of an echo whose sonar pose and ping beamwidth are known."""
        width = self._beamwidths.get(sonar, {}).get(int(msg.ping_seq))
        pos, axis = np.asarray(msg.position), np.asarray(msg.boresight)
        if width is not None and np.all(np.isfinite(pos)) and np.all(np.isfinite(axis)):
            self._beams[sonar] = (pos, axis, width)

    # ------------------------------------------------------------------ foxglove side

    def _send_echo(self, topic: str, msg: Any) -> None:
        import foxglove

        key = "echo" + topic[len("/sonar"):-len("/echo")]
        channel = self._channels.get(key)
        if channel is None:
            channel = self._channels[key] = foxglove.Channel(
                f"/live/echo/{key[5:]}", message_encoding="json", context=self._ctx
            )
        samples = np.asarray(msg.samples, dtype=np.float64).reshape(-1, msg.samples.shape[-1])[0]
        step = max(1, math.ceil(samples.size / self.echo_points))
        n = samples.size // step
        env = np.abs(samples[: n * step]).reshape(n, step).max(axis=1)
        range_m = (np.arange(n) * step / msg.fs * 340.0 / 2.0)
        channel.log({
            "ping_seq": int(msg.ping_seq), "leaves_in_beam": int(msg.leaves_in_beam),
            "range_m": range_m.round(4).tolist(), "amplitude": env.tolist(),
        })
        self._c["echoes_sent"] += 1

    def _send_loop(self) -> None:
        from foxglove.messages import (
            ArrowPrimitive,
            Color,
            CylinderPrimitive,
            LinePrimitive,
            PackedElementField,
            PackedElementFieldNumericType,
            Point3,
            PointCloud,
            Pose,
            Quaternion,
            SceneEntity,
            SceneUpdate,
            Vector3,
        )

        forest_sent: Any = None
        resend_every = max(1, round(2.0 / self.period_s))  # latched data again every ~2 s
        tick = 0
        next_t = time.monotonic()
        while not self._stop.wait(max(0.0, next_t - time.monotonic())):
            next_t += self.period_s
            tick += 1
            if tick % resend_every == 0:  # so a viewer that connects later gets them too
                forest_sent = None
                with self._lock:
                    self._thermals_dirty = self._thermals is not None
            with self._lock:
                poses = dict(self._poses)
                beams = dict(self._beams)
                trails = {g: list(t) for g, t in self._trails.items()}
                thermals = self._thermals if self._thermals_dirty else None
                self._thermals_dirty = False
                forest = self._forest
            arrows = []
            for gid, (x, y, z, q, alive) in sorted(poses.items()):
                qw, qx, qy, qz = (float(v) for v in q)
                color = Color(r=0.1, g=0.5, b=0.9, a=1.0) if alive else Color(r=0.5, g=0.5,
                                                                                b=0.5, a=0.6)
                arrows.append(SceneEntity(
                    frame_id="world", id=f"glider/{gid}", arrows=[ArrowPrimitive(
                        pose=Pose(position=Vector3(x=x, y=y, z=z),
                                  orientation=Quaternion(x=qx, y=qy, z=qz, w=qw)),
                        shaft_length=3.0, shaft_diameter=0.6, head_length=1.5,
                        head_diameter=1.5, color=color)],
                ))
            self._channels["gliders"].log(SceneUpdate(entities=arrows))
            lines = [
                SceneEntity(frame_id="world", id=f"trail/{gid}", lines=[LinePrimitive(
                    thickness=2.0, scale_invariant=True, color=Color(r=1.0, g=0.6, b=0.1, a=0.8),
                    points=[Point3(x=p[0], y=p[1], z=p[2]) for p in pts])])
                for gid, pts in sorted(trails.items()) if len(pts) >= 2
            ]
            self._channels["trails"].log(SceneUpdate(entities=lines))
            cones = []
            for sonar, (pos, axis, width) in sorted(beams.items()):
                c, qc, size = (
                    [float(v) for v in a]
                    for a in beam_cone(pos, axis, width, self.beam_length_m)
                )
                cones.append(SceneEntity(frame_id="world", id=f"beam{sonar}", cylinders=[
                    CylinderPrimitive(
                        pose=Pose(position=Vector3(x=c[0], y=c[1], z=c[2]),
                                  orientation=Quaternion(w=qc[0], x=qc[1], y=qc[2], z=qc[3])),
                        size=Vector3(x=size[0], y=size[1], z=size[2]), bottom_scale=0.0,
                        top_scale=1.0, color=Color(r=0.2, g=0.9, b=0.3, a=0.25))]))
            self._channels["beams"].log(SceneUpdate(entities=cones))
            with self._lock:
                self._c["scene_updates"] += 1
                self._c["beams_sent"] += len(cones)
            if thermals is not None:
                cylinders = [
                    CylinderPrimitive(
                        pose=Pose(position=Vector3(x=float(x), y=float(y), z=100.0)),
                        size=Vector3(x=2 * float(r), y=2 * float(r), z=200.0),
                        bottom_scale=1.0, top_scale=1.0, color=Color(r=1.0, g=0.4, b=0.0, a=0.2))
                    for x, y, r in zip(thermals.x, thermals.y, thermals.radius, strict=True)
                ]
                self._channels["thermals"].log(SceneUpdate(entities=[
                    SceneEntity(frame_id="world", id="thermals", cylinders=cylinders)]))
                with self._lock:
                    self._c["thermals_sent"] += 1
            if forest is not None and forest is not forest_sent:
                pts = np.ascontiguousarray(forest.points, dtype=np.float32)
                self._channels["forest"].log(PointCloud(
                    frame_id="world", pose=Pose(position=Vector3(), orientation=Quaternion(w=1.0)),
                    point_stride=12, data=pts.tobytes(),
                    fields=[PackedElementField(name=n, offset=4 * i,
                                               type=PackedElementFieldNumericType.Float32)
                            for i, n in enumerate("xyz")],
                ))
                forest_sent = forest
                with self._lock:
                    self._c["forest_sent"] += 1
