"""Echoes at the sonar's world pose at the ping's emission: the beam rolls with a banked vehicle,
a mount turns it, and a delayed ping is answered where the vehicle was when it pinged."""

from __future__ import annotations

import dataclasses
import math
import queue
from typing import Any

import numpy as np
import pytest

from hil_bridge.bus.messages import GliderState, SonarEcho, SonarPing
from hil_bridge.bus.node import Node
from hil_bridge.files.scene import load_scene
from hil_bridge.server.sim_server import SimServer
from sim_core.pose import direction_from_az_el, quat_from_euler, quat_rotate
from sim_core.sonar import synthesize
from sim_core.sonar.mount import ears_for_ping, ping_beam

ECHO = {"samples": 8000}  # 20 ms at 400 kHz: leaves up to 3.4 m, keeps the test quick
FOREST = {"preset": "seed000-fig5d", "query_radius_m": 4.0}


def _circle(radius: float, z: float = 2.0, n: int = 180) -> list[list[float]]:
    a = np.linspace(0.0, 2 * np.pi, n, endpoint=False)
    return [[8.0 + radius * math.cos(t), 7.0 + radius * math.sin(t), z] for t in a]


def _run(scene: dict[str, Any], bus: str, pings: list[SonarPing], stop_s: float,
         **params: Any) -> tuple[SimServer, list[SonarEcho], dict[int, GliderState]]:
    srv = SimServer("server", bus=bus, scene=scene, stop_after_s=stop_s, **params)
    head = Node("head", bus=bus)
    sonar = scene["sonars"][0]["id"]
    ping_pub = head.create_publisher(SonarPing, f"/sonar/{sonar}/ping")
    echoes: queue.Queue[SonarEcho] = queue.Queue()
    states: dict[int, GliderState] = {}
    head.create_subscription(SonarEcho, f"/sonar/{sonar}/echo", echoes.put)
    mount = scene["sonars"][0]["mount"]
    head.create_subscription(GliderState, f"/glider/{mount}/state",
                             lambda m: states.__setitem__(m.stamp_ns, m))
    head.start()
    srv.start()
    try:
        assert srv.wait_done(timeout=60)
        for ping in pings:
            ping_pub.publish(ping)
        got = [echoes.get(timeout=30) for _ in pings]
    finally:
        srv.stop()
        head.stop()
    return srv, got, states


def test_a_banked_vehicles_echo_is_the_rotated_beams_with_its_ears() -> None:
    speed = 4.0
    radius = speed**2 / (9.81 * math.tan(math.radians(30.0)))  # a 30 degree coordinated turn
    ears = [{"position_m": [0.0, 0.015, 0.0], "axis": [1.0, 0.27, 0.0]},
            {"position_m": [0.0, -0.015, 0.0], "axis": [1.0, -0.27, 0.0]}]
    scene = {
        "forest": FOREST, "state_rate_hz": 50, "clock": {"mode": "fast"},
        "sonars": [{"id": 3, "mount": 100, "echo": ECHO, "ears": ears}],
        "vehicles": [{"id": 100, "path": {"kind": "points", "speed_mps": speed,
                                          "points": _circle(radius)}}],
    }
    az, el, bw = 0.5, 0.3, 0.8
    ping = SonarPing(stamp_ns=200_000_000, ping_seq=9, az=az, el=el, beamwidth=bw)
    _, (echo,), states = _run(scene, "mem://server_bank", [ping], 0.4)
    state = states[200_000_000]  # emitted on a tick: exactly that state's pose
    assert state.roll == pytest.approx(-math.radians(30.0), abs=math.radians(1.0))
    assert state.bank == pytest.approx(-state.roll)
    q = np.array([state.qw, state.qx, state.qy, state.qz])
    np.testing.assert_allclose(echo.orientation, q, atol=1e-15)
    np.testing.assert_allclose(echo.position, [state.x, state.y, state.z], atol=1e-12)
    np.testing.assert_allclose(echo.boresight, quat_rotate(q, direction_from_az_el(az, el)),
                               atol=1e-12)
    assert echo.emit_ns == 200_000_000
    # the echo is synthesize() on the rotated beam, with the ears rolled the same way
    local = load_scene(scene)
    beam = ping_beam(echo.position, q, az, el, bw)
    params = local.echo_params(3)
    ear_set = ears_for_ping(beam, q, [e["position_m"] for e in ears],
                            [e["axis"] for e in ears], [None, None])
    params = dataclasses.replace(params, ears=ear_set)
    leaves = local.leaves_near(echo.position, local.query_radius_m(3))
    direct = synthesize(leaves, beam, params, fidelity="fast")
    assert echo.samples.shape == (2, 8000) and echo.leaves_in_beam == direct.leaves_in_beam > 0
    np.testing.assert_array_equal(echo.samples, direct.samples.astype(np.float32))
    # the level beam of the same ping (the old attitude-blind echo) hears something else
    level = synthesize(leaves, ping_beam(echo.position, quat_from_euler(0, 0, state.yaw), az,
                                         el, bw), params, fidelity="fast")
    assert not np.allclose(level.samples, direct.samples)


def test_a_ninety_degree_yaw_mount_looks_sideways() -> None:
    scene = {
        "forest": FOREST, "state_rate_hz": 50, "clock": {"mode": "fast"},
        "sonars": [{"id": 0, "mount": 7, "echo": ECHO, "mount_offset_m": [0.2, 0.0, -0.1],
                    "mount_rpy_rad": [0.0, 0.0, math.pi / 2]}],
        # level flight: looped, the path would start in its U-turn back from the far end
        "vehicles": [{"id": 7, "path": {"kind": "points", "speed_mps": 2.0, "loop": False,
                                        "points": [[2.0, 5.0, 2.0], [18.0, 5.0, 2.0]]}}],
    }
    ping = SonarPing(stamp_ns=100_000_000, ping_seq=1, az=0.0, el=0.0, beamwidth=0.5)
    _, (echo,), states = _run(scene, "mem://server_mount", [ping], 0.2)
    np.testing.assert_allclose(echo.boresight, [0.0, 1.0, 0.0], atol=1e-12)  # north: left
    s = states[100_000_000]
    np.testing.assert_allclose(echo.position, [s.x + 0.2, s.y, s.z - 0.1], atol=1e-12)


def test_a_delayed_ping_is_answered_at_its_emission_pose() -> None:
    scene = {
        "forest": FOREST, "state_rate_hz": 50, "clock": {"mode": "fast"},
        "sonars": [{"id": 0, "mount": 7, "echo": ECHO}],
        "vehicles": [{"id": 7, "path": {"kind": "points", "speed_mps": 20.0, "loop": False,
                                        "points": [[2.0, 5.0, 2.0], [102.0, 5.0, 2.0]]}}],
    }
    pings = [
        SonarPing(stamp_ns=310_000_000, ping_seq=1, az=0.0, el=0.0, beamwidth=0.5),
        SonarPing(stamp_ns=0, ping_seq=2, az=0.0, el=0.0, beamwidth=0.5),  # no stamp: arrival
        SonarPing(stamp_ns=50_000_000, ping_seq=3, az=0.0, el=0.0, beamwidth=0.5),  # too old
        SonarPing(stamp_ns=5_000_000_000, ping_seq=4, az=0.0, el=0.0, beamwidth=0.5),  # ahead
    ]
    srv, echoes, _ = _run(scene, "mem://server_emit", pings, 1.0, pose_history_s=0.8)
    by_seq = {e.ping_seq: e for e in echoes}
    # emitted at 0.31 s, between two ticks, received after the run stopped at 1.0 s
    np.testing.assert_allclose(by_seq[1].position, [2.0 + 20.0 * 0.31, 5.0, 2.0], atol=1e-9)
    assert by_seq[1].emit_ns == 310_000_000
    np.testing.assert_allclose(by_seq[2].position, [22.0, 5.0, 2.0], atol=1e-9)
    assert by_seq[2].emit_ns == 1_000_000_000
    assert by_seq[3].emit_ns == 200_000_000  # the oldest pose kept (0.8 s of history)
    assert by_seq[4].emit_ns == 1_000_000_000
    st = srv.stats()
    assert (st["ping_stamp_old"], st["ping_stamp_future"]) == (1, 1)
