"""Trajectory replay: the served vehicle states follow the logged file, ending at its last row."""

from __future__ import annotations

import math
import threading
from pathlib import Path

import pytest

from hil_bridge.bus.messages import GliderState
from hil_bridge.bus.node import Node
from hil_bridge.launch.runner import run
from hil_bridge.replay.trajectory import build_replay_launch

ROOT = Path(__file__).resolve().parents[3]


def _trace(tmp_path: Path) -> Path:
    """Two vehicles; vehicle 7 flies east, then turns through +-pi heading, from t = 100 s."""
    rows = ["t,id,x,y,z,heading,bank,airspeed,vz,alive"]
    for k in range(11):
        t = 100.0 + k
        heading = 3.0 + 0.05 * k  # crosses pi between k = 2 and k = 3
        rows.append(f"{t},7,{10.0 * k},{-2.0 * k},{50 + k},{heading},0.1,10,1,1")
        rows.append(f"{t},8,0,0,100,0,0,10,0,1")
    path = tmp_path / "trace.csv"
    path.write_text("\n".join(rows) + "\n", encoding="utf-8")
    return path


def test_replay_of_a_csv_reaches_the_expected_poses(tmp_path: Path) -> None:
    bus = "mem://replay_csv"
    launch, length = build_replay_launch(
        _trace(tmp_path), vehicle_id=7, scene={}, sonar_rate_hz=None, bus=bus,
        clock_mode="fast", state_rate_hz=20.0,
    )
    assert length == pytest.approx(10.0)
    states: list[GliderState] = []
    lock = threading.Lock()
    obs = Node("observer", bus=bus)

    def on_state(msg: GliderState) -> None:
        with lock:
            states.append(msg)

    obs.create_subscription(GliderState, "/glider/7/state", on_state)
    obs.start()
    try:
        summary = run(launch, duration=1.5, handle_signals=False)
    finally:
        obs.stop()
    assert summary.nodes["server"]["sim_time_s"] == pytest.approx(10.0)
    assert states
    for msg in states:
        t = msg.stamp_ns / 1e9  # sim time 0 is the file's first row (t = 100 s)
        assert msg.x == pytest.approx(10.0 * t, abs=1e-9)
        assert msg.y == pytest.approx(-2.0 * t, abs=1e-9)
        assert msg.z == pytest.approx(50.0 + t, abs=1e-9)
        expected = (3.0 + 0.05 * t + math.pi) % (2 * math.pi) - math.pi
        assert msg.heading == pytest.approx(expected, abs=1e-9)
        assert msg.vz == pytest.approx(1.0)
    stamps = [m.stamp_ns for m in states]
    assert stamps == sorted(set(stamps))  # monotonic sim stamps, one state per tick
    last = states[-1]
    assert (last.stamp_ns, last.x, last.y) == (10_000_000_000, pytest.approx(100.0),
                                               pytest.approx(-20.0))


def test_replay_cli_rejects_a_multi_vehicle_file_without_id(tmp_path: Path) -> None:
    with pytest.raises(ValueError, match=r"holds vehicles \[7, 8\]; choose one"):
        build_replay_launch(_trace(tmp_path), scene={}, bus="mem://replay_bad")


def test_shipped_launch_files_load_and_their_scenes_validate(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    from hil_bridge.launch.runner import load
    from hil_bridge.server.sim_server import SimServer

    monkeypatch.chdir(ROOT)  # launch files name data paths relative to the project root
    files = sorted((ROOT / "launch").glob("*.yaml"))
    assert {f.name for f in files} >= {
        "demo.yaml", "sonar_forest.yaml", "swarm_soaring.yaml", "replay_forest.yaml",
        "hil_sonar.yaml", "hil_glider.yaml",
    }
    for f in files:
        spec = load(f)
        server = spec.node("server")
        SimServer("server", bus="mem://launch_files", **server.params)


def test_replay_through_the_forest_echoes_from_a_worker_process_and_serves_every_tick() -> None:
    """A logged flight through the forest at 2x, pinged at 10 Hz: echoes, forest tiles and
    /forest/points are computed in the echo worker process, every tick of the log is served,
    echoes reach the pinger. (The pace kept, ``rate_achieved``, is wall time: measured by
    ``python -m bench replay``, never asserted here.)"""
    log = ROOT / "launch" / "data" / "sonar_flight.csv"
    launch, length = build_replay_launch(log, rate=2.0, bus="mem://replay_rate")
    assert launch["nodes"][0]["params"]["echo_worker"] == "process"
    summary = run(launch, duration=length + 4.0, handle_signals=False, until_finished=True)
    assert summary.stopped_by == "finished"
    server = summary.nodes["server"]
    assert server["sim_time_s"] == pytest.approx(10.84)  # every tick of the log was served
    assert server["echo_workers"] == 1 and server["tick_wall_s"] > 0
    assert server["echoes_published"] >= 20 and server["echo_errors"] == 0
    assert server["last_echo_error"] == "" and server["tick_error"] == ""
    assert summary.nodes["pinger"]["echoes_received"] >= 20


def test_a_fast_replays_pinger_with_max_pings_holds_the_server_no_longer(tmp_path: Path) -> None:
    """The last of ``max_pings`` lockstep pings says no later one is due: the server flies on
    to the trajectory's end without waiting (no stall) and the run ends there."""
    log = tmp_path / "line.csv"
    log.write_text("t,x,y,z\n" + "".join(f"{t / 10},{t},0,5\n" for t in range(21)),
                   encoding="utf-8")
    launch, length = build_replay_launch(log, bus="mem://replay_max_pings", clock_mode="fast",
                                         state_rate_hz=20.0, pinger={"max_pings": 3})
    summary = run(launch, duration=60.0, handle_signals=False, until_finished=True)
    assert summary.stopped_by == "finished" and summary.failures == []
    server, pinger = summary.nodes["server"], summary.nodes["pinger"]
    assert pinger["pings_sent"] == pinger["echoes_received"] == 3
    assert server["stalls"] == 0 and server["sim_time_s"] == pytest.approx(length)
