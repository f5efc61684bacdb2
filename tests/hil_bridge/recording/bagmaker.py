"""Write small echoloop recordings from message lists (for reader, plot and export tests), and
read a Foxglove export back."""

from __future__ import annotations

import json
from collections.abc import Iterable
from pathlib import Path
from typing import Any

import numpy as np
from mcap.well_known import MessageEncoding

from hil_bridge.bus.codec import Header, encode_payload
from hil_bridge.bus.messages import (
    Clock,
    GliderCmd,
    GliderState,
    Message,
    PointCloud,
    SonarEcho,
    SonarPing,
    ThermalMarkers,
)
from hil_bridge.recording.bag_writer import BagWriter


def write_bag(path: Path, messages: Iterable[tuple[str, Message, str]]) -> Path:
    """``(topic, message, frame_id)`` in order; log time = stamp + 1 ms, seq per topic."""
    seqs: dict[str, int] = {}
    with open(path, "wb") as f:
        bag = BagWriter(f, chunk_size=64 * 1024, compression="zstd",
                         message_encoding=MessageEncoding.MessagePack, as_json=False)
        for topic, msg, frame in messages:
            seq = seqs.get(topic, 0)
            seqs[topic] = seq + 1
            stamp = int(getattr(msg, "stamp_ns", 0))
            hdr = Header(msg.TYPE, msg.VERSION, seq, stamp, 0, frame, "test#1")
            bag.add(topic, hdr, encode_payload(msg), 1_700_000_000_000_000_000 + stamp + 10**6)
        bag.writer.finish()
    return path


def demo_messages(steps: int = 20, gliders: tuple[int, ...] = (0, 1), sonar_mount: int | None = 9,
                  samples: int = 2000) -> list[tuple[str, Message, str]]:
    """A small run: /clock, glider states and commands, thermals, forest points, pings and
    echoes of a sonar on vehicle ``sonar_mount`` (None: no sonar)."""
    rng = np.random.default_rng(3)
    out: list[tuple[str, Message, str]] = []
    out.append(("/thermals", ThermalMarkers(stamp_ns=0, x=[100.0, -50.0], y=[0.0, 80.0],
                                            radius=[60.0, 40.0], w_max=[3.0, 2.5]), ""))
    if sonar_mount is not None:
        pts = rng.uniform(-5, 5, size=(500, 3)).astype(np.float32)
        out.append(("/forest/points", PointCloud(stamp_ns=0, points=pts,
                                                 intensity=np.full(500, 0.02, np.float32),
                                                 label="leaves"), ""))
    ids = (*gliders, *(() if sonar_mount is None else (sonar_mount,)))
    for k in range(steps):
        t = k * 100_000_000
        out.append(("/clock", Clock(stamp_ns=t), ""))
        for gid in ids:
            out.append((f"/glider/{gid}/state", GliderState(
                stamp_ns=t, x=10.0 * k + gid, y=5.0 * gid, z=100.0 - 0.5 * k,
                heading=0.05 * k + 0.3 * gid, bank=0.2, airspeed=11.0, vz=-0.5, glider_id=gid,
                step=k), ""))
        if gliders:
            out.append((f"/glider/{gliders[0]}/cmd", GliderCmd(
                stamp_ns=t, bank_cmd=0.25, airspeed_cmd=11.5, glider_id=gliders[0], step=k), ""))
        if sonar_mount is not None and k % 5 == 0:
            seq = k // 5
            out.append(("/sonar/0/ping", SonarPing(stamp_ns=t, ping_seq=seq, az=0.1, el=-0.05,
                                                   beamwidth=0.6, encoding=2), ""))
            x = rng.normal(0, 1e-3, size=samples).astype(np.float32)
            out.append(("/sonar/0/echo", SonarEcho(
                stamp_ns=t + 20_000_000, ping_seq=seq, fs=400e3, samples=x,
                leaves_in_beam=100 + seq, fidelity="fast", error_bound=3e-4,
                compute_ns=1_000_000), f"glider/{sonar_mount}"))
    return out


def read_foxglove(path: Path) -> dict[str, list[tuple[str, Any]]]:
    """A Foxglove export's messages per topic as ``(schema name, decoded value)``: protobuf
    through the schemas embedded in the file (mcap-protobuf-support), JSON parsed."""
    from mcap.reader import make_reader
    from mcap_protobuf.decoder import DecoderFactory

    factory = DecoderFactory()
    out: dict[str, list[tuple[str, Any]]] = {}
    with open(path, "rb") as f:
        reader = make_reader(f)
        for schema, channel, message in reader.iter_messages():
            if channel.message_encoding == "json":
                assert schema.encoding == "jsonschema"
                value = json.loads(message.data)
            else:
                assert (channel.message_encoding, schema.encoding) == ("protobuf", "protobuf")
                decode = factory.decoder_for("protobuf", schema)
                value = decode(message.data)
            out.setdefault(channel.topic, []).append((schema.name, value))
    return out
