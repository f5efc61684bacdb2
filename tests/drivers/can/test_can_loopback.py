"""The domain's CAN bus across processes (drivers.can.loopback): python-can's udp_multicast
format on loopback only, one group and port per domain, a sender never handed its own frames."""

from __future__ import annotations

import multiprocessing as mp
import queue
import random
import socket
import time

import can
import pytest

from drivers.can.bus import CanBusConfig, CanLink
from hil_bridge.bus.domain import Domain, use

pytestmark = pytest.mark.processes


@pytest.fixture
def domain() -> Domain:
    return Domain(random.SystemRandom().randrange(50, 100))


def _link(domain: Domain) -> CanLink:
    with use(domain):
        return CanLink(CanBusConfig.from_params(interface="udp_multicast"))


def _frame(i: int) -> can.Message:
    return can.Message(arbitration_id=0x100 + i, data=bytes([i, 2, 3]), is_extended_id=False)


def _recv_ids(link: CanLink, n: int, timeout: float = 10.0) -> list[int]:
    got: list[int] = []
    deadline = time.monotonic() + timeout
    while len(got) < n and time.monotonic() < deadline:
        msg = link.recv(0.1)
        if msg is not None:
            got.append(msg.arbitration_id)
    return got


def test_each_domain_has_its_own_group_and_port() -> None:
    groups = {Domain(n).can_multicast() for n in range(100)}
    assert len(groups) == 100
    assert all(g.startswith("239.255.74.") for g, _ in groups)
    ports = {p for _, p in groups}
    assert not ports & {p for n in range(100) for p in Domain(n).ports}
    with pytest.raises(ValueError, match="virtual"):
        Domain.private("/tmp").can_multicast()


def test_a_frame_reaches_every_other_link_and_not_its_sender(domain: Domain) -> None:
    a, b, c = _link(domain), _link(domain), _link(domain)
    try:
        assert _recv_ids(b, 1, timeout=0.2) == []  # opens the buses before anything is sent
        assert _recv_ids(c, 1, timeout=0.2) == []
        assert _recv_ids(a, 1, timeout=0.2) == []
        for i in range(3):
            assert a.send(_frame(i))
        assert _recv_ids(b, 3) == [0x100, 0x101, 0x102]
        assert _recv_ids(c, 3) == [0x100, 0x101, 0x102]
        assert _recv_ids(a, 1, timeout=0.5) == []
    finally:
        for link in (a, b, c):
            link.close()


def test_two_domains_do_not_hear_each_other(domain: Domain) -> None:
    other = Domain((domain.number or 0) - 40)
    a, b = _link(domain), _link(other)
    try:
        _recv_ids(b, 1, timeout=0.2)
        a.send(_frame(1))
        assert _recv_ids(b, 1, timeout=1.0) == []
    finally:
        a.close()
        b.close()


def test_the_socket_stays_on_loopback(domain: Domain) -> None:
    link = _link(domain)
    try:
        link.recv(0.01)
        bus = link._bus
        assert bus is not None
        rx: socket.socket = bus._multicast._socket
        tx: socket.socket = bus._multicast._tx
        assert tx.getsockopt(socket.IPPROTO_IP, socket.IP_MULTICAST_TTL) == 0
        assert socket.inet_ntoa(tx.getsockopt(socket.IPPROTO_IP, socket.IP_MULTICAST_IF, 4)) \
            == "127.0.0.1"
        assert tx.getsockname()[0] == "127.0.0.1"
        assert rx.getsockname()[0] == domain.can_multicast()[0]
    finally:
        link.close()


def test_a_sender_s_frames_never_reach_its_receiving_socket(domain: Domain) -> None:
    """The kernel drops them (the socket filter), so the receive thread never wakes for them:
    read below python-can, with nothing of the link between."""
    a, b = _link(domain), _link(domain)
    try:
        a.recv(0.01)
        b.recv(0.01)
        bus_a, bus_b = a._bus, b._bus
        assert bus_a is not None and bus_b is not None
        for i in range(5):
            assert a.send(_frame(i))
        got = [bus_b._multicast.recv(1.0) for _ in range(5)]
        assert all(r is not None for r in got)
        assert bus_a._multicast.recv(0.3) is None
    finally:
        a.close()
        b.close()


def _child(number: int, ready: mp.synchronize.Event, out: mp.Queue) -> None:  # type: ignore[type-arg]
    link = _link(Domain(number))
    try:
        link.recv(0.01)
        ready.set()
        out.put(_recv_ids(link, 2))
    finally:
        link.close()


def test_a_frame_crosses_processes(domain: Domain) -> None:
    ctx = mp.get_context("spawn")
    ready, out = ctx.Event(), ctx.Queue()
    proc = ctx.Process(target=_child, args=(domain.number, ready, out))
    proc.start()
    link = _link(domain)
    try:
        assert ready.wait(60)
        deadline = time.monotonic() + 30
        got: list[int] = []
        while not got and time.monotonic() < deadline:  # until the child has both frames
            link.send(_frame(7))
            link.send(_frame(8))
            try:
                got = out.get(timeout=0.5)
            except queue.Empty:
                got = []
        assert got == [0x107, 0x108]
    finally:
        link.close()
        proc.join(30)
        if proc.is_alive():
            proc.kill()
