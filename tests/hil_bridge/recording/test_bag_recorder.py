"""A recorder that never fails in silence: file limits, channel limits, unbounded ``src``,
signals; its failures reach /diagnostics, the run summary and the exit status."""

from __future__ import annotations

import os
import resource
import signal
import subprocess
import sys
import threading
from collections.abc import Iterator
from pathlib import Path

import numpy as np
import pytest
import yaml
from mcap.reader import make_reader

from hil_bridge.bus.codec import encode
from hil_bridge.bus.messages import Clock, Diagnostics, SonarEcho
from hil_bridge.bus.node import Node
from hil_bridge.bus.proxy import Proxy
from hil_bridge.bus.transport import open_transport
from hil_bridge.errors import OutputExistsError
from hil_bridge.recording.bag import bag_info, read_bag
from hil_bridge.recording.bag_writer import MAX_PUBLISHERS_PER_TOPIC
from hil_bridge.recording.recorder import Recorder
from tests.hil_bridge.bus.bus_test_util import WAIT, poll_until

ROOT = Path(__file__).resolve().parents[3]
MIB = 1 << 20


def _noise_echo(i: int) -> SonarEcho:
    samples = np.random.default_rng(i).standard_normal(8192).astype(np.float32)  # 32 KiB
    return SonarEcho(stamp_ns=i, ping_seq=i, fs=400e3, samples=samples, leaves_in_beam=0,
                     fidelity="fast")


def _limit_file_size() -> None:
    resource.setrlimit(resource.RLIMIT_FSIZE, (MIB, MIB))


def _echoloop(*args: str, limit: bool = False) -> subprocess.Popen[str]:
    return subprocess.Popen(
        [sys.executable, "-m", "hil_bridge.cli", *args], cwd=ROOT, text=True,
        stdout=subprocess.PIPE, stderr=subprocess.PIPE,
        preexec_fn=_limit_file_size if limit else None,
    )


@pytest.fixture
def proxy() -> Iterator[Proxy]:
    with Proxy("tcp://127.0.0.1:0", "tcp://127.0.0.1:0") as p:
        yield p


def _publish_until_done(url: str, proc: subprocess.Popen[str], topic: str = "/sonar/0/echo"
                        ) -> int:
    """Publish incompressible 32 KiB echoes until the recording process exits (bounded)."""
    sent = 0
    with Node("src", bus=url, diagnostics_period_s=0) as node:
        pub = node.create_publisher(SonarEcho, topic)
        assert pub.wait_for_subscribers(WAIT)
        tick = threading.Event()
        while proc.poll() is None and sent < 400:  # 400 x 32 KiB = 12.5 MiB at most
            pub.publish(_noise_echo(sent))
            sent += 1
            tick.wait(0.005)
    return sent


def test_bag_record_under_a_file_size_limit_exits_non_zero(proxy: Proxy,
                                                          tmp_path: Path) -> None:
    out = tmp_path / "limited.mcap"
    proc = _echoloop("bag", "record", str(out), "--bus", proxy.url, "--duration", "6",
                     "--flush-period", "0.05", "--compression", "none", limit=True)
    try:
        assert proc.stdout is not None and "recording" in proc.stdout.readline()
        _publish_until_done(proxy.url, proc)
        _, err = proc.communicate(timeout=60)
    finally:
        proc.kill()
    assert proc.returncode == 1, err
    assert "File too large" in err and str(out) in err
    assert len(err.strip().splitlines()) <= 2, err  # the logged failure + the one error line
    info = bag_info(out)  # what was written before the limit is still readable
    assert info.truncated and info.messages > 0


def test_launch_record_under_a_file_size_limit_exits_non_zero(proxy: Proxy,
                                                             tmp_path: Path) -> None:
    launch = tmp_path / "listen.yaml"
    launch.write_text(yaml.safe_dump({"bus": proxy.url, "nodes": [
        {"name": "server", "entry": "hil_bridge.server:SimServer",
         "params": {"scene": {"state_rate_hz": 5}, "embed_proxy": False}},
    ]}), encoding="utf-8")
    out = tmp_path / "run.mcap"
    proc = _echoloop("launch", str(launch), "--duration", "6", "--record", str(out), "--json",
                     limit=True)
    try:
        _publish_until_done(proxy.url, proc)
        stdout, err = proc.communicate(timeout=60)
    finally:
        proc.kill()
    assert proc.returncode == 1, err
    assert f"recorder failed: writing {out}: OSError: [Errno 27] File too large" in err
    import json

    summary = json.loads(stdout)
    assert summary["exit_status"] == 1
    assert summary["failures"][0]["source"] == "recorder"
    assert summary["extras"]["recorder"]["failed"] == 1


def test_recorder_survives_70000_distinct_src(tmp_path: Path) -> None:
    n = 70_000
    path = tmp_path / "spray.mcap"
    bus = f"mem://spray?depth={n + 10}"
    rec = Recorder(path, bus=bus, diagnostics_period_s=0)
    rec.start()
    try:
        with open_transport(bus) as raw:
            for i in range(n):
                raw.publish(encode("/glider/0/state_raw", Clock(stamp_ns=i), seq=0, pub_ns=i,
                                   src=f"spoof#{i}"))
        assert rec.wait_for(n, 120)
    finally:
        rec.stop()
    assert rec.failure() is None
    stats = rec.stats()
    assert stats["channels"] == MAX_PUBLISHERS_PER_TOPIC + 1
    assert stats["src_shared"] == n - MAX_PUBLISHERS_PER_TOPIC
    with open(path, "rb") as f:  # the standard reader, through the summary and index
        summary = make_reader(f).get_summary()
        assert summary is not None and summary.statistics is not None
        assert summary.statistics.message_count == n
    assert sum(1 for _ in read_bag(path)) == n


def test_channel_limit_is_reported_on_diagnostics(tmp_path: Path) -> None:
    bus = "mem://chanlimit"
    rec = Recorder(tmp_path / "x.mcap", bus=bus, max_channels=4, diagnostics_period_s=0.05)
    seen: list[Diagnostics] = []
    with Node("watch", bus=bus, diagnostics_period_s=0) as watch:
        watch.create_subscription(Diagnostics, "/diagnostics", seen.append)
        watch.start()
        rec.start()
        try:
            with open_transport(bus) as raw:
                for t in range(10):
                    raw.publish(encode(f"/t{t}", Clock(stamp_ns=t), seq=0, pub_ns=0, src="p"))
            assert poll_until(lambda: any(d.node == "recorder" and d.counters.get("failed")
                                          for d in list(seen)))
        finally:
            rec.stop()
    failure = rec.failure()
    assert failure is not None and "channels (the limit)" in failure
    assert rec.stats()["not_recorded"] > 0


def test_recorder_refuses_an_existing_file(tmp_path: Path) -> None:
    path = tmp_path / "keep.mcap"
    path.write_bytes(b"precious")
    with pytest.raises(OutputExistsError, match="pass --overwrite"):
        Recorder(path, bus="mem://refuse").start()
    assert path.read_bytes() == b"precious"
    assert list(tmp_path.iterdir()) == [path]  # no temporary file left behind


@pytest.mark.parametrize("how", ["SIGTERM", "SIGINT", "duration"])
@pytest.mark.parametrize("command", ["launch", "bag"])
def test_recording_has_a_summary_however_the_run_ends(proxy: Proxy, tmp_path: Path,
                                                     how: str, command: str) -> None:
    out = tmp_path / "run.mcap"
    duration = ["--duration", "2"] if how == "duration" else []
    if command == "launch":
        launch = tmp_path / "l.yaml"
        launch.write_text(yaml.safe_dump({"bus": proxy.url, "nodes": [
            {"name": "server", "entry": "hil_bridge.server:SimServer",
             "params": {"scene": {"state_rate_hz": 20}, "embed_proxy": False}},
        ]}), encoding="utf-8")
        proc = _echoloop("launch", str(launch), "--record", str(out), *duration)
        ready = "echoloop launch: running"
        stream = proc.stderr
    else:
        proc = _echoloop("bag", "record", str(out), "--bus", proxy.url, *duration)
        ready = "recording"
        stream = proc.stdout
    try:
        assert stream is not None and ready in stream.readline()
        with Node("src", bus=proxy.url, diagnostics_period_s=0) as node:
            pub = node.create_publisher(Clock, "/probe")
            assert pub.wait_for_subscribers(WAIT)
            for i in range(20):
                pub.publish(Clock(stamp_ns=i))

            def flushed() -> bool:  # the recorder flushes a chunk at least once a second
                parts = list(tmp_path.glob(".run.*.part.mcap"))
                return bool(parts) and bag_info(parts[0]).topics.get("/probe") is not None \
                    and bag_info(parts[0]).topics["/probe"].count == 20

            if how != "duration":
                assert poll_until(flushed)
        if how != "duration":
            os.kill(proc.pid, getattr(signal, how))
        _, err = proc.communicate(timeout=60)
    finally:
        proc.kill()
    assert proc.returncode == 0, err
    with open(out, "rb") as f:
        summary = make_reader(f).get_summary()
    assert summary is not None and summary.statistics is not None
    assert summary.statistics.message_count >= 20
