"""Replay of a flight log the real tools wrote (an ArduPilot QuadPlane's tlog, README in
``tests/data/flightlogs``): the server flies the vehicle along it, from its first fix to where
it landed. (The server's last tick is the last one within the log: 208.0 s of its 208.412 s at
2 Hz.)"""

from __future__ import annotations

import threading
from pathlib import Path

import numpy as np
import pytest

from hil_bridge.bus.messages import GliderState
from hil_bridge.bus.node import Node
from hil_bridge.launch.runner import run
from hil_bridge.recording.logs import read_log
from hil_bridge.replay.trajectory import build_replay_launch

TLOG = Path(__file__).resolve().parents[2] / "data" / "flightlogs" / "ardupilot_quadplane_sitl.tlog"


def test_replay_of_an_ardupilot_tlog_flies_the_logged_track_to_its_end() -> None:
    bus = "mem://replay_real_tlog"
    traj, _ = read_log(TLOG)
    launch, length = build_replay_launch(
        TLOG, scene={}, sonar_rate_hz=None, bus=bus, clock_mode="fast", state_rate_hz=2.0,
    )
    assert length == pytest.approx(208.412)
    last_tick_ns = 208_000_000_000
    states: list[GliderState] = []
    lock = threading.Lock()
    at_end = threading.Event()
    obs = Node("observer", bus=bus)

    def on_state(msg: GliderState) -> None:
        with lock:
            states.append(msg)
        if msg.stamp_ns >= last_tick_ns:
            at_end.set()

    obs.create_subscription(GliderState, "/glider/0/state", on_state)
    obs.start()
    try:  # the run ends once the last pose is served (the duration is only a bound)
        summary = run(launch, duration=120.0, stop_event=at_end, handle_signals=False)
    finally:
        obs.stop()
    assert at_end.is_set(), f"the replay never reached the log's end: {summary.nodes}"
    assert summary.nodes["server"]["sim_time_s"] == pytest.approx(last_tick_ns / 1e9)
    with lock:
        got = list(states)
    assert len(got) > 200  # 2 Hz over 208 s, minus what passed before the observer joined
    t = np.array([m.stamp_ns for m in got]) / 1e9 + traj.t[0]  # sim 0 = the first fix
    xyz = np.array([[m.x, m.y, m.z] for m in got])
    expected = np.stack([np.interp(t, traj.t, traj.xyz[:, k]) for k in range(3)], axis=1)
    np.testing.assert_allclose(xyz, expected, atol=1e-6)
    assert xyz[:, 2].max() > 50.0  # up is up: it flew its circuits 56.6 m above take-off
    assert got[-1].stamp_ns == last_tick_ns
    np.testing.assert_allclose(xyz[-1], [8.25, 225.03, -1.21], atol=0.05)  # where it landed


REAL = sorted(p for p in TLOG.parent.iterdir() if p.suffix in (".ulg", ".bin", ".tlog"))
PING_HZ = 10.0
#: sim seconds replayed of each log (the DataFlash excerpts are shorter: all of them)
UNTIL_S = 1.5


@pytest.mark.parametrize("log", REAL, ids=[p.stem for p in REAL])
def test_every_real_log_replays_fast_through_the_forest_with_echoes_and_exports(
    log: Path, tmp_path: Path,
) -> None:
    """A fast replay: the pinger is the lockstep server's sonar head, pinging on the sim grid
    (k / 10 Hz from sim 0, each stamp its due time), every ping answered at its pose; the run
    ends when the trajectory does (``until_finished``); the recording exports to a ROS 2 bag
    whose states are the log's poses."""
    from rosbags.highlevel import AnyReader

    from hil_bridge.bus.codec import decode_payload
    from hil_bridge.bus.messages import SonarEcho, SonarPing
    from hil_bridge.cli import main as echoloop
    from hil_bridge.recording.bag import read_bag

    traj, _ = read_log(log)
    launch, length = build_replay_launch(
        log, sonar_rate_hz=PING_HZ, bus=f"mem://replay_{log.stem}", clock_mode="fast",
        state_rate_hz=20.0, until_s=UNTIL_S,
    )
    assert length == pytest.approx(min(UNTIL_S, traj.duration))
    assert launch["nodes"][0]["params"]["scene"]["clock"]["mode"] == "lockstep"
    rec = tmp_path / "replay.mcap"
    summary = run(launch, duration=120.0, record=rec, handle_signals=False,
                  until_finished=True)
    assert summary.failures == [] and summary.stopped_by == "finished", summary.nodes
    server, pinger = summary.nodes["server"], summary.nodes["pinger"]
    pings = int(length * PING_HZ + 1e-9) + 1  # 0, 0.1, ... up to the trajectory's end
    assert pinger["pings_sent"] == pinger["echoes_received"] == pings
    assert server["echoes_published"] == pings and server["stalls"] == 0
    assert server["sim_time_s"] == pytest.approx(int(length * 20 + 1e-9) / 20)
    by_topic: dict[str, list] = {}
    for m in read_bag(rec, ["/sonar/0/ping", "/sonar/0/echo"]):
        by_topic.setdefault(m.topic, []).append(decode_payload(m.header.type, m.header.v,
                                                               m.payload))
    sent: list[SonarPing] = by_topic["/sonar/0/ping"]
    echoes: list[SonarEcho] = by_topic["/sonar/0/echo"]
    assert [p.stamp_ns for p in sent] == [k * 100_000_000 for k in range(pings)]
    assert sorted(e.emit_ns for e in echoes) == [p.stamp_ns for p in sent]
    assert all(e.samples.size > 0 for e in echoes)
    out = tmp_path / "replay_ros2.mcap"
    assert echoloop(["bag", "export", str(rec), "--ros2", str(out)]) == 0
    with AnyReader([out]) as reader:
        conns = [c for c in reader.connections if c.topic == "/glider/0/state"]
        odo = [reader.deserialize(raw, c.msgtype) for c, _, raw in reader.messages(conns)]
    ns = np.array([o.header.stamp.sec * 10**9 + o.header.stamp.nanosec for o in odo])
    # every tick from sim 0 (a lockstep server waiting for its head re-sends the last one)
    ticks = int(length * 20 + 1e-9) + 1
    np.testing.assert_array_equal(np.unique(ns), np.arange(ticks) * 50_000_000)
    t = ns * 1e-9
    xyz = np.array([[o.pose.pose.position.x, o.pose.pose.position.y,
                     o.pose.pose.position.z] for o in odo])
    expected = np.stack([np.interp(t + traj.t[0], traj.t, traj.xyz[:, k]) for k in range(3)],
                        axis=1)
    np.testing.assert_allclose(xyz, expected, atol=1e-6)
