"""SonarHeadAdapter on a mem:// bus against the mock head: data path, budget, diagnostics."""

from __future__ import annotations

import itertools
import threading
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from drivers.mocks.sonar_head import MockSonarHead
from drivers.serial.adapter import SonarHeadAdapter
from hil_bridge.bus.domain import Domain, use
from hil_bridge.bus.messages import Diagnostics, SonarEcho, SonarPing
from hil_bridge.bus.node import Node
from sim_core.config import ConfigError

FS = 400000.0
_BUS = itertools.count()


class Simulator:
    """A bus node answering each /sonar/0/ping with an echo of one return peaking at ``at``
    (a 70 kHz burst, band-limited as a real echo is)."""

    def __init__(self, bus: str, n_samples: int = 4000, at: int = 1000) -> None:
        self.node = Node("fake_sim", bus=bus, diagnostics_period_s=0)
        t = (np.arange(n_samples) - at) / FS
        self.echo = (0.25 * np.exp(-0.5 * (t / 2e-5) ** 2)
                     * np.cos(2 * np.pi * 70e3 * t)).astype(np.float32)
        self.pings: list[SonarPing] = []
        self.diags: list[Diagnostics] = []
        self.cv = threading.Condition()
        self.pub = self.node.create_publisher(SonarEcho, "/sonar/0/echo")
        self.node.create_subscription(SonarPing, "/sonar/0/ping", self.on_ping)
        self.node.create_subscription(Diagnostics, "/diagnostics", self.on_diag)

    def on_ping(self, ping: SonarPing) -> None:
        with self.cv:
            self.pings.append(ping)
        self.pub.publish(SonarEcho(stamp_ns=ping.stamp_ns, ping_seq=ping.ping_seq, fs=FS,
                                   samples=self.echo, leaves_in_beam=1, fidelity="test"))

    def on_diag(self, msg: Diagnostics) -> None:
        with self.cv:
            self.diags.append(msg)
            self.cv.notify_all()

    def wait_diag(self, node: str, timeout: float) -> Diagnostics | None:
        with self.cv:
            self.cv.wait_for(lambda: any(d.node == node for d in self.diags), timeout)
            found = [d for d in self.diags if d.node == node]
        return found[-1] if found else None


@pytest.fixture
def bus() -> str:
    return f"mem://serial_adapter_{next(_BUS)}"


@pytest.fixture
def mock() -> Iterator[MockSonarHead]:
    m = MockSonarHead("mock", pty=True, rate_hz=20, encoding="iq16", beamwidth=50)
    m.start()
    yield m
    m.stop()


def test_ping_to_bus_and_echo_back_to_the_head(bus: str, mock: MockSonarHead) -> None:
    sim = Simulator(bus)
    adapter = SonarHeadAdapter("sonar_head", bus=bus, port=mock.path, ping_rate_hz=20,
                               echo_samples=4000, encoding="iq16", diagnostics_period_s=0.2)
    sim.node.start()
    adapter.start()
    try:
        assert mock.wait_echoes(4, 10.0), mock.stats()
        diag = sim.wait_diag("sonar_head", 5.0)
    finally:
        adapter.stop()
        sim.node.stop()
    st = adapter.stats()
    assert st["pings_in"] >= 4 and st["echoes_out"] >= 4 and st["crc_errors"] == 0
    assert st["link_state"] == 0 and 0 < st["link_utilisation"] < 1
    ping = sim.pings[0]
    assert ping.sonar_id == 0 and ping.encoding == 1
    assert ping.beamwidth == pytest.approx(np.radians(50), rel=1e-6)
    m = mock.stats()
    assert m.get("encoding_mismatch", 0) == 0 and m["crc_errors"] == 0
    assert m["status_rx"] >= 1  # STATUS on connect
    assert diag is not None and diag.counters["frames_in"] >= 1
    assert {"crc_errors", "reconnects", "frames_out", "frames_dropped"} <= set(diag.counters)
    adapter.stop()  # idempotent


def test_sonarsim_port_needs_no_pty(bus: str) -> None:
    sim = Simulator(bus, n_samples=400, at=100)
    adapter = SonarHeadAdapter("sonar_head", bus=bus, ping_rate_hz=50,
                               port="sonarsim://?rate_hz=50&encoding=float32&beamwidth=35")
    sim.node.start()
    adapter.start()
    try:
        assert adapter.host.link.wait_connected(5.0)
        head = adapter.host.link.port.mock
        assert head.wait_echoes(3, 10.0)
    finally:
        adapter.stop()
        sim.node.stop()
    assert head.stats()["last_range_m"] == pytest.approx(340 * 100 / FS / 2, abs=1e-4)


def test_budget_refuse_fails_at_load_and_warn_marks_the_state(
    bus: str, caplog: pytest.LogCaptureFixture
) -> None:
    with pytest.raises(ValueError, match=r"over budget.*921600 baud"):
        SonarHeadAdapter("sonar_head", bus=bus, port="loop://", ping_rate_hz=20,
                         encoding="int16", budget="refuse")
    adapter = SonarHeadAdapter("sonar_head", bus=bus, port="loop://", ping_rate_hz=20,
                               encoding="int16")
    try:
        assert adapter.stats()["link_state"] == 2
        assert "over budget" in caplog.text
    finally:
        adapter.stop()
    ok = SonarHeadAdapter("sonar_head", bus=bus, port="loop://", ping_rate_hz=20,
                          echo_samples=20000, encoding="iq16", budget="refuse")
    ok.stop()


@pytest.mark.parametrize(("params", "match"), [
    ({"port": "loop://", "budget": "maybe"}, "budget"),
    ({"port": "loop://", "baudrate": 0}, "baudrate"),
    ({"port": "loop://", "encoding": "mp3"}, "encoding"),
    ({"port": "nope://x"}, "nope"),
])
def test_bad_params_fail_at_load(bus: str, params: dict[str, Any], match: str) -> None:
    with pytest.raises((ConfigError, ValueError), match=match):
        SonarHeadAdapter("sonar_head", bus=bus, **params)


def test_default_port_is_the_domain_link_of_the_mock(bus: str, tmp_path: Path) -> None:
    """Without ``port`` the adapter opens the pty a MockSonarHead made for its domain."""
    with use(Domain.private(tmp_path)) as domain:
        mock = MockSonarHead("mock", pty=True, sonar_id=2, rate_hz=20, encoding="int16")
        adapter = SonarHeadAdapter("sonar_head", bus=bus, sonar_id=2, echo_samples=4000)
    assert adapter.port == str(domain.path("sonar2"))
    mock.start()
    adapter.start()
    try:
        assert mock.path == adapter.port
        assert adapter.host.link.wait_connected(5.0)
        assert adapter.host.wait_for(lambda h: h.counts["pings_in"] > 0, 5.0)
    finally:
        adapter.stop()
        mock.stop()
    assert adapter.stats()["links"]["serial"]["connected"] is True


def test_loop_port_reads_back_valid_frames(bus: str) -> None:
    """On loop:// the adapter decodes its own output: every frame it writes is valid §2."""
    sim = Node("echo_src", bus=bus, diagnostics_period_s=0)
    pub = sim.create_publisher(SonarEcho, "/sonar/0/echo")
    adapter = SonarHeadAdapter("sonar_head", bus=bus, port="loop://", encoding="float32",
                               echo_samples=3000, ping_rate_hz=1, heartbeat_period_s=0.05)
    sim.start()
    adapter.start()
    try:
        assert adapter.host.link.wait_connected(5.0)
        assert pub.wait_for_subscribers(5.0)
        pub.publish(SonarEcho(stamp_ns=1, ping_seq=9, fs=FS, samples=np.ones(3000, np.float32),
                              leaves_in_beam=0, fidelity="test"))
        # 3000 float32 samples = 3 ECHO chunks, read back as frames a host never expects
        assert adapter.host.wait_for(
            lambda h: h.counts["unexpected_in"] >= 3 and h.counts["status_in"] >= 2, 5.0)
    finally:
        adapter.stop()
        sim.stop()
    st = adapter.stats()
    assert st["frames_dropped"] == 0 and st["crc_errors"] == 0
    assert st["echoes_out"] == 1
    assert adapter.host.counts["heartbeats_in"] >= 1


def test_link_state_degrades_while_frames_drop() -> None:
    from drivers.serial.host import SonarHeadHost
    from drivers.serial.protocol import LinkState

    host = SonarHeadHost("loop://")  # never started: only the decoder is exercised
    assert host.update_state() is LinkState.OK
    host.decoder.feed(b"\x05\x01\x00")  # a COBS error
    assert host.update_state() is LinkState.DEGRADED
    assert host.update_state() is LinkState.OK  # nothing dropped since
    host.state = LinkState.OVER_BUDGET
    host.decoder.feed(b"\x05\x01\x00")
    assert host.update_state() is LinkState.OVER_BUDGET
    host.stop()


def test_unsupported_encoding_in_a_ping_is_answered_with_an_error() -> None:
    import struct

    from drivers.serial.framing import MsgType, frame_bytes
    from drivers.serial.host import SonarHeadHost
    from drivers.serial.protocol import ErrorCode

    host = SonarHeadHost("loop://")  # the host reads back what it writes
    host.start()
    try:
        assert host.link.wait_connected(5.0)
        bad_ping = struct.pack("<HfffB", 3, 0.0, 0.0, 0.5, 9)  # encoding 9 does not exist
        host.link.send(frame_bytes(MsgType.PING, 77, 0, bad_ping))
        assert host.wait_for(lambda h: any(e.code == ErrorCode.UNSUPPORTED_ENCODING
                                           for e in h.head_errors), 5.0)
    finally:
        host.stop()
    err = next(e for e in host.head_errors if e.code == ErrorCode.UNSUPPORTED_ENCODING)
    assert err.ref_seq == 77 and "encoding" in err.text
    assert host.counts["bad_payloads"] == 1 and host.counts["pings_in"] == 0


@pytest.mark.parametrize(("field", "value"), [
    ("decimation", 65535), ("decimation", 7), ("channels", 0), ("channels", 200),
    ("flags", 1), ("proto_version", 2), ("ping_rate_mhz", 5_000_000), ("baudrate", 300),
    ("f_center_hz", 250_000),
], ids=lambda v: str(v))
def test_a_bad_config_is_refused_and_the_previous_one_stays(field: str, value: int) -> None:
    """One CRC-valid CONFIG out of range (the issue: decimation 65535 silenced every echo) is
    answered with an ERROR frame and changes nothing; a sane CONFIG afterwards applies."""
    import dataclasses

    from drivers.serial.framing import MsgType, frame_bytes
    from drivers.serial.host import SonarHeadHost
    from drivers.serial.protocol import ConfigPayload, Encoding, ErrorCode

    good = ConfigPayload(Encoding.IQ16, 1, 10_000, 921600, 70_000, 20)
    host = SonarHeadHost("loop://", encoding="int16", decimation=10, f_center_hz=65_000)
    host.start()
    try:
        assert host.link.wait_connected(5.0)
        bad = dataclasses.replace(good, **{field: value})
        host.link.send(frame_bytes(MsgType.CONFIG, 41, 0, bad.pack()))
        assert host.wait_for(lambda h: any(e.code == ErrorCode.BAD_CONFIG
                                           for e in h.head_errors), 5.0)
        err = next(e for e in host.head_errors if e.code == ErrorCode.BAD_CONFIG)
        assert err.ref_seq == 41 and f"{field} {value}" in err.text
        assert host.head_config is None and host.counts["configs_refused"] == 1
        assert (host.encoding, host.decimation, host.f_center_hz) == (Encoding.INT16, 10, 65_000)
        host.link.send(frame_bytes(MsgType.CONFIG, 42, 0, good.pack()))
        assert host.wait_for(lambda h: h.head_config == good, 5.0)
        assert (host.encoding, host.decimation, host.f_center_hz) == (Encoding.IQ16, 20, 70_000)
    finally:
        host.stop()
