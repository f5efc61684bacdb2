"""The SITL JSON node against the protocol double and a lockstep server (mem:// bus): lockstep,
frame counters, restarts, bad packets, one answer per frame, and the loop closing."""

from __future__ import annotations

import itertools
import math
import socket
from collections.abc import Iterator
from typing import Any

import numpy as np
import pytest

from drivers.ardupilot.sitl import ArduPilotSitl
from drivers.mocks.sitl_double import SitlDouble, WingLeveler
from hil_bridge.server.sim_server import SimServer
from sim_core.config import ConfigError
from sim_core.pose import euler_from_quat

RATE = 100
TICK = 1.0 / RATE
_n = itertools.count()


def _scene() -> dict[str, Any]:
    return {
        "state_rate_hz": RATE,
        "clock": {"mode": "lockstep", "lockstep_timeout_s": 5.0},
        "swarm": {"overrides": {"numAgents": 3, "dt": 0.1}, "seed": 4},
        "vehicles": [{"id": 7, "sixdof": {},
                      "path": {"kind": "points", "points": [[0, 0, 300], [100, 0, 300]]}}],
    }


@pytest.fixture
def loop() -> Iterator[tuple[SimServer, ArduPilotSitl, SitlDouble]]:
    bus = f"mem://sitl_{next(_n)}"
    srv = SimServer("server", bus=bus, scene=_scene(), autopilots=[7])
    node = ArduPilotSitl("sitl", bus=bus, instances=[{"vehicle_id": 7, "port": 0}],
                         reply_timeout_s=5.0)
    node.start()
    srv.start()
    double = SitlDouble(port=node.ports[7], timeout_s=10.0)
    try:
        yield srv, node, double
    finally:
        double.close()
        srv.stop()
        node.stop()
        assert node.failure(final=True) is None and srv.failure(final=True) is None


def test_lockstep_one_tick_per_frame_and_the_loop_closes(
        loop: tuple[SimServer, ArduPilotSitl, SitlDouble]) -> None:
    srv, node, double = loop
    answers = double.fly(800, WingLeveler(bank_deg=25.0))
    stamps = np.array([a["timestamp"] for a in answers])
    np.testing.assert_allclose(np.diff(stamps), TICK, rtol=0, atol=1e-9)  # one tick a frame
    st = node.stats()
    assert st["frames"] == st["replies"] == 800
    assert st["surfaces_published"] == 799  # every frame but the first answers a state
    assert st["packets_bad"] == st["replies_stale"] == st["frames_lost"] == 0
    s = srv.stats()
    assert s["surfaces_applied"] == 799 and s["stalls"] == 0
    # the firmware's aileron banked the 6-DoF glider right, and it turned right (NED yaw grew)
    roll, _, yaw = euler_from_quat(np.array([answers[-1]["quaternion"] for _ in (0,)]))
    assert math.degrees(float(roll[0])) == pytest.approx(25.0, abs=8.0)
    yaw0 = euler_from_quat(np.array(answers[0]["quaternion"]))[2]
    assert float(yaw[0]) - float(yaw0) > 0.2
    # one per frame; the last frame's is booked just after its answer left, maybe after stats()
    assert st["added_latency_us"]["n"] in (799, 800)


def test_repeats_gaps_restarts_and_bad_packets(
        loop: tuple[SimServer, ArduPilotSitl, SitlDouble]) -> None:
    srv, node, double = loop
    pilot = WingLeveler()
    double.fly(10, pilot)
    ticks = srv.stats()["ticks"]
    # SITL re-sending the same frame gets the same line again, and nothing is flown
    double.send_raw(double.packet(pilot(double.last)))
    again = double.receive()
    assert again["timestamp"] == double.last["timestamp"]
    assert srv.stats()["ticks"] == ticks
    # bad datagrams are dropped and counted, never answered
    for bad in (b"", b"\x1aH", struct_bad_magic(), double.packet([1500] * 16) + b"x"):
        double.send_raw(bad)
    with pytest.raises(socket.timeout):
        double._sock.settimeout(0.3)
        double.receive()
    double._sock.settimeout(10.0)
    # a gap in the counter is counted; the flow goes on
    double.frame_count += 3
    double.fly(5, pilot)
    # a restarted SITL counts from 1 again: detected, counted, and served on the same clock
    before = double.last["timestamp"]
    double.restart()
    after = double.fly(5, pilot)
    assert after[0]["timestamp"] > before
    st = node.stats()
    assert st["frames_repeated"] == 1
    assert st["packets_bad"] == 4
    assert st["frames_lost"] == 3
    assert st["sitl_restarts"] == 1
    assert st["replies"] == st["frames"] == 10 + 1 + 5 + 5


def struct_bad_magic() -> bytes:
    import struct

    return struct.pack("<HHI16H", 1234, 400, 1, *[1500] * 16)


def test_thirty_two_channels(loop: tuple[SimServer, ArduPilotSitl, SitlDouble]) -> None:
    _, node, double = loop
    wide = SitlDouble(port=double.port, channels=32, timeout_s=10.0)
    try:
        answers = wide.fly(20)
    finally:
        wide.close()
    assert len(answers) == 20 and node.stats()["packets_bad"] == 0


def test_bad_params_fail_at_load_with_the_key() -> None:
    with pytest.raises(ConfigError, match="instances"):
        ArduPilotSitl("sitl", bus="mem://x", instances=[])
    with pytest.raises(ConfigError, match="distinct"):
        ArduPilotSitl("sitl", bus="mem://x", instances=[{"vehicle_id": 1}],
                      channels={"aileron": 2})
    with pytest.raises(ConfigError, match="bogus"):
        ArduPilotSitl("sitl", bus="mem://x", instances=[{"vehicle_id": 1, "bogus": 1}])


def test_a_port_in_use_fails_the_start_naming_it() -> None:
    taken = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    taken.bind(("127.0.0.1", 0))
    port = taken.getsockname()[1]
    node = ArduPilotSitl("sitl", bus="mem://sitl_taken",
                         instances=[{"vehicle_id": 1, "port": 0}, {"vehicle_id": 2, "port": port}])
    try:
        with pytest.raises(OSError, match=f"vehicle 2.*cannot bind UDP 127.0.0.1:{port}"):
            node.start()
    finally:
        taken.close()
        node.stop()


def test_a_noisy_imu_comes_from_the_sensor_model() -> None:
    """``sensors: {noise: true}``: the IMU SITL is sent is the sensor model's, seeded: the
    gyro's white noise at 100 Hz is 3.394e-4 · √100 = 3.4e-3 rad/s per sample."""
    bus = f"mem://sitl_{next(_n)}"
    srv = SimServer("server", bus=bus, scene=_scene(), autopilots=[7])
    node = ArduPilotSitl("sitl", bus=bus, instances=[{"vehicle_id": 7, "port": 0}],
                         reply_timeout_s=5.0, sensors={"noise": True}, seed=3)
    node.start()
    srv.start()
    double = SitlDouble(port=node.ports[7], timeout_s=10.0)
    try:
        answers = double.fly(300, WingLeveler())
    finally:
        double.close()
        srv.stop()
        node.stop()
    gyro = np.array([a["imu"]["gyro"] for a in answers[100:]])
    wobble = np.diff(gyro, axis=0).std(axis=0) / math.sqrt(2.0)  # white: the flight is smooth
    np.testing.assert_allclose(wobble, 3.394e-4 * 10.0, rtol=0.25)
    assert node.failure(final=True) is None
