"""The Foxglove live view starts on loopback, serves the WebSocket protocol, and stops."""

from __future__ import annotations

import base64
import math
import os
import socket
import time

import numpy as np
import pytest

from hil_bridge.bus.codec import encode
from hil_bridge.bus.messages import Clock, GliderState, SonarEcho, SonarPing, state_quaternion
from hil_bridge.bus.transport import open_transport
from hil_bridge.server.sim_server import SimServer
from hil_bridge.tools.live import LiveView, beam_cone
from sim_core.flight import glide_attitude
from sim_core.pose import quat_from_euler, quat_rotate
from tests.hil_bridge.bus.bus_test_util import poll_until


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


def test_beam_cone_has_its_apex_at_the_sonar_and_its_axis_on_the_boresight() -> None:
    pos, axis = np.array([1.0, 2.0, 3.0]), np.array([0.0, 0.6, -0.8])
    centre, q, size = beam_cone(pos, axis, math.radians(40.0), 3.0)
    # the cylinder's local -z end (the apex, bottom_scale 0) and +z end (the base)
    np.testing.assert_allclose(centre + quat_rotate(q, [0, 0, -1.5]), pos, atol=1e-12)
    np.testing.assert_allclose(centre + quat_rotate(q, [0, 0, 1.5]), pos + 3.0 * axis,
                               atol=1e-12)
    np.testing.assert_allclose(size, [6 * math.tan(math.radians(20.0))] * 2 + [3.0])


def test_state_attitude_is_the_quaternion_or_the_flight_models_glide() -> None:
    q = quat_from_euler(-0.3, 0.05, 1.0)
    state = GliderState(stamp_ns=0, x=0.0, y=0.0, z=0.0, heading=1.0, bank=0.3, airspeed=9.0,
                        vz=0.0, qw=q[0], qx=q[1], qy=q[2], qz=q[3])
    np.testing.assert_array_equal(state_quaternion(state), q)
    old = GliderState(stamp_ns=0, x=0.0, y=0.0, z=0.0, heading=1.0, bank=0.3, airspeed=9.0,
                      vz=0.0)
    # no attitude given: the flight model's glide at that heading, bank and airspeed. A left
    # turn (bank > 0) lowers the left wing: roll = -bank; the nose is down by the SB-XC's glide
    # angle through the air (vz, here 0, is not used: an updraft does not tilt the glider)
    att = glide_attitude(1.0, 0.3, 9.0)
    np.testing.assert_allclose(state_quaternion(old), att.quat, atol=1e-12)
    assert float(att.roll) == -0.3 and 0.04 < float(att.pitch) < 0.06


def test_live_view_draws_the_beam_of_an_echo_from_its_ping() -> None:
    bus = "mem://live_beam"
    view = LiveView("live", bus=bus, port=0, rate_hz=50.0)
    view.start()
    try:
        with open_transport(bus) as raw:
            raw.publish(encode("/sonar/2/ping", SonarPing(stamp_ns=0, ping_seq=4, az=0.0,
                                                          el=0.0, beamwidth=0.6),
                               seq=0, pub_ns=0))
            echo = SonarEcho(stamp_ns=0, ping_seq=4, fs=1e5, samples=np.zeros(8),
                             leaves_in_beam=0, fidelity="fast", sonar_id=2,
                             position=[1.0, 2.0, 3.0], orientation=[1.0, 0, 0, 0],
                             boresight=[1.0, 0.0, 0.0], emit_ns=5)
            raw.publish(encode("/sonar/2/echo", echo, seq=0, pub_ns=0))
            assert poll_until(lambda: view.stats()["beams_sent"] > 0), view.stats()
    finally:
        view.stop()
