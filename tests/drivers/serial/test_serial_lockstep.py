"""Lockstep over the serial link: the mock head pings on the host's sim time, one ping per echo;
the adapter forwards /clock and publishes pings with their sim stamp and the next one's."""

from __future__ import annotations

import math
import threading
from pathlib import Path

import numpy as np
import pytest

from drivers.mocks.sonar_head import MockSonarHead
from drivers.mocks.sonar_head_config import BEAMWIDTH_RANGE_DEG
from drivers.serial.adapter import SonarHeadAdapter
from drivers.serial.framing import Frame
from drivers.serial.host import SonarHeadHost
from drivers.serial.protocol import HEARTBEAT_LOCKSTEP, HeartbeatPayload, PingPayload
from hil_bridge.bus.messages import Clock, SonarEcho, SonarPing
from hil_bridge.bus.node import Node
from sim_core.rng import make_rng
from tests.drivers.can._util import unique, wait_until

PERIOD_NS = 200_000_000  # 5 Hz


def test_heartbeat_flags_and_the_five_byte_form() -> None:
    beat = HeartbeatPayload(1234, 1, HEARTBEAT_LOCKSTEP)
    assert HeartbeatPayload.unpack(beat.pack()) == beat and beat.lockstep
    legacy = HeartbeatPayload.unpack(bytes([1, 0, 0, 0, 2]))
    assert (legacy.uptime_ms, legacy.state, legacy.lockstep) == (1, 2, False)
    with pytest.raises(ValueError, match="HEARTBEAT payload of 4 bytes"):
        HeartbeatPayload.unpack(b"\0\0\0\0")


def test_mock_head_pings_on_sim_time_one_ping_per_echo(tmp_path: Path) -> None:
    mock = MockSonarHead("mock", pty=True, link=str(tmp_path / "head"), rate_hz=5,
                         encoding="int16", seed=7, throttle=False)
    pings: list[tuple[PingPayload, Frame]] = []  # on sim time: stamps of at most 3 periods
    own: list[PingPayload] = []  # on the head's own clock: monotonic nanoseconds
    lock = threading.Lock()

    def on_ping(ping: PingPayload, frame: Frame) -> None:
        with lock:
            if frame.stamp_ns <= 3 * PERIOD_NS:
                pings.append((ping, frame))
            else:
                own.append(ping)

    mock.start()
    host = SonarHeadHost(str(tmp_path / "head"), on_ping=on_ping)
    host.start()
    try:
        assert host.link.wait_connected(5.0)
        assert wait_until(lambda: len(own) >= 1)  # on its own clock first
        host.send_heartbeat(stamp_ns=0, lockstep=True)
        assert wait_until(lambda: len(pings) >= 1)
        host.send_heartbeat(stamp_ns=PERIOD_NS + 1, lockstep=True)
        threading.Event().wait(0.4)  # ping 1 is due now, but waits for echo 0
        with lock:
            first = list(pings)
        assert [(p.ping_seq, f.stamp_ns) for p, f in first] == [(0, 0)]
        lo, hi = BEAMWIDTH_RANGE_DEG
        assert first[0][0].beamwidth == pytest.approx(
            math.radians(make_rng(7).uniform(lo, hi)), rel=1e-6)  # the stream restarted
        host.send_echo(0, np.zeros(400, np.float32), 400e3)
        assert wait_until(lambda: len(pings) == 2)
        threading.Event().wait(0.3)
        assert len(pings) == 2  # ping 2 is due at 400 ms of sim time, the host is at 200 ms
        host.send_echo(1, np.zeros(400, np.float32), 400e3)
        host.send_heartbeat(stamp_ns=2 * PERIOD_NS, lockstep=True)
        assert wait_until(lambda: len(pings) == 3)
    finally:
        host.stop()
        mock.stop()
    assert [(p.ping_seq, f.stamp_ns) for p, f in pings] == [
        (0, 0), (1, PERIOD_NS), (2, 2 * PERIOD_NS)]
    st = mock.stats()
    assert st["lockstep_starts"] == 1 and st["echoes_complete"] == 2
    assert st.get("echo_timeouts", 0) == 0


def test_adapter_forwards_clock_and_stamps_pings_with_sim_time(tmp_path: Path) -> None:
    bus = f"mem://{unique('serial-ls-')}"
    sim = Node("sim", bus=bus, diagnostics_period_s=0)
    clock = sim.create_publisher(Clock, "/clock")
    echoes = sim.create_publisher(SonarEcho, "/sonar/0/echo")
    got: list[SonarPing] = []

    def on_ping(msg: SonarPing) -> None:
        got.append(msg)
        if msg.next_ns >= 0:
            echoes.publish(SonarEcho(stamp_ns=msg.stamp_ns, ping_seq=msg.ping_seq, fs=400e3,
                                     samples=np.zeros(400, np.float32), leaves_in_beam=0,
                                     fidelity="test"))

    sim.create_subscription(SonarPing, "/sonar/0/ping", on_ping)
    mock = MockSonarHead("mock", pty=True, link=str(tmp_path / "head"), rate_hz=5,
                         encoding="float32", throttle=False)
    adapter = SonarHeadAdapter("sonar_head", bus=bus, port=str(tmp_path / "head"),
                               ping_rate_hz=5, echo_samples=400, encoding="float32")
    mock.start()
    adapter.start()
    sim.start()
    try:
        assert adapter.host.link.wait_connected(5.0)
        assert clock.wait_for_subscribers(5.0)
        t = 0
        while t <= 3 * PERIOD_NS:
            clock.publish(Clock(stamp_ns=t, lockstep=True))
            n_due = t // PERIOD_NS + 1
            assert wait_until(lambda n=n_due: sum(p.next_ns >= 0 for p in got) >= n, 10.0), got
            t += 20_000_000
    finally:
        sim.stop()
        adapter.stop()
        mock.stop()
    lockstep = [p for p in got if p.next_ns >= 0]
    assert [(p.ping_seq, p.stamp_ns, p.next_ns) for p in lockstep] == [
        (k, k * PERIOD_NS, (k + 1) * PERIOD_NS) for k in range(4)]


def test_a_lockstep_ping_whose_echo_does_not_come_is_fired_again_the_same(
        tmp_path: Path) -> None:
    """The host's loop waits for a sim-time ping: one lost on the way must not hold it up."""
    mock = MockSonarHead("mock", pty=True, link=str(tmp_path / "head"), rate_hz=5,
                         encoding="int16", seed=7, throttle=False, echo_timeout_s=0.3)
    pings: list[tuple[PingPayload, Frame]] = []
    lock = threading.Lock()

    def on_ping(ping: PingPayload, frame: Frame) -> None:
        with lock:
            if frame.stamp_ns <= 3 * PERIOD_NS:
                pings.append((ping, frame))

    mock.start()
    host = SonarHeadHost(str(tmp_path / "head"), on_ping=on_ping)
    host.start()
    try:
        assert host.link.wait_connected(5.0)
        host.send_heartbeat(stamp_ns=0, lockstep=True)
        assert wait_until(lambda: len(pings) >= 2)  # ping 0, unanswered, then ping 0 again
        host.send_echo(0, np.zeros(400, np.float32), 400e3)
        assert wait_until(lambda: mock.stats()["echoes_complete"] == 1)
        host.send_heartbeat(stamp_ns=PERIOD_NS, lockstep=True)
        assert wait_until(lambda: any(p.ping_seq == 1 for p, _ in pings))
    finally:
        host.stop()
        mock.stop()
    first, again = pings[0], pings[1]
    assert (first[0], first[1].stamp_ns) == (again[0], again[1].stamp_ns)  # seq, beam, stamp
    assert first[0].ping_seq == 0 and first[1].stamp_ns == 0
    st = mock.stats()
    assert st["pings_refired"] >= 1 and st["echo_timeouts"] == st["pings_refired"]
    assert st["echoes_complete"] == 1 and st["lockstep_starts"] == 1
