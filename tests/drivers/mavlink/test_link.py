"""MAVLink links, one conformance suite over the backends: TCP (both ends), UDP (both ends)
and serial (a pty): messages both ways, bad frames and unknown messages counted, a peer that
goes and comes back, and what a bad URL or a port in use says."""

from __future__ import annotations

import socket
import time
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from drivers.mavlink.link import MavlinkLink, mavlink, open_mavlink
from drivers.serial.ptyport import PtyPort

Pair = tuple[MavlinkLink, MavlinkLink]


def _free_port(kind: int = socket.SOCK_STREAM) -> int:
    with socket.socket(socket.AF_INET, kind) as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def _until(cond: Callable[[], bool], *links: MavlinkLink, timeout: float = 5.0) -> None:
    deadline = time.monotonic() + timeout
    while not cond():
        if time.monotonic() > deadline:
            raise TimeoutError([ln.stats() for ln in links])
        for ln in links:
            ln.recv(0.01)


def _tcp() -> Pair:
    port = _free_port()
    server = open_mavlink(f"tcpin://127.0.0.1:{port}")
    client = open_mavlink(f"tcp://127.0.0.1:{port}", component=1)
    return server, client


def _udp() -> Pair:
    port = _free_port(socket.SOCK_DGRAM)
    server = open_mavlink(f"udpin://127.0.0.1:{port}")
    client = open_mavlink(f"udp://127.0.0.1:{port}", component=1)
    return server, client


@pytest.fixture(params=["tcp", "udp"])
def pair(request: pytest.FixtureRequest) -> Iterator[Pair]:
    a, b = {"tcp": _tcp, "udp": _udp}[request.param]()
    try:
        yield a, b
    finally:
        a.close()
        b.close()


def _heartbeat() -> Any:
    return mavlink.MAVLink_heartbeat_message(0, 8, 0, 0, 4, 3)


def _exchange(a: MavlinkLink, b: MavlinkLink) -> None:
    """b speaks first (a server learns its peer so), then a answers."""
    got: list[Any] = []
    _until(lambda: b.connected, a, b)
    b.send(_heartbeat())
    _until(lambda: bool(got.extend(a.recv(0.01)) or got), a)
    assert got[0].get_type() == "HEARTBEAT" and got[0].get_srcComponent() == 1
    back: list[Any] = []
    assert a.send(mavlink.MAVLink_hil_actuator_controls_message(7, [0.5] * 16, 0, 1))
    _until(lambda: bool(back.extend(b.recv(0.01)) or back), b)
    assert back[0].get_type() == "HIL_ACTUATOR_CONTROLS" and back[0].time_usec == 7


def test_messages_both_ways_and_bad_ones_counted(pair: Pair) -> None:
    a, b = pair
    _exchange(a, b)
    tx = mavlink.MAVLink(None, srcSystem=2, srcComponent=1)
    good = bytearray(_heartbeat().pack(tx))
    good[-1] ^= 0xFF
    unknown = bytearray(_heartbeat().pack(tx))
    unknown[7:10] = b"\xee\xee\x00"
    b._write(b"\x00\xffnot mavlink" + bytes(good) + bytes(unknown))
    _until(lambda: a.stats()["bad"] >= 2 and a.stats()["unknown"] == 1, a)
    _exchange(a, b)  # the link goes on
    st = a.stats()
    assert st["messages_in"] == 2 and st["sent"] == 2 and st["bytes_in"] > 0


def test_a_tcp_peer_that_goes_is_found_again() -> None:
    server, client = _tcp()
    try:
        _exchange(server, client)
        client.close()  # PX4 exits; a new one connects
        client = open_mavlink(f"tcp://127.0.0.1:{server.port}", component=1)
        _exchange(server, client)
        assert server.stats()["connects"] == 2 and server.stats()["disconnects"] == 1
        # the client side: its server restarts on the same port
        port = server.port
        server.close()
        _until(lambda: not client.connected, client)
        server = open_mavlink(f"tcpin://127.0.0.1:{port}")
        _exchange(server, client)
        assert client.stats()["connects"] == 2
    finally:
        server.close()
        client.close()


def test_serial_over_a_pty(tmp_path: Path) -> None:
    pty = PtyPort(tmp_path / "fc")
    link = open_mavlink(f"serial://{tmp_path / 'fc'}?baud=921600")
    try:
        _until(lambda: link.connected, link)
        tx = mavlink.MAVLink(None, srcSystem=1, srcComponent=1)
        pty.write(_heartbeat().pack(tx))
        got: list[Any] = []
        _until(lambda: bool(got.extend(link.recv(0.01)) or got), link)
        assert got[0].get_type() == "HEARTBEAT"
        assert link.send(mavlink.MAVLink_hil_actuator_controls_message(9, [0.0] * 16, 0, 0))
        rx = mavlink.MAVLink(None)
        assert rx.parse_buffer(pty.read(4096, 2.0))[0].time_usec == 9
        pty.unplug()  # the USB cable pulled, then put back
        _until(lambda: not link.connected, link)
        pty.replug()
        _until(lambda: link.connected, link, timeout=10.0)
        assert link.stats()["connects"] == 2
    finally:
        link.close()
        pty.close()


def test_bad_urls_and_a_port_in_use_say_what() -> None:
    with pytest.raises(ValueError, match="unknown scheme 'mqtt'"):
        open_mavlink("mqtt://x:1")
    with pytest.raises(ValueError, match="HOST:PORT"):
        open_mavlink("tcpin://127.0.0.1")
    with pytest.raises(ValueError, match="baud"):
        open_mavlink("serial:///dev/ttyACM0?baud=fast")
    with pytest.raises(ValueError, match="colour"):
        open_mavlink("serial:///dev/ttyACM0?colour=red")
    taken = socket.socket()
    taken.bind(("127.0.0.1", 0))
    taken.listen(1)
    try:
        port = taken.getsockname()[1]
        with pytest.raises(OSError, match=f"cannot listen on TCP 127.0.0.1:{port}"):
            open_mavlink(f"tcpin://127.0.0.1:{port}")
    finally:
        taken.close()
    link = open_mavlink("udp://127.0.0.1:9")
    link.close()
    link.close()  # idempotent
    assert not link.send(_heartbeat()) and link.stats()["send_dropped"] == 1


@settings(max_examples=60, deadline=None)
@given(st.binary(max_size=300), st.binary(max_size=300))
def test_noise_around_a_message_never_hides_it(before: bytes, after: bytes) -> None:
    """Whatever bytes come before and after a message, it is found once, the rest is
    counted as bad or ignored, and parsing never raises."""
    link = open_mavlink("udp://127.0.0.1:9")
    try:
        tx = mavlink.MAVLink(None, srcSystem=3, srcComponent=1)
        msg = mavlink.MAVLink_hil_actuator_controls_message(123456, [0.25] * 16, 129, 1)
        marker = bytes(msg.pack(tx))
        got = link._parse(before.replace(b"\xfd", b"").replace(b"\xfe", b"") + marker + after)
        found = [m for m in got if m.get_type() == "HIL_ACTUATOR_CONTROLS"
                 and m.time_usec == 123456]
        assert len(found) >= 1
    finally:
        link.close()
