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
