"""The host session against the mock head on a pty and through sonarsim://; mock behaviour."""

from __future__ import annotations

import itertools
import math
import os
import threading
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from drivers import cli
from drivers.mocks.sonar_head import MockSonarHead
from drivers.mocks.sonar_head_config import BEAMWIDTH_RANGE_DEG
from drivers.serial.framing import Frame, FrameDecoder, MsgType
from drivers.serial.host import SonarHeadHost
from drivers.serial.link import open_link
from drivers.serial.protocol import Encoding, PingPayload

FS = 400000.0
IMPULSE_AT = 2000  # samples -> t = 5 ms -> range 340 * 0.005 / 2 = 0.85 m


def impulse_echo(n: int = 4000) -> np.ndarray:
    x = np.zeros(n, np.float32)
    x[min(IMPULSE_AT, n - 1)] = 1.0
    return x


def tone_burst_echo(n: int = 4000) -> np.ndarray:
    t = np.arange(n) / FS
    env = np.exp(-0.5 * ((t - IMPULSE_AT / FS) / 2e-4) ** 2)
    return (env * np.cos(2 * np.pi * 70e3 * t)).astype(np.float32)


class Pings:
    """Host ``on_ping`` that answers every ping with ``echo`` and records the pings."""

    def __init__(self, echo: np.ndarray) -> None:
        self.echo = echo
        self.host: SonarHeadHost | None = None
        self.pings: list[PingPayload] = []
        self.cv = threading.Condition()

    def __call__(self, ping: PingPayload, frame: Frame) -> None:
        with self.cv:
            self.pings.append(ping)
            self.cv.notify_all()
        if self.host is not None:
            self.host.send_echo(ping.ping_seq, self.echo, FS)

    def wait(self, n: int, timeout: float = 5.0) -> bool:
        with self.cv:
            return self.cv.wait_for(lambda: len(self.pings) >= n, timeout)


def run_session(kind: str, encoding: str, echo: np.ndarray, n: int = 3, **mock_params: Any
                ) -> tuple[dict[str, Any], SonarHeadHost, Pings]:
    """Mock head (on a pty, or inside a sonarsim:// port) + host answering every ping."""
    params = {"rate_hz": 20, "encoding": encoding, "beamwidth": 40, **mock_params}
    answer = Pings(echo)
    mock: MockSonarHead | None = None
    if kind == "pty":
        mock = MockSonarHead("mock", pty=True, **params)
        mock.start()
        port = mock.path
    else:
        port = "sonarsim://?" + "&".join(f"{k}={v}" for k, v in params.items())
    host = SonarHeadHost(port, on_ping=answer)
    answer.host = host
    try:
        host.start()
        assert host.link.wait_connected(5.0)
        if mock is None:
            mock = host.link.port.mock
        assert mock is not None
        assert mock.wait_echoes(n, 10.0), mock.stats()
        stats = mock.stats()
    finally:
        host.stop()
        if kind == "pty" and mock is not None:
            mock.stop()
    return stats, host, answer


@pytest.mark.parametrize("encoding", ["int16", "iq16", "float32"])
@pytest.mark.parametrize("kind", ["pty", "sonarsim"])
def test_echoes_arrive_complete_in_the_requested_encoding(kind: str, encoding: str) -> None:
    echo = tone_burst_echo()
    stats, host, answer = run_session(kind, encoding, echo)
    assert stats["echoes_complete"] >= 3
    assert stats.get("encoding_mismatch", 0) == 0
    assert stats["crc_errors"] == 0 and stats["frames_dropped"] == 0
    assert all(p.encoding == Encoding.parse(encoding) for p in answer.pings)
    assert all(math.isclose(p.beamwidth, math.radians(40), rel_tol=1e-6) for p in answer.pings)
    lat = stats["latency_p50_ms"]
    assert isinstance(lat, float) and lat > 0
    rng = stats["last_range_m"]
    assert isinstance(rng, float)
    # the burst's envelope peaks at IMPULSE_AT: to a tenth of a sample at 400 kHz, to a
    # tenth of a baseband sample (20 kHz: 8.5 mm each) through IQ, int16 rounding included
    step = 340 / (20000 if encoding == "iq16" else FS) / 2
    assert abs(rng - 340 * IMPULSE_AT / FS / 2) < 0.1 * step
    assert host.decoder.dropped == 0 and host.counts["configs_in"] >= 1
    if encoding == "iq16":
        assert host.f_center_hz == 70000 and host.decimation == 20


def test_head_status_reaches_the_mock() -> None:
    _, host, _ = run_session("pty", "int16", impulse_echo())
    assert host.counts["frames_out"] > 0


def test_random_beamwidth_is_seeded_and_in_range() -> None:
    def beams(seed: int) -> list[float]:
        _, _, answer = run_session("sonarsim", "float32", impulse_echo(100), n=6, seed=seed,
                                   rate_hz=100, beamwidth="random")
        return [p.beamwidth for p in answer.pings[:6]]

    a, b, c = beams(3), beams(3), beams(4)
    lo, hi = (math.radians(d) for d in BEAMWIDTH_RANGE_DEG)
    assert all(lo <= x <= hi for x in a + c)
    assert a == b and a != c


def test_the_mock_ranges_the_first_return_of_any_ear() -> None:
    """The head's range is echoloop's one rule (sim_core.sensors.echo_range) over its ears:
    bursts peaking at samples 400 (ear 1, half as loud) and 500 (ear 0) are returns at
    340 * n / fs / 2 m."""
    t = np.arange(1000) / FS
    x = np.stack([np.exp(-0.5 * ((t - at / FS) / 2e-5) ** 2) * a * np.cos(2 * np.pi * 70e3 * t)
                  for at, a in ((500, 1.0), (400, 0.5))])
    head = MockSonarHead("m", pty=True, link=None)
    try:
        assert head._range(x, FS) == pytest.approx(340 * 400 / FS / 2, abs=1e-5)
        loud = MockSonarHead("m2", pty=True, threshold=0.8)
        try:
            assert loud._range(x, FS) == pytest.approx(340 * 500 / FS / 2, abs=1e-5)
        finally:
            loud.stop()
        assert head._range(np.zeros(10), 1.0) is None
    finally:
        head.stop()


@pytest.mark.parametrize(("params", "match"), [
    ({"pty": True, "beamwidth": "wide"}, "beamwidth"),
    ({"pty": True, "rate_hz": 0}, "rate_hz"),
    ({"pty": True, "encoding": "mp3"}, "encoding"),
    ({"pty": True, "colour": 1}, "colour"),
    ({"pty": True, "port": "loop://"}, "exactly one"),
    ({}, "exactly one"),
])
def test_mock_rejects_bad_config(params: dict[str, object], match: str) -> None:
    with pytest.raises(ValueError, match=match):
        MockSonarHead("m", **params)  # type: ignore[arg-type]


def test_sonarsim_rejects_unknown_options() -> None:
    with pytest.raises(ValueError, match="colour"):
        open_link("sonarsim://?colour=red", connect_timeout_s=2.0)


def test_cli_runs_the_mock_on_a_pty(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    link = tmp_path / "sonar0"
    assert cli.main(["sonar-head", "--pty", "--link", str(link), "--rate", "50",
                     "--duration", "0.2", "--every", "0"]) == 0
    out = capsys.readouterr().out
    assert f"open it with sonar_head.port={link}" in out and "pings_sent=" in out
    assert not link.exists()  # the mock removes its symlink when it stops
    assert cli.main([]) == 2
    assert cli.main(["toaster"]) == 2


def test_capture_decodes_to_the_counted_frames(tmp_path: Path) -> None:
    mock = MockSonarHead("mock", pty=True, rate_hz=50, encoding="int16", beamwidth=40)
    mock.start()
    answer = Pings(impulse_echo(500))
    host = SonarHeadHost(mock.path, on_ping=answer, capture=tmp_path / "head")
    answer.host = host
    try:
        host.start()
        assert mock.wait_echoes(5, 10.0)
    finally:
        host.stop()
        mock.stop()
    rx = FrameDecoder().feed((tmp_path / "head.rx.bin").read_bytes())
    tx = FrameDecoder().feed((tmp_path / "head.tx.bin").read_bytes())
    assert len(rx) == host.decoder.frames_ok
    assert len(tx) == host.counts["frames_out"]
    assert sum(f.msg_type == MsgType.PING for f in rx) == host.counts["pings_in"]


#: the in-process mock always; a real head too when HIL_SERIAL_PORT names its port
HEAD_PORTS = [pytest.param("sonarsim://?rate_hz=50&encoding=int16", id="sonarsim")]
if os.environ.get("HIL_SERIAL_PORT"):
    HEAD_PORTS.append(pytest.param(os.environ["HIL_SERIAL_PORT"], id="hardware",
                                   marks=pytest.mark.hardware))


@pytest.mark.parametrize("port", HEAD_PORTS)
def test_head_conformance(port: str) -> None:
    """What any head must do: announce CONFIG, send valid PINGs, accept ECHO chunks."""
    answer = Pings(impulse_echo(1000))
    baud = int(os.environ.get("HIL_SERIAL_BAUD", "921600"))
    host = SonarHeadHost(port, baudrate=baud, on_ping=answer)
    answer.host = host
    try:
        host.start()
        assert answer.wait(3, 10.0), host.stats()
        assert host.wait_for(lambda h: h.head_config is not None, 5.0)
        assert host.wait_for(lambda h: h.counts["echoes_out"] >= 3, 5.0)
    finally:
        host.stop()
    assert host.decoder.dropped == 0 and host.counts["bad_payloads"] == 0
    assert host.head_config is not None and host.head_config.proto_version == 1
    seqs = [p.ping_seq for p in answer.pings]
    assert all((b - a) % 65536 == 1 for a, b in itertools.pairwise(seqs))
    assert not [e for e in host.head_errors if e.code != 3]  # only over-budget is tolerable
