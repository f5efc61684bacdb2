"""Fault injection: corrupt frames are dropped and counted, resync within one frame, no
exception escapes a read loop, unplug -> reconnect."""

from __future__ import annotations

import threading
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from drivers.faults.serial_proxy import FaultInjector, SerialFaultProxy, SerialFaults
from drivers.mocks.sonar_head import MockSonarHead
from drivers.serial.framing import Frame, FrameDecoder, MsgType, encode_frame
from drivers.serial.host import SonarHeadHost
from drivers.serial.protocol import PingPayload
from sim_core.rng import make_rng


def make_frames(n: int) -> list[Frame]:
    return [Frame(MsgType.STATUS, i, i, bytes((i * 7 + k) % 256 for k in range(i % 50)))
            for i in range(n)]


def test_injector_is_seeded_and_counts_each_fault() -> None:
    frames = make_frames(300)
    wire = b"".join(encode_frame(f.body()) for f in frames)
    faults = SerialFaults(drop=0.1, bit_flip=0.1, truncate=0.1, garbage=0.1, duplicate=0.1)
    a = FaultInjector(faults, make_rng(5)).process(wire)
    inj = FaultInjector(faults, make_rng(5))
    b = b"".join(inj.process(wire[i:i + 37]) for i in range(0, len(wire), 37))
    assert a == b  # one decision per frame: read sizes do not matter
    assert a != FaultInjector(faults, make_rng(6)).process(wire)
    for kind in ("dropped", "bit_flips", "truncated", "garbage", "duplicated"):
        assert 10 <= inj.counts[kind] <= 60, (kind, inj.counts)
    with pytest.raises(ValueError, match="drop"):
        SerialFaults(drop=1.5)


@settings(max_examples=40, deadline=None)
@given(st.integers(0, 2**32 - 1), st.floats(0.0, 0.5))
def test_only_hit_frames_are_lost(seed: int, p: float) -> None:
    """Resync within one frame: every frame no fault touched decodes, nothing else appears."""
    frames = make_frames(120)
    wire = b"".join(encode_frame(f.body()) for f in frames)
    inj = FaultInjector(SerialFaults(drop=p, bit_flip=p, truncate=p, garbage=p), make_rng(seed))
    dec = FrameDecoder()
    out = dec.feed(inj.process(wire))
    hit = sum(inj.counts[k] for k in ("dropped", "bit_flips", "truncated", "garbage"))
    assert len(out) >= len(frames) - hit
    assert all(f in frames for f in out)
    assert dec.dropped + len(out) >= len(frames) - inj.counts["dropped"] - hit


class EchoBack:
    def __init__(self) -> None:
        self.host: SonarHeadHost | None = None
        t = (np.arange(3000) - 800) / 400000.0  # one return peaking at sample 800
        self.echo = (np.exp(-0.5 * (t / 2e-5) ** 2)
                     * np.cos(2 * np.pi * 70e3 * t)).astype(np.float32)

    def __call__(self, ping: PingPayload, frame: Frame) -> None:
        if self.host is not None:
            self.host.send_echo(ping.ping_seq, self.echo, 400000.0)


def test_faulty_link_drops_counts_and_keeps_running(tmp_path: Path) -> None:
    mock = MockSonarHead("mock", pty=True, rate_hz=40, encoding="float32", beamwidth=45,
                         baudrate=3000000)
    mock.start()
    proxy = SerialFaultProxy(upstream=mock.path, link=str(tmp_path / "tty_faulty"),
                             baudrate=3000000, seed=11, bit_flip=0.1, drop=0.05, truncate=0.05,
                             garbage=0.05, duplicate=0.05)
    answer = EchoBack()
    host = SonarHeadHost(proxy.path, baudrate=3000000, on_ping=answer, backoff_initial_s=0.01)
    answer.host = host
    try:
        proxy.start()
        host.start()
        assert mock.wait_echoes(15, 20.0), mock.stats()
        # the host's reader keeps going: no callback error, still connected, still counting
        assert host.link.callback_errors == 0 and host.link.connected
    finally:
        host.stop()
        proxy.stop()
        mock.stop()
    ps, ms = proxy.stats(), mock.stats()
    hit_up = ps.get("to_host_bit_flips", 0) + ps.get("to_host_truncated", 0) + ps.get(
        "to_host_garbage", 0)
    hit_down = ps.get("to_device_bit_flips", 0) + ps.get("to_device_truncated", 0) + ps.get(
        "to_device_garbage", 0)
    assert hit_up > 0 and hit_down > 0
    assert host.decoder.dropped > 0 and ms["frames_dropped"] > 0
    # corrupted ECHO chunks make incomplete echoes, never wrong ones
    assert ms["echoes_incomplete"] + ms["echo_timeouts"] > 0
    # every ping has exactly one outcome: the summary's counts add up
    assert ms["pings_sent"] + ms["pings_refired"] == (
        ms["echoes_complete"] + ms["echoes_incomplete"] + ms["echo_timeouts"]
        + ms["pings_in_flight"]), ms
    # the head reports abandoned echoes back in ERROR frames (some survive the faults)
    assert ms.get("errors_tx", 0) > 0 and host.counts["errors_in"] > 0
    assert ms["last_range_m"] == pytest.approx(340 * 800 / 400000 / 2, abs=1e-4)


def test_unplug_then_replug_reconnects_and_echoes_resume(tmp_path: Path) -> None:
    mock = MockSonarHead("mock", pty=True, rate_hz=40, encoding="int16", beamwidth=45)
    mock.start()
    proxy = SerialFaultProxy(upstream=mock.path, link=str(tmp_path / "tty_usb"))
    answer = EchoBack()
    host = SonarHeadHost(str(tmp_path / "tty_usb"), on_ping=answer, backoff_initial_s=0.01,
                         backoff_max_s=0.05)
    answer.host = host
    try:
        proxy.start()
        host.start()
        assert mock.wait_echoes(2, 10.0)
        proxy.unplug()
        assert not (tmp_path / "tty_usb").exists()
        assert host.link.wait_for(lambda lk: not lk.connected, 5.0)
        assert host.link.faults.failure(final=True) is not None  # the drop, not yet recovered
        proxy.replug()
        assert host.link.wait_for(lambda lk: lk.connected and lk.reconnects == 1, 5.0)
        assert host.link.faults.failure(final=True) is None  # the re-open recovered it
        n = mock.stats()["echoes_complete"]
        assert mock.wait_echoes(n + 3, 10.0)
    finally:
        host.stop()
        proxy.stop()
        mock.stop()
    assert host.stats()["reconnects"] == 1 and proxy.stats()["unplugs"] == 1


def test_scheduled_unplugs_from_params(tmp_path: Path) -> None:
    mock = MockSonarHead("mock", pty=True, rate_hz=20)
    mock.start()
    proxy = SerialFaultProxy("faults", bus="mem://unused", upstream=mock.path,
                             link=str(tmp_path / "tty_sched"), unplug_every_s=0.05,
                             unplug_for_s=0.05)
    host = SonarHeadHost(str(tmp_path / "tty_sched"), backoff_initial_s=0.01,
                         backoff_max_s=0.02)
    done = threading.Event()
    try:
        proxy.start()
        host.start()
        assert host.link.wait_for(lambda lk: lk.reconnects >= 2, 10.0)
        done.set()
    finally:
        host.stop()
        proxy.stop()
        mock.stop()
    assert done.is_set() and proxy.stats()["unplugs"] >= 2
