"""Fault wrapper and the resilient link: ENOBUFS retry, bus-off recovery, error frames, logs."""

from __future__ import annotations

import errno
from collections.abc import Iterator

import can
import pytest

from drivers.can.bus import CanBusConfig, CanLink, LinkPolicy
from drivers.can.codec import GliderCanCodec
from drivers.faults.can_bus import (
    CAN_ERR_BUSOFF,
    CAN_ERR_RESTARTED,
    CanFaultConfig,
    FaultInjectingBus,
)
from hil_bridge.errors import CodecError
from tests.drivers.can._util import unique, wait_until


def _frame(i: int) -> can.Message:
    return can.Message(arbitration_id=0x120 + (i % 16), data=i.to_bytes(8, "little"),
                       is_extended_id=False)


@pytest.fixture
def channel() -> str:
    return unique("faults-")


@pytest.fixture
def peer(channel: str) -> Iterator[can.BusABC]:
    bus = can.Bus(interface="virtual", channel=channel)
    yield bus
    bus.shutdown()


def test_wrapper_is_transparent_without_faults(channel: str, peer: can.BusABC) -> None:
    with FaultInjectingBus(can.Bus(interface="virtual", channel=channel)) as bus:
        bus.send(_frame(1))
        got = peer.recv(1.0)
        assert got is not None and bytes(got.data) == bytes(_frame(1).data)
        peer.send(_frame(2))
        back = bus.recv(1.0)
        assert back is not None and back.arbitration_id == _frame(2).arbitration_id
        assert bus.state == can.BusState.ACTIVE
        assert dict(bus.injected) == {}


def test_enobufs_is_a_can_operation_error_with_errno(channel: str) -> None:
    with FaultInjectingBus(can.Bus(interface="virtual", channel=channel)) as bus:
        bus.inject_enobufs(2)
        for _ in range(2):
            with pytest.raises(can.CanOperationError) as info:
                bus.send(_frame(0))
            assert info.value.error_code == errno.ENOBUFS
        bus.send(_frame(0))
        assert bus.injected["enobufs"] == 2


def test_bus_off_then_automatic_restart(channel: str, peer: can.BusABC) -> None:
    with FaultInjectingBus(can.Bus(interface="virtual", channel=channel)) as bus:
        bus.inject_bus_off(0.1)
        assert bus.state == can.BusState.ERROR
        with pytest.raises(can.CanOperationError) as info:
            bus.send(_frame(0))
        assert info.value.error_code == errno.ENETDOWN
        err = bus.recv(1.0)
        assert err is not None and err.is_error_frame and err.arbitration_id & CAN_ERR_BUSOFF
        peer.send(_frame(3))  # lost: a bus-off controller hears nothing
        assert wait_until(lambda: bus.state == can.BusState.ACTIVE, timeout=2.0)
        restarted = bus.recv(1.0)
        assert restarted is not None and restarted.arbitration_id & CAN_ERR_RESTARTED
        peer.send(_frame(4))
        got = bus.recv(1.0)
        assert got is not None and bytes(got.data) == bytes(_frame(4).data)


def _received(seed: int, channel: str) -> tuple[list[tuple[int, bool, bytes]], dict[str, int]]:
    cfg = CanFaultConfig(seed=seed, error_frame_rate=0.2, truncate_rate=0.2, foreign_rate=0.1,
                         drop_rate=0.1)
    bus = FaultInjectingBus(can.Bus(interface="virtual", channel=channel), cfg)
    peer = can.Bus(interface="virtual", channel=channel)
    try:
        for i in range(200):
            peer.send(_frame(i))
        out = []
        while (msg := bus.recv(0.05)) is not None:
            out.append((msg.arbitration_id, msg.is_error_frame, bytes(msg.data)))
        return out, dict(bus.injected)
    finally:
        peer.shutdown()
        bus.shutdown()


def test_faults_are_seeded() -> None:
    a = _received(11, unique("seed-a-"))
    b = _received(11, unique("seed-b-"))
    c = _received(12, unique("seed-c-"))
    assert a == b
    assert a != c
    frames, injected = a
    assert injected["error_frames"] == sum(1 for _, err, _ in frames if err)
    assert injected["dropped"] + len(frames) - injected["error_frames"] == 200


def test_config_is_validated() -> None:
    with pytest.raises(ValueError, match="drop_rate"):
        CanFaultConfig(drop_rate=1.5)
    with pytest.raises(ValueError, match="enobufs_burst"):
        CanFaultConfig(enobufs_burst=0)


def _link(channel: str, faults: CanFaultConfig | None = None, **kw: object) -> CanLink:
    return CanLink(CanBusConfig(channel=channel, faults=faults or CanFaultConfig()), **kw)  # type: ignore[arg-type]


def test_link_retries_send_buffer_full_with_backoff(channel: str, peer: can.BusABC) -> None:
    with _link(channel) as link:
        bus = link.bus
        assert isinstance(bus, FaultInjectingBus)
        bus.inject_enobufs(2)
        assert link.send(_frame(1))
        assert peer.recv(1.0) is not None
        stats = link.stats()
        assert stats["tx_buffer_full"] == 2 and stats["tx_retried_ok"] == 1
        assert stats["state"] == "up"
        bus.inject_enobufs(100)
        assert not link.send(_frame(2))
        assert link.stats()["tx_dropped"] == 1 and link.state == "degraded"
        bus.inject_enobufs(0)
        assert link.send(_frame(3)) and link.state == "up"


def test_link_recovers_from_bus_off_by_reopening(channel: str, peer: can.BusABC) -> None:
    with _link(channel, policy=LinkPolicy(reopen_backoff_s=0.02)) as link:
        first = link.bus
        assert isinstance(first, FaultInjectingBus)
        first.inject_bus_off(60.0)  # never restarts by itself: only a re-open helps
        assert not link.send(_frame(0))
        assert link.state == "bus_off"
        assert wait_until(lambda: link.send(_frame(1)), timeout=5.0)
        assert link.state == "up" and link.bus is not first
        stats = link.stats()
        assert stats["bus_off"] == 1 and stats["bus_off_recoveries"] == 1
        assert stats["reopens"] >= 1 and stats["tx_dropped_bus_off"] >= 1
        assert peer.recv(1.0) is not None


def test_link_recovers_from_bus_off_by_restart_frame(channel: str) -> None:
    with _link(channel) as link:
        bus = link.bus
        assert isinstance(bus, FaultInjectingBus)
        bus.inject_bus_off(0.2)
        assert link.recv(0.02) is None  # the BUSOFF error frame is counted, not returned
        assert link.state == "bus_off"
        assert wait_until(lambda: link.recv(0.01) is None and link.state == "up", timeout=3.0)
        stats = link.stats()
        assert stats["error_frames"] == 2 and stats["bus_off_recoveries"] == 1


def test_link_receive_errors_never_raise(channel: str) -> None:
    faults = CanFaultConfig(recv_error_rate=1.0)
    policy = LinkPolicy(reopen_after_failures=3, send_backoff_s=0.001)
    with _link(channel, faults, policy=policy) as link:
        for _ in range(10):
            assert link.recv(0.01) is None
        stats = link.stats()
        assert stats["rx_errors"] >= 10 and stats["reopens"] >= 3
        assert stats["state"] == "up"


def test_corrupt_and_error_frames_are_counted_and_dropped(
    channel: str, peer: can.BusABC
) -> None:
    faults = CanFaultConfig(seed=3, error_frame_rate=0.3, truncate_rate=0.3, foreign_rate=0.2)
    codec = GliderCanCodec()
    sent = [codec.encode("GLIDER_STATE_POS", i % 16, {"x_m": i, "y_m": -i, "z_m": 100.0})
            for i in range(100)]
    decoded, rejected = 0, 0
    with _link(channel, faults) as link:
        for frame in sent:
            peer.send(frame)
        while (msg := link.recv(0.05)) is not None:
            try:
                codec.decode(msg)
                decoded += 1
            except CodecError:
                rejected += 1
        injected = link.bus.injected  # type: ignore[union-attr]
        assert link.stats()["error_frames"] == injected["error_frames"] > 0
    assert decoded + rejected == 100
    assert rejected >= injected["foreign"] > 0
    assert rejected <= injected["truncated"] + injected["foreign"]


def test_candump_log_is_readable_by_logreader(channel: str, peer: can.BusABC, tmp_path) -> None:  # type: ignore[no-untyped-def]
    path = tmp_path / "traffic.log"
    with _link(channel, log_path=path) as link:
        assert link.send(_frame(5))
        peer.send(_frame(6))
        got = link.recv(1.0)
        assert got is not None
        bus = link.bus
        assert isinstance(bus, FaultInjectingBus)
        bus.inject_bus_off(0.01)
        link.recv(0.5)  # the error frame is logged too
    rows = list(can.LogReader(path))
    assert [(m.arbitration_id, bytes(m.data), m.is_rx) for m in rows[:2]] == [
        (_frame(5).arbitration_id, bytes(_frame(5).data), False),
        (_frame(6).arbitration_id, bytes(_frame(6).data), True),
    ]
    assert rows[2].is_error_frame
    assert path.read_text().splitlines()[0].endswith(" T")
