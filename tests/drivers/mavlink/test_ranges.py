"""Echoes as range finders: MAVLink orientations of a beam's axis, DISTANCE_SENSOR per ear
from the echo (never the geometry), OBSTACLE_DISTANCE sectors, and the MAVLink range-finder
node against a stand-in autopilot on TCP."""

from __future__ import annotations

import math
import socket
import time
from typing import Any

import numpy as np
import pytest

from drivers.mavlink.link import mavlink
from drivers.mavlink.rangefinder import MavlinkRangefinder
from drivers.mavlink.ranges import EchoRanger, RangeFinderSpec, SonarRange, orientation_of
from hil_bridge.bus.messages import SonarEcho
from hil_bridge.bus.node import Node
from sim_core.config import ConfigError
from sim_core.pose import quat_rotate
from sim_core.sensors import echo_ranges
from sim_core.sonar import Beam, EchoParams, synthesize
from sim_core.sonar.params import Ear


@pytest.mark.parametrize(("axis", "code"), [
    ((1.0, 0.0, 0.0), 0), ((0.0, 1.0, 0.0), 2), ((0.0, -1.0, 0.0), 6), ((-1.0, 0.0, 0.0), 4),
    ((0.0, 0.0, 1.0), 25), ((0.0, 0.0, -1.0), 24), ((math.cos(0.05), 0.0, math.sin(0.05)), 0),
])
def test_standard_orientations(axis: tuple[float, float, float], code: int) -> None:
    got, quat = orientation_of(np.array(axis), 5.0)
    assert got == code and quat == [0.0] * 4


def test_an_oblique_beam_is_custom_with_its_rotation() -> None:
    axis = np.array([math.cos(1.2), 0.0, math.sin(1.2)])  # FRD: 69° below the nose
    code, quat = orientation_of(axis, 5.0)
    assert code == 100
    np.testing.assert_allclose(quat_rotate(np.array(quat), [1.0, 0.0, 0.0]), axis, atol=1e-12)


def leaf_echo(distance: float, *, ears: int = 2, down: bool = True) -> SonarEcho:
    """The echo model's echo of one leaf ``distance`` below (or ahead of) a sonar with
    ``ears`` ears, as the server publishes it."""
    axis = np.array([0.0, 0.0, -1.0]) if down else np.array([1.0, 0.0, 0.0])
    leaf = (axis[None] * distance, axis[None], np.array([0.02]))
    params = EchoParams(ears=tuple(Ear(offset=(0.0, 0.01 * (k - 0.5), 0.0))
                                   for k in range(ears)))
    e = synthesize(leaf, Beam([0.0, 0.0, 0.0], axis, 0.7), params, fidelity="reference")
    return SonarEcho(stamp_ns=2_000_000_000, ping_seq=1, fs=e.fs, samples=e.samples,
                     leaves_in_beam=1, fidelity="reference", sonar_id=0,
                     emit_ns=1_990_000_000, boresight_body=np.array(
                         [0.0, 0.0, -1.0] if down else [1.0, 0.0, 0.0]))


def test_distance_sensor_per_ear_from_the_echo() -> None:
    ranger = EchoRanger(RangeFinderSpec(sonars=(SonarRange(sensor_id=4, fov_deg=40.0),)))
    echo = leaf_echo(3.21)
    msgs = ranger.messages(echo)
    assert [m.id for m in msgs] == [4, 5]
    level = echo_ranges(echo.samples, echo.fs).level_db
    for m, db in zip(msgs, level, strict=True):
        expect = (3.21 + math.hypot(3.21, 0.005)) / 2  # emitter to leaf to ear, halved
        assert m.current_distance == round(expect * 100)
        assert (m.min_distance, m.max_distance, m.orientation) == (20, 1000, 25)
        assert m.type == mavlink.MAV_DISTANCE_SENSOR_ULTRASOUND and m.covariance == 4
        assert m.horizontal_fov == pytest.approx(math.radians(40.0))
        assert m.signal_quality == round(100 * (db + 100) / 60)  # 60 dB over the floor: 100
        assert m.time_boot_ms == 1990
    assert ranger.counters["returns"] == 2


def test_no_return_is_out_of_range_and_a_bare_echo_is_counted() -> None:
    ranger = EchoRanger(RangeFinderSpec())
    quiet = SonarEcho(stamp_ns=1, ping_seq=1, fs=4e5, samples=np.zeros((2, 24000), np.float32),
                      leaves_in_beam=0, fidelity="fast", sonar_id=0,
                      boresight_body=np.array([0.0, 0.0, -1.0]))
    msgs = ranger.messages(quiet)
    assert [m.current_distance for m in msgs] == [1001, 1001]  # max + 1 cm: nothing in reach
    assert [m.signal_quality for m in msgs] == [0, 0]
    old = SonarEcho(stamp_ns=1, ping_seq=2, fs=4e5, samples=np.zeros(100, np.float32),
                    leaves_in_beam=0, fidelity="fast", sonar_id=0)  # no boresight_body
    assert ranger.messages(old) == [] and ranger.counters["echoes_unoriented"] == 1
    pinned = EchoRanger(RangeFinderSpec(sonars=(SonarRange(orientation=25),)))
    assert pinned.messages(old)[0].orientation == 25


def test_obstacle_distance_sectors_of_a_forward_beam() -> None:
    spec = RangeFinderSpec(sonars=(SonarRange(fov_deg=20.0, obstacle_distance=True),))
    ranger = EchoRanger(spec)
    msgs = ranger.messages(leaf_echo(4.0, ears=1, down=False))
    obstacle = msgs[-1]
    assert obstacle.get_type() == "OBSTACLE_DISTANCE" and obstacle.frame == 12
    d = list(obstacle.distances)
    covered = [k for k, v in enumerate(d) if v != 65535]
    assert sorted(covered) == [0, 1, 2, 70, 71]  # ±10° around ahead, 5° sectors
    assert {d[k] for k in covered} == {400}
    assert obstacle.increment == 5 and obstacle.increment_f == 5.0
    down = ranger.messages(leaf_echo(4.0, ears=1, down=True))
    assert all(m.get_type() == "DISTANCE_SENSOR" for m in down)
    assert ranger.counters["obstacle_skipped"] == 1


class FakeAutopilot:
    """ArduPilot SITL's SERIAL1 as far as a range finder sees it: a TCP port that reads
    MAVLink (and sends heartbeats back)."""

    def __init__(self, port: int = 0) -> None:
        self.sock = socket.socket()
        self.sock.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        self.sock.bind(("127.0.0.1", port))
        self.sock.listen(1)
        self.port = self.sock.getsockname()[1]
        self.rx = mavlink.MAVLink(None)
        self.conn: socket.socket | None = None

    def messages(self, kind: str, n: int, timeout: float = 10.0) -> list[Any]:
        if self.conn is None:
            self.sock.settimeout(timeout)
            self.conn, _ = self.sock.accept()
            self.conn.settimeout(0.2)
        out: list[Any] = []
        deadline = time.monotonic() + timeout
        while len(out) < n and time.monotonic() < deadline:
            try:
                data = self.conn.recv(4096)
            except TimeoutError:
                continue
            out += [m for m in self.rx.parse_buffer(data) or () if m.get_type() == kind]
        return out

    def close(self) -> None:
        if self.conn is not None:
            self.conn.close()
            self.conn = None
        self.sock.close()


def test_the_rangefinder_node_feeds_an_autopilot_and_survives_its_restart() -> None:
    ap = FakeAutopilot()
    bus = "mem://rangefinder_node"
    node = MavlinkRangefinder("rangefinder", bus=bus, link=f"tcp://127.0.0.1:{ap.port}",
                              heartbeat_hz=20.0)
    pub_node = Node("sim", bus=bus)
    pub = pub_node.create_publisher(SonarEcho, "/sonar/0/echo")
    node.start()
    try:
        assert ap.messages("HEARTBEAT", 1)
        echo = leaf_echo(2.5)
        pub.publish(echo)
        got = ap.messages("DISTANCE_SENSOR", 2)
        assert [m.current_distance for m in got] == [250, 250]
        port = ap.port
        ap.close()  # SITL restarts on the same port
        ap = FakeAutopilot(port)
        assert ap.messages("HEARTBEAT", 1)
        pub.publish(echo)
        assert len(ap.messages("DISTANCE_SENSOR", 2)) == 2
        st = node.stats()
        assert st["autopilot_connects"] == 2 and st["ranges_sent"] >= 2
    finally:
        node.stop()
        pub_node.stop()
        ap.close()
    assert node.failure(final=True) is None


def test_a_private_domain_needs_the_link() -> None:
    from hil_bridge.bus.domain import Domain, use

    with use(Domain.private("/tmp/echoloop-test-rf")), pytest.raises(ConfigError, match="link"):
        MavlinkRangefinder("rangefinder", bus="mem://x")
