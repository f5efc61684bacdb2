"""MCAP record/replay: round trip byte-identical, SIGKILL-truncated files, info, JSON export."""

from __future__ import annotations

import json
import math
import os
import signal
import subprocess
import sys
import textwrap
import threading
import time
from pathlib import Path

import numpy as np
import pytest
from mcap.reader import make_reader

from hil_bridge.bus.codec import decode, decode_payload, encode
from hil_bridge.bus.messages import Clock, GliderState, SonarEcho
from hil_bridge.bus.node import Node
from hil_bridge.bus.proxy import Proxy
from hil_bridge.bus.qos import SENSOR, QoSProfile
from hil_bridge.bus.transport import open_transport
from hil_bridge.cli.bag import main as bag_main
from hil_bridge.recording.bag import bag_info, read_bag
from hil_bridge.recording.bag_player import Player
from hil_bridge.recording.recorder import Recorder
from tests.hil_bridge.bus.bus_test_util import poll_until

WAIT = 20.0


def _state(i: int) -> GliderState:
    return GliderState(stamp_ns=1_000 + i * 4_000_000, x=float(i), y=-1.0, z=120.0,
                       heading=0.1, bank=0.0, airspeed=9.5, vz=-0.6, glider_id=0)


def _echo(i: int) -> SonarEcho:
    samples = np.linspace(-1, 1, 64, dtype=np.float32).reshape(2, 32) * i
    return SonarEcho(stamp_ns=2_000 + i, ping_seq=i, fs=200e3, samples=samples,
                     leaves_in_beam=i, fidelity="fast", error_bound=math.nan)


def _record_sample(bus: str, path: Path, n: int = 40) -> None:
    rec = Recorder(path, bus=bus, chunk_size=4096)
    rec.start()
    try:
        with Node("src", bus=bus, diagnostics_period_s=0) as node:
            states = node.create_publisher(GliderState, "/glider/0/state", SENSOR,
                                           frame_id="world")
            echoes = node.create_publisher(SonarEcho, "/sonar/0/echo")
            assert states.wait_for_subscribers(WAIT) and echoes.wait_for_subscribers(WAIT)
            for i in range(n):
                states.publish(_state(i))
                if i % 4 == 0:
                    echoes.publish(_echo(i))
        assert rec.wait_for(n + n // 4, WAIT)
    finally:
        rec.stop()


def _part(path: Path) -> Path:
    """The temporary file of a recording that was never finished."""
    (part,) = path.parent.glob(f".{path.stem}.*.part{path.suffix}")
    return part


def _signature(path: Path) -> list[tuple[object, ...]]:
    return [
        (m.topic, m.header.type, m.header.v, m.header.seq, m.header.stamp_ns,
         m.header.frame_id, m.header.src, m.payload)
        for m in read_bag(path)
    ]


def test_record_play_record_is_byte_identical(bus_url: str, tmp_path: Path) -> None:
    first, second = tmp_path / "a.mcap", tmp_path / "b.mcap"
    _record_sample(bus_url, first)
    original = _signature(first)
    assert len(original) == 50
    rec = Recorder(second, bus=bus_url)
    rec.start()
    player = Player(first, bus=bus_url, rate=math.inf, wait_for_subscribers_s=WAIT)
    try:
        player.start()
        assert player.wait(WAIT)
        assert rec.wait_for(len(original), WAIT)
    finally:
        player.stop()
        rec.stop()
    assert _signature(second) == original
    assert player.stats()["published"] == len(original)
    decoded = [decode_payload(m.header.type, m.header.v, m.payload) for m in read_bag(second)]
    assert decoded[0] == _state(0) and _echo(4) in decoded


def test_sigkilled_recording_is_readable_to_its_last_chunk(tmp_path: Path) -> None:
    path = tmp_path / "killed.mcap"
    child = textwrap.dedent(f"""
        import sys, threading
        from hil_bridge.recording.recorder import Recorder
        from hil_bridge.bus.messages import Clock
        from hil_bridge.bus.node import Node
        bus = "mem://kill?depth=100000"
        rec = Recorder({str(path)!r}, bus=bus, chunk_size=2048, flush_period_s=0.02)
        rec.start()
        node = Node("src", bus=bus, diagnostics_period_s=0)
        pub = node.create_publisher(Clock, "/clock")
        for i in range(2000):
            pub.publish(Clock(stamp_ns=i))
        assert rec.wait_for(2000, 30)
        flushes = rec.stats()["flushes"]
        i = 2000
        while rec.stats()["flushes"] <= flushes:  # keep the bus busy until a flush covers 2000
            pub.publish(Clock(stamp_ns=i))
            i += 1
            threading.Event().wait(0.001)
        print("flushed", flush=True)
        while True:
            pub.publish(Clock(stamp_ns=i))
            i += 1
    """)
    proc = subprocess.Popen([sys.executable, "-c", child], stdout=subprocess.PIPE, text=True,
                            cwd=Path(__file__).resolve().parents[3])
    try:
        assert proc.stdout is not None
        assert proc.stdout.readline().strip() == "flushed"
    finally:
        os.kill(proc.pid, signal.SIGKILL)
        proc.wait(timeout=30)
    assert proc.returncode == -signal.SIGKILL
    assert not path.exists()  # never renamed: the recording is its temporary file
    path = _part(path)
    info = bag_info(path)
    assert info.truncated
    stamps = [decode_payload(m.header.type, m.header.v, m.payload).stamp_ns  # type: ignore[attr-defined]
              for m in read_bag(path)]
    assert len(stamps) >= 2000
    assert stamps == list(range(len(stamps)))
    assert info.topics["/clock"].gaps == 0


def test_info_reports_counts_rates_and_seq_gaps(tmp_path: Path) -> None:
    path = tmp_path / "gaps.mcap"
    bus = "mem://baginfo"
    rec = Recorder(path, bus=bus)
    rec.start()
    try:
        with open_transport(bus) as raw:
            for seq in (0, 1, 2, 6, 7):  # 3 messages lost between 2 and 6
                raw.publish(encode("/g", Clock(stamp_ns=seq * 10_000_000), seq=seq, pub_ns=0,
                                   src="p"))
        assert rec.wait_for(5, WAIT)
    finally:
        rec.stop()
    info = bag_info(path)
    assert not info.truncated and info.messages == 5
    st = info.topics["/g"]
    assert (st.count, st.gaps, st.lost) == (5, 1, 3)
    assert st.rate_hz == pytest.approx(4 / 0.07)
    assert bag_main(["info", str(path)]) == 0
    assert bag_main(["info", str(path), "--json"]) == 0


def test_export_json_is_foxglove_readable(tmp_path: Path) -> None:
    src, dst = tmp_path / "a.mcap", tmp_path / "a.json.mcap"
    _record_sample("mem://export", src, n=8)
    assert bag_main(["export", str(src), "--json", str(dst)]) == 0
    with open(dst, "rb") as f:
        reader = make_reader(f)
        summary = reader.get_summary()
        assert summary is not None
        assert {s.encoding for s in summary.schemas.values()} == {"jsonschema"}
        assert {c.message_encoding for c in summary.channels.values()} == {"json"}
        rows = [(c.topic, json.loads(m.data), s) for s, c, m in reader.iter_messages()]
    assert len(rows) == 10
    _topic, body, schema = next(r for r in rows if r[0] == "/sonar/0/echo")
    assert schema is not None and schema.name == "echoloop/SonarEcho"
    assert set(json.loads(schema.data)["properties"]) >= {"samples", "fs", "ping_seq"}
    assert body["error_bound"] is None  # NaN exported as null
    assert np.allclose(np.array(body["samples"], dtype=np.float32), _echo(0).samples)
    state = next(b for t, b, _ in rows if t == "/glider/0/state")
    assert state["x"] == 0.0 and state["alive"] is True


def test_play_filters_topics_publishes_clock_and_loops(tmp_path: Path) -> None:
    src, out = tmp_path / "a.mcap", tmp_path / "b.mcap"
    _record_sample("mem://playsrc", src, n=8)
    bus = "mem://playdst"
    rec = Recorder(out, bus=bus)
    rec.start()
    player = Player(src, bus=bus, rate=math.inf, loop=True, topics=["/glider/0/state"],
                    clock=True)
    try:
        player.start()
        assert rec.wait_for(40, WAIT)
    finally:
        player.stop()
        rec.stop()
    msgs = list(read_bag(out))
    topics = {m.topic for m in msgs}
    assert topics == {"/glider/0/state", "/clock"}
    srcs = {m.header.src for m in msgs if m.topic == "/glider/0/state"}
    assert any(s.endswith("~loop1") for s in srcs)  # a second pass under a new src
    clocks = [decode_payload(m.header.type, m.header.v, m.payload) for m in msgs
              if m.topic == "/clock"]
    assert clocks and all(isinstance(c, Clock) for c in clocks)


def test_start_offset_skips_the_beginning(tmp_path: Path) -> None:
    src, out = tmp_path / "a.mcap", tmp_path / "b.mcap"
    _record_sample("mem://offsrc", src, n=8)
    logs = [m.log_time for m in read_bag(src)]
    cut = (logs[-1] - logs[0]) / 2e9
    expected = sum(1 for t in logs if (t - logs[0]) / 1e9 >= cut)
    bus = "mem://offdst"
    rec = Recorder(out, bus=bus)
    rec.start()
    player = Player(src, bus=bus, rate=math.inf, start_offset_s=cut)
    try:
        player.start()
        assert player.wait(WAIT)
        assert rec.wait_for(expected, WAIT)
    finally:
        player.stop()
        rec.stop()
    assert len(list(read_bag(out))) == expected < len(logs)


def test_bad_player_and_recorder_arguments(tmp_path: Path) -> None:
    with pytest.raises(ValueError, match="does not exist"):
        Player(tmp_path / "none.mcap", bus="mem://x")
    (tmp_path / "f.mcap").write_bytes(b"")
    with pytest.raises(ValueError, match="rate"):
        Player(tmp_path / "f.mcap", bus="mem://x", rate=0)
    with pytest.raises(ValueError, match="compression"):
        Recorder(tmp_path / "r.mcap", bus="mem://x", compression="gzip")
    with pytest.raises(ValueError, match="invalid topic"):
        Recorder(tmp_path / "r.mcap", ["bad topic"], bus="mem://x")


def test_cli_record_until_sigint_writes_a_complete_file(tmp_path: Path) -> None:
    path = tmp_path / "cli.mcap"
    with Proxy("tcp://127.0.0.1:0", "tcp://127.0.0.1:0") as proxy:
        proc = subprocess.Popen(
            [sys.executable, "-m", "hil_bridge.cli", "bag", "record", str(path), "--bus",
             proxy.url, "--flush-period", "0.05"],
            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
        )
        try:
            assert proc.stdout is not None and "recording" in proc.stdout.readline()
            with Node("src", bus=proxy.url, diagnostics_period_s=0) as node:
                pub = node.create_publisher(GliderState, "/glider/0/state")
                assert pub.wait_for_subscribers(WAIT)
                for i in range(30):
                    pub.publish(_state(i))
                # the recorder flushes a chunk every 0.05 s: poll the growing temporary file
                deadline = time.monotonic() + WAIT
                tick = threading.Event()
                while not (list(tmp_path.glob("*.part.mcap"))
                           and bag_info(_part(path)).messages >= 30):
                    assert time.monotonic() < deadline and proc.poll() is None
                    tick.wait(0.02)
        finally:
            proc.send_signal(signal.SIGINT)
            out, err = proc.communicate(timeout=30)
    assert proc.returncode == 0, err
    assert "recorded 30 messages" in out
    info = bag_info(path)
    assert not info.truncated and info.messages == 30



def test_replay_transport_feeds_nodes_and_tools_offline(tmp_path: Path) -> None:
    path = tmp_path / "a.mcap"
    _record_sample("mem://replaysrc", path, n=12)
    recorded = [(m.topic, m.header.seq, m.header.stamp_ns, m.payload) for m in read_bag(path)]
    url = f"replay://{path}?rate=0"
    got: list[tuple[str, int, int, bytes]] = []
    with open_transport(url) as t:
        t.subscribe(b"")
        while (frames := t.recv(timeout=0.2)) is not None:
            env = decode(frames)
            got.append((env.topic, env.header.seq, env.header.stamp_ns, env.payload))
        t.publish(encode("/x", Clock(stamp_ns=0), seq=0, pub_ns=0))
        assert t.stats()["discarded"] == 1 and not t.has_subscriber("/x")
    assert got == recorded
    states = [m for m in recorded if m[0] == "/glider/0/state"]
    seen: list[GliderState] = []
    cond = threading.Condition()

    def on_state(msg: GliderState) -> None:
        with cond:
            seen.append(msg)
            cond.notify_all()

    deep = QoSProfile("offline", depth=1000)
    with Node("offline", bus=f"replay://{path}?rate=0&loop=1") as node:
        node.create_subscription(GliderState, "/glider/0/state", on_state, deep)
        node.start()
        with cond:  # a later pass (loop=1) counts seq from 0 again: a new epoch, delivered
            assert cond.wait_for(lambda: len(seen) >= 2 * len(states), WAIT)
        assert poll_until(lambda: node.stats()["epochs"] >= 1)
        assert node.stats()["duplicates"] == 0
    assert [s.x for s in seen[:24]] == [float(i) for i in range(12)] * 2
    with pytest.raises(ValueError, match="existing MCAP"):
        open_transport(f"replay://{tmp_path}/none.mcap")
    with pytest.raises(ValueError, match="unknown option"):
        open_transport(f"replay://{path}?speed=2")


@pytest.mark.parametrize("content", [b"", b"not an mcap file at all"], ids=["empty", "text"])
def test_info_on_a_file_that_is_not_mcap_fails_clearly(tmp_path: Path, content: bytes,
                                                       capsys: pytest.CaptureFixture[str]) -> None:
    from hil_bridge.cli import main as echoloop

    path = tmp_path / "notes.mcap"
    path.write_bytes(content)
    with pytest.raises(ValueError, match="not an MCAP file"):
        bag_info(path)
    assert echoloop(["bag", "info", str(path)]) == 1
    assert "not an MCAP file" in capsys.readouterr().err
