"""The sonar's pose at a ping's emission: between two ticks it is the pose at the stamp, a ping
stamped after the newest tick waits for the tick that covers it (or is extrapolated when that
tick does not come), and every ping is counted once."""

from __future__ import annotations

import dataclasses
import math
import queue
import threading
import time
from typing import Any

import numpy as np
import pytest

from hil_bridge.bus.faults import Faults
from hil_bridge.bus.messages import Clock, SonarEcho, SonarPing
from hil_bridge.bus.node import Node
from hil_bridge.files.scene import load_scene
from hil_bridge.server.emission import EMISSION_COUNTERS, EmissionPoses
from hil_bridge.server.fleet import Fleet
from hil_bridge.server.pose_history import VehiclePose
from hil_bridge.server.sim_server import SimServer
from sim_core.config import ConfigError
from sim_core.flight import path_state
from sim_core.pose import quat_conjugate, quat_multiply, quat_rotate
from sim_core.scene import Scene

TICK_NS = 20_000_000  # 50 Hz
SPEED = 6.0
RADIUS = 5.0
#: the stated errors (docs/server.md, "Pose at emission") on the 5 m circle at 6 m/s, 50 Hz
INTERP_M, EXTRAP_M, ANGLE_DEG = 0.2e-3, 3e-3, 0.01


def _circle(n: int = 720) -> list[list[float]]:
    a = np.linspace(0.0, 2 * np.pi, n, endpoint=False)
    return [[8.0 + RADIUS * math.cos(t), 7.0 + RADIUS * math.sin(t), 2.0] for t in a]


VEHICLES = [
    {"id": 1, "path": {"kind": "points", "speed_mps": 5.0, "loop": False,
                       "points": [[0.0, 5.0, 2.0], [100.0, 5.0, 2.0]]}},
    {"id": 2, "path": {"kind": "points", "speed_mps": SPEED, "loop": False,
                       "points": _circle()}},
]


def _angle_deg(qa: Any, qb: Any) -> float:
    d = quat_multiply(quat_conjugate(qa), qb)
    return math.degrees(2.0 * math.atan2(float(np.linalg.norm(d[1:])), abs(float(d[0]))))


def _fleet(ticks: int) -> tuple[Scene, Fleet]:
    scene = load_scene({"vehicles": VEHICLES, "state_rate_hz": 50})
    fleet = Fleet(scene, tick_ns=TICK_NS, history_ids=[1, 2])
    fleet.states()
    for _ in range(ticks):
        fleet.advance({})
        fleet.states()
    return scene, fleet


def _error(scene: Scene, vid: int, pose: VehiclePose, t_ns: int) -> tuple[float, float]:
    """Position (m) and attitude (deg) error of ``pose`` against vehicle ``vid``'s path at
    ``t_ns`` (the path is the truth the server samples at every tick)."""
    truth = path_state(scene.trajectories[vid], t_ns / 1e9)
    return (float(np.linalg.norm(pose.position - truth.position)),
            _angle_deg(pose.orientation, truth.outputs.quat))


class _Sink:
    def __init__(self) -> None:
        self.got: queue.Queue[tuple[Any, VehiclePose]] = queue.Queue()

    def __call__(self, payload: Any, pose: VehiclePose, received: float) -> None:
        self.got.put((payload, pose))


def test_a_ping_between_two_ticks_gets_the_pose_at_its_stamp() -> None:
    scene, fleet = _fleet(20)
    sink = _Sink()
    poses = EmissionPoses(fleet.history, horizon_ns=2 * TICK_NS, wait_s=60.0, on_pose=sink)
    for k, frac in enumerate((0.1, 0.5, 0.93)):
        for vid in (1, 2):
            stamp = (10 + k) * TICK_NS + round(frac * TICK_NS)
            poses.request(vid, stamp, (vid, stamp), time.monotonic())
            (_, pose) = sink.got.get_nowait()  # the history covers it: answered at once
            assert (pose.t_ns, pose.source) == (stamp, "history")
            dp, da = _error(scene, vid, pose, stamp)
            if vid == 1:  # a straight line at constant speed: exact
                assert dp < 1e-9 and da < 1e-6
                np.testing.assert_allclose(pose.velocity, [5.0, 0.0, 0.0], atol=1e-6)
            else:
                assert dp < INTERP_M and da < ANGLE_DEG
                assert np.linalg.norm(pose.velocity) == pytest.approx(SPEED, rel=1e-3)
    assert poses.stats()["ping_stamp_waited"] == 0


def test_a_ping_stamped_after_the_newest_tick_gets_the_pose_at_its_stamp_once_covered() -> None:
    scene, fleet = _fleet(20)
    newest = fleet.history.recorded_ns
    sink = _Sink()
    poses = EmissionPoses(fleet.history, horizon_ns=2 * TICK_NS, wait_s=600.0, on_pose=sink)
    poses.start(Faults("server"))
    try:
        stamp = newest + round(0.6 * TICK_NS)
        poses.request(2, stamp, "ping", time.monotonic())
        assert poses.stats()["pings_waiting_tick"] == 1 and sink.got.empty()
        fleet.advance({})
        fleet.states()  # the tick after the stamp: the waiting ping is answered
        payload, pose = sink.got.get(timeout=30)
    finally:
        poses.close()
    assert payload == "ping" and (pose.t_ns, pose.source) == (stamp, "history")
    dp, da = _error(scene, 2, pose, stamp)
    assert dp < INTERP_M and da < ANGLE_DEG
    older = fleet.history.pose_at(2, newest)
    assert np.linalg.norm(pose.position - older.position) > 0.5 * SPEED * 0.6 * TICK_NS / 1e9
    st = poses.stats()
    assert (st["ping_stamp_waited"], st["pings_waiting_tick"], len(st["ping_wait_ms"])) == (1, 0, 1)


def test_a_held_ping_whose_tick_does_not_come_is_extrapolated_and_every_ping_is_counted() -> None:
    scene, fleet = _fleet(20)
    newest = fleet.history.recorded_ns
    sink = _Sink()
    poses = EmissionPoses(fleet.history, horizon_ns=2 * TICK_NS, wait_s=600.0, on_pose=sink)
    poses.start(Faults("server"))
    try:
        stamps = [newest + round(f * TICK_NS) for f in (0.3, 1.0, 1.9)]
        for s in stamps:
            poses.request(2, s, s, time.monotonic())
        assert poses.stats()["pings_waiting_tick"] == 3
        poses.ticks_ended()  # no tick will come: extrapolated from the newest
        got = dict(sink.got.get(timeout=30) for _ in stamps)
        # after the ticks: at once; too far ahead or before the history: the nearest state
        poses.request(2, newest + TICK_NS // 2, "late", time.monotonic())
        poses.request(2, newest + 3 * TICK_NS, "future", time.monotonic())
        poses.request(2, -10 * TICK_NS, "old", time.monotonic())
        got.update(sink.got.get_nowait() for _ in range(3))
    finally:
        poses.close()
    for s in stamps:
        pose = got[s]
        assert (pose.t_ns, pose.source) == (s, "extrapolated")
        dp, da = _error(scene, 2, pose, s)
        assert dp < EXTRAP_M and da < ANGLE_DEG
    assert (got["late"].source, got["late"].t_ns) == ("extrapolated", newest + TICK_NS // 2)
    assert (got["future"].source, got["future"].t_ns) == ("newest", newest)
    assert (got["old"].source, got["old"].t_ns) == ("oldest", 0)
    st = poses.stats()
    assert {k: st[k] for k in EMISSION_COUNTERS} == {
        "ping_stamp_old": 1, "ping_stamp_future": 1, "ping_stamp_waited": 0,
        "ping_stamp_extrapolated": 4, "ping_pose_errors": 0}
    assert st["pings_waiting_tick"] == 0


def test_a_held_ping_whose_pose_fails_is_counted_and_handed_back_the_others_answered() -> None:
    """One held ping's failure strands neither the others nor itself: ``on_error`` hears of it
    (the server then stops waiting for its echo), the next pings get their poses."""
    _, fleet = _fleet(20)
    newest = fleet.history.recorded_ns
    sink, failed = _Sink(), queue.Queue[tuple[Any, str]]()

    def on_pose(payload: Any, pose: VehiclePose, received: float) -> None:
        if payload == "bad":
            raise RuntimeError("no such sonar")
        sink(payload, pose, received)

    poses = EmissionPoses(fleet.history, horizon_ns=2 * TICK_NS, wait_s=600.0, on_pose=on_pose,
                          on_error=lambda payload, why: failed.put((payload, why)))
    poses.start(Faults("server"))
    try:
        for payload in ("bad", "good"):
            poses.request(2, newest + TICK_NS // 2, payload, time.monotonic())
        fleet.advance({})
        fleet.states()
        assert failed.get(timeout=30) == ("bad", "no pose at emission: RuntimeError('no such "
                                                 "sonar')")
        assert sink.got.get(timeout=30)[0] == "good"
    finally:
        poses.close()
    assert poses.stats()["ping_pose_errors"] == 1


def test_without_waiting_a_ping_after_the_newest_tick_is_extrapolated_at_once() -> None:
    scene, fleet = _fleet(20)
    sink = _Sink()
    poses = EmissionPoses(fleet.history, horizon_ns=2 * TICK_NS, wait_s=0.0, on_pose=sink)
    poses.start(Faults("server"))
    stamp = fleet.history.recorded_ns + TICK_NS // 2
    poses.request(2, stamp, "p", time.monotonic())
    (_, pose) = sink.got.get_nowait()
    poses.close()
    assert (pose.source, pose.t_ns, pose.ahead_ns) == ("extrapolated", stamp, TICK_NS // 2)
    dp, da = _error(scene, 2, pose, stamp)
    assert dp < EXTRAP_M and da < ANGLE_DEG
    st = poses.stats()
    assert (st["ping_stamp_extrapolated"], st["ping_extrapolated_ms"]) == (1, [10.0])


def _accounted(st: dict[str, Any]) -> int:
    """Pings the server is done with."""
    return int(st["echoes_published"] + st["pings_dropped"] + st["pings_dropped_deadline"]
               + st["echo_errors"] + st["ping_pose_errors"] + st["pings_ignored"])


class _WallClockHead:
    """A sonar head that stamps each ping with the server's sim time when it fires, ahead of
    the newest ``/clock`` it heard by ``ahead`` of a tick (a head pinging between ticks)."""

    def __init__(self, bus: str, sonar: int) -> None:
        self.node = Node("head", bus=bus)
        self._pub = self.node.create_publisher(SonarPing, f"/sonar/{sonar}/ping")
        self.echoes: queue.Queue[SonarEcho] = queue.Queue()
        self.node.create_subscription(SonarEcho, f"/sonar/{sonar}/echo", self.echoes.put)
        self._clock = threading.Condition()
        self.clock_ns = -1
        self.node.create_subscription(Clock, "/clock", self._on_clock)

    def _on_clock(self, msg: Clock) -> None:
        with self._clock:
            self.clock_ns = max(self.clock_ns, int(msg.stamp_ns))
            self._clock.notify_all()

    def ping(self, seq: int, ahead: float) -> int:
        with self._clock:
            # from the tenth tick on (a path's first state has half its speed: t < 0 clamps)
            if not self._clock.wait_for(lambda: self.clock_ns >= 10 * TICK_NS, timeout=30):
                raise TimeoutError("no /clock")
            stamp = self.clock_ns + round(ahead * TICK_NS)
        self._pub.publish(SonarPing(stamp_ns=stamp, ping_seq=seq, az=0.0, el=0.0,
                                    beamwidth=0.6))
        return stamp


def test_a_realtime_server_answers_pings_between_ticks_at_their_stamp_and_counts_them_all(
) -> None:
    scene = {"forest": {"preset": "seed000-fig5d", "query_radius_m": 3.0},
             "state_rate_hz": 50, "clock": {"mode": "realtime"},
             "sonars": [{"id": 0, "mount": 2, "echo": {"samples": 8000}}],
             "vehicles": VEHICLES}
    bus = "mem://emission_realtime"
    srv = SimServer("server", bus=bus, scene=scene, stop_after_s=120.0)
    head = _WallClockHead(bus, 0)
    head.node.start()
    srv.start()
    sent: dict[int, int] = {}
    try:
        for seq in range(16):
            sent[seq] = head.ping(seq, ahead=(0.2, 0.55, 0.9, 1.4)[seq % 4])
            time.sleep(0.07)
        deadline = time.monotonic() + 60.0
        while time.monotonic() < deadline and _accounted(srv.stats()) < len(sent):
            time.sleep(0.05)
        st = srv.stats()
    finally:
        srv.stop()
        head.node.stop()
    # every ping accounted for: answered, dropped, failed, ignored or still waiting (none now)
    assert st["pings_received"] == len(sent) == _accounted(st) + st["pings_waiting_tick"]
    echoes = [head.echoes.get(timeout=10) for _ in range(st["echoes_published"])]
    assert len(echoes) >= len(sent) // 2
    local = load_scene(scene)
    for echo in echoes:
        stamp = sent[echo.ping_seq]
        assert echo.emit_ns == stamp  # the pose at the stamp, never the older tick's
        truth = path_state(local.trajectories[2], stamp / 1e9)
        assert np.linalg.norm(echo.position - truth.position) < EXTRAP_M
        assert _angle_deg(echo.orientation, truth.outputs.quat) < ANGLE_DEG
        boresight = quat_rotate(truth.outputs.quat, [1.0, 0.0, 0.0])
        np.testing.assert_allclose(echo.boresight, boresight, atol=1e-3)
    ahead = st["ping_stamp_waited"] + st["ping_stamp_extrapolated"]
    assert 0 < ahead <= len(sent) and st["ping_stamp_future"] == st["ping_stamp_old"] == 0
    assert st["ping_wait_ms"]["n"] == ahead


def test_doppler_needs_the_reference_fidelity() -> None:
    sonar = {"id": 0, "mount": 1, "echo": {"doppler": True}}
    base = {"forest": {"preset": "seed000-fig5d"}, "vehicles": VEHICLES[:1]}
    with pytest.raises(ConfigError, match=r"sonars\[0\]\.echo\.doppler: needs fidelity"):
        load_scene({**base, "sonars": [sonar]})
    load_scene({**base, "sonars": [{**sonar, "fidelity": "reference"}]})


def test_a_doppler_echo_is_given_the_sonars_velocity_at_emission() -> None:
    offset = [0.0, 1.0, 0.0]  # 1 m towards the inside of the left turn: slower than the vehicle
    scene = {"forest": {"preset": "seed000-fig5d", "query_radius_m": 3.0},
             "state_rate_hz": 50, "clock": {"mode": "fast"},
             "sonars": [{"id": 0, "mount": 2, "fidelity": "reference", "mount_offset_m": offset,
                         "echo": {"samples": 8000, "doppler": True}}],
             "vehicles": VEHICLES}
    bus = "mem://emission_doppler"
    srv = SimServer("server", bus=bus, scene=scene, stop_after_s=3.0)
    head = Node("head", bus=bus)
    pub = head.create_publisher(SonarPing, "/sonar/0/ping")
    echoes: queue.Queue[SonarEcho] = queue.Queue()
    head.create_subscription(SonarEcho, "/sonar/0/echo", echoes.put)
    head.start()
    srv.start()
    stamp = 2_500_000_000 + 7_000_000  # between two ticks, leaves ahead
    try:
        assert srv.wait_done(timeout=60)
        pub.publish(SonarPing(stamp_ns=stamp, ping_seq=1, az=0.0, el=-0.1, beamwidth=1.0))
        echo = echoes.get(timeout=60)
    finally:
        srv.stop()
        head.stop()
    local = load_scene(scene)
    # the sonar's velocity at emission: the vehicle's (interpolated as the server does) plus
    # the turn's lever arm
    pose = _fleet(round(3.0e9 / TICK_NS))[1].history.pose_at(2, stamp)
    velocity = pose.velocity + quat_rotate(pose.orientation, np.cross(pose.rates, offset))
    truth = path_state(local.trajectories[2], stamp / 1e9)
    np.testing.assert_allclose(velocity, truth.velocity + quat_rotate(
        truth.outputs.quat, np.cross(truth.outputs.rates, offset)), atol=0.03)  # the chords'
    # a rigid body turning at V / R: the point 1 m inwards (level part cos(bank)) is slower
    bank = math.atan(SPEED**2 / (9.81 * RADIUS))
    assert np.linalg.norm(velocity) == pytest.approx(SPEED - SPEED / RADIUS * math.cos(bank),
                                                     rel=2e-3)
    from sim_core.sonar import synthesize
    from sim_core.sonar.mount import ping_beam

    beam = ping_beam(echo.position, echo.orientation, 0.0, -0.1, 1.0)
    leaves = local.leaves_near(echo.position, local.query_radius_m(0))
    params = local.echo_params(0)
    moving = synthesize(leaves, beam, dataclasses.replace(
        params, platform_velocity=tuple(velocity)), fidelity="reference").samples
    still = synthesize(leaves, beam, params, fidelity="reference").samples
    peak = float(np.abs(moving).max())
    assert echo.leaves_in_beam > 0 and peak > 0
    np.testing.assert_allclose(echo.samples, moving, rtol=0, atol=1e-5 * peak)
    assert np.abs(still - moving).max() > 0.05 * peak
