"""SimServer echoes: answered at the ping's pose and beam; the state stream keeps ticking."""

from __future__ import annotations

import queue
import threading
from typing import Any

import numpy as np
import pytest

from hil_bridge.bus.messages import GliderState, SonarEcho, SonarPing
from hil_bridge.bus.node import Node
from hil_bridge.files.scene import load_scene
from hil_bridge.server.sim_server import SimServer
from sim_core.sonar import Beam, synthesize

ECHO = {"samples": 8000}  # 20 ms at 400 kHz: leaves up to 3.4 m, keeps the test quick


def _scene(mode: str) -> dict[str, Any]:
    return {
        "forest": {"preset": "seed000-fig5d", "query_radius_m": 4.0},
        "sonars": [{"id": 3, "mount": 100, "echo": ECHO}],
        # level flight (the beam below has no roll): looped, the path would start in its
        # U-turn back from the far end
        "vehicles": [{"id": 100, "path": {"kind": "points", "loop": False,
                                          "points": [[2.0, 5.0, 2.0], [18.0, 5.0, 2.0]]}}],
        "state_rate_hz": 20,
        "clock": {"mode": mode},
    }


@pytest.mark.parametrize("worker", ["process", "thread"])
def test_echo_is_computed_at_the_pose_and_beam_of_the_ping(worker: str) -> None:
    bus = f"mem://server_echo_{worker}"
    srv = SimServer("server", bus=bus, scene=_scene("fast"), stop_after_s=0.05,
                    echo_worker=worker)
    head = Node("head", bus=bus)
    ping_pub = head.create_publisher(SonarPing, "/sonar/3/ping")
    echoes: queue.Queue[SonarEcho] = queue.Queue()
    head.create_subscription(SonarEcho, "/sonar/3/echo", echoes.put)
    head.start()
    srv.start()
    try:
        assert srv.wait_done(timeout=30)  # the vehicle now rests at its t = 0.05 s pose
        ping_pub.publish(SonarPing(stamp_ns=0, ping_seq=7, az=0.3, el=0.1, beamwidth=0.6))
        echo = echoes.get(timeout=20)
    finally:
        srv.stop()
        head.stop()
    pose = srv.scene.trajectories[100].sample(0.05)
    position = np.array([pose["x"], pose["y"], pose["z"]], dtype=float)
    assert position[0] == pytest.approx(2.25)
    beam = Beam.from_az_el(position, float(pose["heading"]) + 0.3, 0.1, 0.6)
    scene = load_scene(_scene("fast"))
    leaves = scene.leaves_near(position, scene.query_radius_m(3))
    direct = synthesize(leaves, beam, scene.echo_params(3), fidelity="fast")
    assert echo.ping_seq == 7 and echo.sonar_id == 3
    assert echo.leaves_in_beam == direct.leaves_in_beam > 0
    assert echo.fs == direct.fs
    np.testing.assert_array_equal(echo.samples, direct.samples.astype(np.float32))
    # the forest is built where echoes are computed: in the worker process, or right here
    built = ["forest_tiles", "trajectories"] if worker == "thread" else ["trajectories"]
    assert srv.stats()["built"] == built


def test_state_stream_keeps_ticking_while_an_echo_computes() -> None:
    bus = "mem://server_rate"
    # a 'reference' echo takes hundreds of ms: many ticks fit in it however loaded the machine
    # (a 'fast' one takes ~10 ms, a handful of ticks)
    scene = _scene("fast")
    scene["sonars"] = [{**scene["sonars"][0], "fidelity": "reference"}]
    srv = SimServer("server", bus=bus, scene=scene, stop_after_s=600.0)
    head = Node("head", bus=bus)
    ping_pub = head.create_publisher(SonarPing, "/sonar/3/ping")
    echoes: queue.Queue[SonarEcho] = queue.Queue()
    first_state: queue.Queue[GliderState] = queue.Queue()
    sent = threading.Event()

    def on_state(msg: GliderState) -> None:
        if not sent.is_set():
            sent.set()
            first_state.put(msg)
            ping_pub.publish(SonarPing(stamp_ns=msg.stamp_ns, ping_seq=1, az=0.0, el=0.0,
                                       beamwidth=0.8))

    head.create_subscription(GliderState, "/glider/100/state", on_state)
    head.create_subscription(SonarEcho, "/sonar/3/echo", echoes.put)
    head.start()
    srv.start()
    try:
        echo = echoes.get(timeout=20)
        state = first_state.get(timeout=1)
    finally:
        srv.stop()
        head.stop()
    st = srv.stats()
    ticks_during_echo = (echo.stamp_ns - state.stamp_ns) / srv.tick_ns
    # The tick loop never waited for the echo: many ticks passed while it was computed, and
    # every tick published every vehicle's state.
    assert ticks_during_echo >= 10
    assert st["states_published"] == st["ticks"]
    assert st["echoes_published"] == 1


def test_scene_pins_thermals_and_gliders_through_law_overrides() -> None:
    scene = load_scene({"swarm": {"first_id": 10, "overrides": {
        "agents": [{"x": 0.0, "y": 0.0, "z": 500.0, "heading": 0.5, "speed": 10.0},
                   {"x": 100.0, "y": 0.0, "z": 500.0}],
        "thermals": [{"x": 50.0, "y": 0.0, "radius": 300.0, "strength": 5.0}]}}})
    assert scene.glider_ids == (10, 11)
    np.testing.assert_array_equal(scene.swarm.state.x, [[0.0, 100.0]])
    np.testing.assert_array_equal(scene.swarm.thermals.x, [[50.0]])


def test_scene_errors_name_the_key() -> None:
    from sim_core.config import ConfigError

    with pytest.raises(ConfigError, match=r"unknown key\(s\) \['colour'\]"):
        load_scene({"colour": 1})
    with pytest.raises(ConfigError, match="a sonar needs a 'forest'"):
        load_scene({"sonars": [{"id": 0, "mount": 1}]})
    with pytest.raises(ConfigError, match=r"sonars\[0\]\.mount: no vehicle or glider with id 5"):
        load_scene({"forest": {"preset": "seed000-fig5d"}, "sonars": [{"id": 0, "mount": 5}]})
    with pytest.raises(ConfigError, match=r"collide with swarm glider ids"):
        load_scene({"swarm": {"overrides": {"numAgents": 2}}, "vehicles": [
            {"id": 1, "path": {"kind": "points", "points": [[0, 0, 1], [1, 0, 1]]}}]})
    with pytest.raises(ConfigError, match="fidelity"):
        load_scene({"forest": {"preset": "seed000-fig5d"}, "sonars": [
            {"id": 0, "mount": 1, "fidelity": "nope"}], "vehicles": [
            {"id": 1, "path": {"kind": "points", "points": [[0, 0, 1], [1, 0, 1]]}}]})
    with pytest.raises(ConfigError, match="state_rate_hz"):
        load_scene({"state_rate_hz": 0})


def test_scene_builds_only_what_it_needs() -> None:
    no_sonar = load_scene({
        "forest": {"preset": "seed000-fig5d"},
        "vehicles": [{"id": 1, "path": {"kind": "points", "points": [[0, 0, 1], [1, 0, 1]]}}],
    })
    assert no_sonar.forest_source is None
    assert no_sonar.swarm is None
    assert no_sonar.built == set()
    with_sonar = load_scene(_scene("fast"))
    assert with_sonar.built == set()  # validated, nothing heavy built yet
    with_sonar.leaves_near(np.array([5.0, 5.0, 2.0]))
    assert with_sonar.built == {"forest_tiles"}
    srv = SimServer("server", bus="mem://server_lazy", scene={
        "swarm": {"overrides": {"numAgents": 2}}, "clock": {"mode": "fast"}}, stop_after_s=1.0)
    srv.start()
    try:
        assert srv.wait_done(timeout=30)
    finally:
        srv.stop()
    st = srv.stats()
    assert st["built"] == ["swarm"]
    assert st["neighbors_published"] == 0  # no autopilot asked
