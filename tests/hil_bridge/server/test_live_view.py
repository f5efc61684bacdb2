"""The Foxglove live view starts on loopback, serves the WebSocket protocol, and stops."""

from __future__ import annotations

import base64
import os
import socket
import time

import pytest

from hil_bridge.codec import encode
from hil_bridge.live import LiveView
from hil_bridge.messages import Clock, GliderState
from hil_bridge.server import SimServer
from hil_bridge.transport import open_transport
from tests.hil_bridge.core.bus_test_util import poll_until


def _handshake(port: int) -> bytes:
    key = base64.b64encode(os.urandom(16)).decode()
    request = (
        f"GET / HTTP/1.1\r\nHost: 127.0.0.1:{port}\r\nUpgrade: websocket\r\n"
        f"Connection: Upgrade\r\nSec-WebSocket-Key: {key}\r\nSec-WebSocket-Version: 13\r\n"
        "Sec-WebSocket-Protocol: foxglove.sdk.v1\r\n\r\n"
    )
    with socket.create_connection(("127.0.0.1", port), timeout=10) as sock:
        sock.sendall(request.encode())
        data = b""
        while b"\r\n\r\n" not in data:
            chunk = sock.recv(4096)
            if not chunk:
                break
            data += chunk
    return data


def test_live_view_serves_on_loopback_and_stops() -> None:
    bus = "mem://live_view"
    srv = SimServer("server", bus=bus, scene={
        "swarm": {"overrides": {"numAgents": 3}}, "clock": {"mode": "fast"}}, stop_after_s=2.0)
    view = LiveView("live", bus=bus, port=0, rate_hz=50.0)
    view.start()
    srv.start()
    try:
        assert srv.wait_done(timeout=30)
        port = view.port
        assert port is not None and port > 0
        reply = _handshake(port)
        assert reply.startswith(b"HTTP/1.1 101"), reply[:200]
    finally:
        srv.stop()
        view.stop()
    st = view.stats()
    assert st["received"] > 0 and st["vehicles"] == 3
    # the listener closes once stop() returns (the SDK may finish closing on its own thread)
    deadline = time.monotonic() + 10.0
    while True:
        try:
            socket.create_connection(("127.0.0.1", port), timeout=2).close()
        except OSError:
            break
        assert time.monotonic() < deadline, f"port {port} still accepts after stop()"
        time.sleep(0.05)


def test_live_view_refuses_a_non_loopback_host() -> None:
    with pytest.raises(ValueError, match="loopback only"):
        LiveView("live", bus="mem://live_bad", host="0.0.0.0")


def test_live_view_survives_foreign_messages_under_its_topics() -> None:
    bus = "mem://live_foreign"
    view = LiveView("live", bus=bus, port=0)
    view.start()
    try:
        with open_transport(bus) as raw:
            state = GliderState(stamp_ns=0, x=1.0, y=2.0, z=3.0, heading=0.0, bank=0.0,
                                airspeed=9.0, vz=0.0, glider_id=4)
            raw.publish(encode("/glider/abc/state", state, seq=0, pub_ns=0))
            raw.publish(encode("/glider/5/state", Clock(stamp_ns=0), seq=0, pub_ns=0))
            raw.publish(encode("/thermals", Clock(stamp_ns=0), seq=0, pub_ns=0))
            raw.publish(encode("/sonar/0/echo", Clock(stamp_ns=0), seq=0, pub_ns=0))
            raw.publish(encode("/glider/4/state", state, seq=1, pub_ns=0))
            assert poll_until(lambda: view.stats()["received"] == 5), view.stats()
    finally:
        view.stop()
    st = view.stats()
    assert st["vehicles"] == 1 and st["bad"] == 0 and st["echoes_sent"] == 0
