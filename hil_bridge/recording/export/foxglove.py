"""A recording with Foxglove's well-known schemas (``bag export IN --foxglove OUT.mcap``), so
Foxglove's 3D panel draws it as the live view does and its Plot panel plots the echoes.

- ``/tf`` (``foxglove.FrameTransforms``): ``world`` → ``glider_<id>`` for every state;
- ``/gliders`` (``foxglove.SceneUpdate``): an arrow per glider at its pose (grey once dead),
  at most every 0.1 s of sim time;
- ``/thermals`` (``SceneUpdate``): a translucent cylinder per thermal (radius, 200 m tall);
- ``/sonar/<id>/beam`` (``SceneUpdate``): each ping's −3 dB cone at the sonar pose, out to
  the echo's range;
- ``/forest/points`` (``foxglove.PointCloud``): leaf centres, ``intensity`` = leaf radius (m);
- ``/sonar/<id>/echo`` (JSON with a JSON Schema): ``ping_seq``, ``leaves_in_beam``,
  ``peak_db`` and the envelope (``range_m[]``, ``envelope_db[]`` in dB re A0, max-pooled to at
  most 2000 points) for the Plot panel.

Frames: world ENU (``world``), bodies FLU. Timestamps inside messages are sim time; the MCAP
``log_time`` is the recorded receive time. Other topics are counted as skipped.
"""

from __future__ import annotations

import json
import math
import os
from pathlib import Path
from typing import Any

import numpy as np
from mcap.writer import CompressionType, Writer

from hil_bridge.bus.messages import (
    GliderState,
    PointCloud,
    SonarEcho,
    SonarPing,
    ThermalMarkers,
    state_quaternions,
)
from hil_bridge.outputs import atomic_output
from hil_bridge.recording.export.common import (
    STATE_TOPIC,
    ExportCounts,
    batches,
    decoded,
    mount_id,
    sonar_pose,
)
from sim_core.pose import quat_from_euler, quat_multiply

__all__ = ["ECHO_POINTS", "WORLD", "export_foxglove"]

WORLD = "world"
ECHO_POINTS = 2000
GLIDER_PERIOD_NS = 100_000_000
THERMAL_HEIGHT_M = 200.0
_SOUND_SPEED = 340.0
_ECHO_SCHEMA = {
    "type": "object",
    "title": "echoloop.EchoEnvelope",
    "description": "echo envelope for plotting: dB re the emitted amplitude A0 at 1 m",
    "properties": {
        "stamp_ns": {"type": "integer"}, "sonar_id": {"type": "integer"},
        "ping_seq": {"type": "integer"}, "leaves_in_beam": {"type": "integer"},
        "fs": {"type": "number"}, "peak": {"type": "number"}, "peak_db": {"type": "number"},
        "range_m": {"type": "array", "items": {"type": "number"}},
        "envelope_db": {"type": "array", "items": {"type": "number"}},
    },
}


def _fx() -> Any:
    import foxglove.messages as fx

    return fx


def _time(ns: int) -> Any:
    return _fx().Timestamp(sec=ns // 1_000_000_000, nsec=ns % 1_000_000_000)


def _pose(p: Any, q: Any) -> Any:
    fx = _fx()
    return fx.Pose(position=fx.Vector3(x=float(p[0]), y=float(p[1]), z=float(p[2])),
                   orientation=fx.Quaternion(x=float(q[1]), y=float(q[2]), z=float(q[3]),
                                             w=float(q[0])))


class _Mcap:
    def __init__(self, stream: Any) -> None:
        self.writer = Writer(stream, chunk_size=1024 * 1024, compression=CompressionType.ZSTD)
        self.writer.start(profile="", library="echoloop hil_bridge.recording.export.foxglove")
        self.channels: dict[str, int] = {}
        self.schemas: dict[str, int] = {}

    def _channel(self, topic: str, schema: tuple[str, str, bytes], encoding: str) -> int:
        cid = self.channels.get(topic)
        if cid is None:
            sid = self.schemas.get(schema[0])
            if sid is None:
                sid = self.schemas[schema[0]] = self.writer.register_schema(*schema)
            cid = self.channels[topic] = self.writer.register_channel(topic, encoding, sid)
        return cid

    def proto(self, topic: str, msg: Any, log_time: int, stamp_ns: int) -> None:
        s = type(msg).get_schema()
        cid = self._channel(topic, (s.name, s.encoding, bytes(s.data)), "protobuf")
        self.writer.add_message(cid, log_time=log_time, data=bytes(msg.encode()),
                                publish_time=max(0, stamp_ns))

    def json(self, topic: str, obj: dict[str, Any], log_time: int, stamp_ns: int) -> None:
        schema = ("echoloop.EchoEnvelope", "jsonschema", json.dumps(_ECHO_SCHEMA).encode())
        cid = self._channel(topic, schema, "json")
        self.writer.add_message(cid, log_time=log_time, publish_time=max(0, stamp_ns),
                                data=json.dumps(obj, allow_nan=False).encode())


def _glider_entity(gid: int, st: GliderState, q: Any) -> Any:
    fx = _fx()
    color = fx.Color(r=0.1, g=0.45, b=0.9, a=1.0) if st.alive else fx.Color(r=0.5, g=0.5,
                                                                            b=0.5, a=0.6)
    arrow = fx.ArrowPrimitive(pose=_pose((st.x, st.y, st.z), q),
                              shaft_length=3.0, shaft_diameter=0.6, head_length=1.5,
                              head_diameter=1.5, color=color)
    return fx.SceneEntity(timestamp=_time(st.stamp_ns), frame_id=WORLD, id=f"glider_{gid}",
                          arrows=[arrow])


def _thermals(th: ThermalMarkers) -> Any:
    fx = _fx()
    cylinders = [fx.CylinderPrimitive(
        pose=_pose((th.x[k], th.y[k], THERMAL_HEIGHT_M / 2), (1.0, 0.0, 0.0, 0.0)),
        size=fx.Vector3(x=2 * float(th.radius[k]), y=2 * float(th.radius[k]), z=THERMAL_HEIGHT_M),
        bottom_scale=1.0, top_scale=1.0, color=fx.Color(r=1.0, g=0.55, b=0.0, a=0.25))
        for k in range(len(th.x))]
    return fx.SceneUpdate(entities=[fx.SceneEntity(timestamp=_time(th.stamp_ns), frame_id=WORLD,
                                                   id="thermals", cylinders=cylinders)])


def _beam(echo: SonarEcho, ping: Any, pose: Any) -> Any:
    """The ping's -3 dB cone (apex at the sonar, axis along the boresight) out to the echo's
    range ``samples / fs * c / 2``."""
    fx = _fx()
    length = echo.samples.shape[-1] / echo.fs * _SOUND_SPEED / 2.0
    bw = float(ping.beamwidth) if ping is not None else math.radians(30.0)
    diameter = 2.0 * length * math.tan(bw / 2.0)
    # the cylinder's axis is its z: turn z onto the sonar's x (boresight), apex at min z
    q = quat_multiply(pose.orientation, quat_from_euler(0.0, math.pi / 2, 0.0))
    centre = pose.position + pose.boresight * length / 2.0
    cone = fx.CylinderPrimitive(pose=_pose(centre, q),
                                size=fx.Vector3(x=diameter, y=diameter, z=length),
                                bottom_scale=0.0, top_scale=1.0,
                                color=fx.Color(r=0.9, g=0.1, b=0.1, a=0.2))
    return fx.SceneUpdate(entities=[fx.SceneEntity(
        timestamp=_time(echo.stamp_ns), frame_id=WORLD, id=f"beam_{echo.sonar_id}",
        cylinders=[cone])])


def _point_cloud(pc: PointCloud) -> Any:
    fx = _fx()
    n = pc.points.shape[0]
    packed = np.zeros((n, 4), dtype="<f4")
    packed[:, :3] = pc.points
    if pc.intensity.size:
        packed[:, 3] = pc.intensity
    f32 = fx.PackedElementFieldNumericType.Float32
    fields = [fx.PackedElementField(name=name, offset=4 * i, type=f32)
              for i, name in enumerate(("x", "y", "z", "intensity"))]
    return fx.PointCloud(timestamp=_time(pc.stamp_ns), frame_id=WORLD,
                         pose=_pose((0, 0, 0), (1.0, 0.0, 0.0, 0.0)), point_stride=16,
                         fields=fields, data=packed.tobytes())


def _envelope(echo: SonarEcho) -> dict[str, Any]:
    from sim_core.sonar.baseband import envelope_db

    x = np.atleast_2d(echo.samples).astype(np.float64)[0]
    n = x.size
    edges = np.linspace(0, n, min(ECHO_POINTS, n) + 1).astype(np.intp)
    db = np.maximum.reduceat(envelope_db(x, floor_db=-300.0), edges[:-1]) if n else x
    centre = (edges[:-1] + edges[1:]) / 2.0
    peak = float(np.max(np.abs(x))) if n else 0.0
    return {
        "stamp_ns": echo.stamp_ns, "sonar_id": echo.sonar_id, "ping_seq": echo.ping_seq,
        "leaves_in_beam": echo.leaves_in_beam, "fs": echo.fs, "peak": peak,
        "peak_db": float(db.max()) if n else -300.0,
        "range_m": np.round(centre / echo.fs * _SOUND_SPEED / 2.0, 4).tolist(),
        "envelope_db": np.round(db, 2).tolist(),
    }


def export_foxglove(src: str | os.PathLike[str], dst: str | os.PathLike[str], *,
                    overwrite: bool = False) -> ExportCounts:
    """Write ``dst`` from the recording ``src`` (module docstring)."""
    counts = ExportCounts()
    with atomic_output(Path(dst), overwrite=overwrite, inputs=[src]) as tmp, \
            open(tmp, "wb") as fh:
        out = _Writer(fh, counts)
        for batch in batches(decoded(src, counts)):
            states = [d.msg for d in batch if isinstance(d.msg, GliderState)]
            quats = iter(state_quaternions(states))
            for d in batch:
                if isinstance(d.msg, GliderState):
                    out.state(d, next(quats))
                else:
                    out.other(d)
        out.mcap.writer.finish()
    return counts


class _Writer:
    """The export's state: last pose per glider, pings by (sonar, seq), glider update time."""

    def __init__(self, stream: Any, counts: ExportCounts) -> None:
        self.mcap = _Mcap(stream)
        self.counts = counts
        self.last: dict[int, tuple[GliderState, Any]] = {}
        self.pings: dict[tuple[int, int], Any] = {}
        self.next_gliders = 0

    def state(self, d: Any, q: Any) -> None:
        fx = _fx()
        msg, log_t = d.msg, d.raw.log_time
        hit = STATE_TOPIC.match(d.topic)
        gid = int(hit.group(1)) if hit else msg.glider_id
        self.last[gid] = (msg, q)
        tf = fx.FrameTransform(timestamp=_time(msg.stamp_ns), parent_frame_id=WORLD,
                               child_frame_id=f"glider_{gid}",
                               translation=fx.Vector3(x=msg.x, y=msg.y, z=msg.z),
                               rotation=fx.Quaternion(x=q[1], y=q[2], z=q[3], w=q[0]))
        self.mcap.proto("/tf", fx.FrameTransforms(transforms=[tf]), log_t, msg.stamp_ns)
        self.counts.written += 1
        if msg.stamp_ns >= self.next_gliders:
            entities = [_glider_entity(g, s, sq) for g, (s, sq) in sorted(self.last.items())]
            self.mcap.proto("/gliders", fx.SceneUpdate(entities=entities), log_t, msg.stamp_ns)
            self.next_gliders = msg.stamp_ns + GLIDER_PERIOD_NS
            self.counts.written += 1

    def other(self, d: Any) -> None:
        msg, log_t, topic = d.msg, d.raw.log_time, d.topic
        if isinstance(msg, ThermalMarkers):
            self.mcap.proto(topic, _thermals(msg), log_t, msg.stamp_ns)
        elif isinstance(msg, PointCloud):
            self.mcap.proto(topic, _point_cloud(msg), log_t, msg.stamp_ns)
        elif isinstance(msg, SonarPing):
            self.pings[(msg.sonar_id, msg.ping_seq)] = msg
            self.counts.skip("pings (drawn with their echo's beam)")
            return
        elif isinstance(msg, SonarEcho):
            ping = self.pings.get((msg.sonar_id, msg.ping_seq))
            mount = mount_id(d.raw.header.frame_id)
            state = self.last.get(mount) if mount is not None else None
            pose = sonar_pose(msg, ping, None if state is None else state[0])
            if pose is not None:
                self.mcap.proto(f"/sonar/{msg.sonar_id}/beam", _beam(msg, ping, pose), log_t,
                                msg.stamp_ns)
                self.counts.written += 1
            self.mcap.json(topic, _envelope(msg), log_t, msg.stamp_ns)
        else:
            self.counts.skip(f"no Foxglove schema for {d.raw.header.type}")
            return
        self.counts.written += 1
