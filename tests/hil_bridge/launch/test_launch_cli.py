"""`echoloop launch --record --plot --json` and `echoloop replay --json` end to end (mem:// bus)."""

from __future__ import annotations

import json
from pathlib import Path

import pytest
import yaml

from hil_bridge.cli import main as echoloop
from hil_bridge.recording.bag import bag_info

SCENE = {"swarm": {"overrides": {"numAgents": 3, "dt": 0.1}}, "state_rate_hz": 20,
         "clock": {"mode": "realtime", "rate": 5.0}}


def test_launch_records_plots_and_prints_json(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    launch = tmp_path / "swarm.yaml"
    launch.write_text(yaml.safe_dump({"bus": "mem://cli_record", "nodes": [
        {"name": "server", "entry": "hil_bridge.server:SimServer", "params": {"scene": SCENE}},
    ]}), encoding="utf-8")
    mcap, png = tmp_path / "run.mcap", tmp_path / "run.png"
    code = echoloop(["launch", str(launch), "--duration", "1.0", "--record", str(mcap),
                     "--plot", str(png), "--json"])
    assert code == 0
    summary = json.loads(capsys.readouterr().out)
    assert summary["stopped_by"] == "duration"
    assert summary["record"] == str(mcap)
    info = bag_info(mcap)
    assert not info.truncated
    assert info.topics["/glider/0/state"].count > 0
    assert "/thermals" in info.topics
    assert png.stat().st_size > 10_000


def test_plot_needs_a_recording(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    assert echoloop(["launch", str(tmp_path / "x.yaml"), "--plot", "x.png"]) == 1
    assert "--plot needs --record" in capsys.readouterr().err


def test_replay_cli_runs_a_trajectory_file(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    csv = tmp_path / "flight.csv"
    csv.write_text("t,x,y,z,heading,bank,airspeed\n0,0,0,100,0,0,10\n4,40,0,100,0,0,10\n",
                   encoding="utf-8")
    scene = tmp_path / "empty.yaml"
    scene.write_text("{}\n", encoding="utf-8")
    code = echoloop(["replay", str(csv), "--scene", str(scene), "--fast", "--bus",
                     "mem://cli_replay", "--duration", "1.0", "--json"])
    assert code == 0
    summary = json.loads(capsys.readouterr().out)
    server = summary["nodes"]["server"]
    assert server["sim_time_s"] == pytest.approx(4.0)
    assert summary["monitor"]["topics"]["/glider/0/state"]["count"] > 0


def test_plot_draws_the_beam_cone_of_the_shown_echo(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    import math

    import numpy as np

    from hil_bridge.plots.recording import beam_outline, plot_recording

    scene = {
        "forest": {"preset": "seed000-fig5d", "query_radius_m": 4.0},
        "sonars": [{"id": 0, "mount": 5, "echo": {"samples": 8000}}],
        "vehicles": [{"id": 5, "path": {"kind": "figure_eight", "speed_mps": 3.0, "params": {
            "center": [8.0, 7.0], "half_length": 7.0, "half_width": 5.0, "altitude": 2.0,
            "count": 200}}}],
        "state_rate_hz": 20, "clock": {"mode": "realtime", "rate": 2.0},
    }
    launch = tmp_path / "sonar.yaml"
    launch.write_text(yaml.safe_dump({"bus": "mem://cli_beam", "nodes": [
        {"name": "server", "entry": "hil_bridge.server:SimServer", "params": {"scene": scene}},
        {"name": "pinger", "entry": "hil_bridge.replay:Pinger",
         "params": {"sonar_id": 0, "rate_hz": 10, "el": 0.2, "beamwidth": 0.8}},
    ]}), encoding="utf-8")
    mcap = tmp_path / "run.mcap"
    assert echoloop(["launch", str(launch), "--duration", "1.5", "--record", str(mcap),
                     "--json"]) == 0
    capsys.readouterr()
    drawn = plot_recording(mcap, tmp_path / "run.png")
    assert drawn["echo"] == 1 and drawn["beams"] == 1
    cone = beam_outline([1.0, 2.0, 3.0], [0.0, 0.0, 2.0], 0.6, 3.0)
    np.testing.assert_array_equal(cone[0], [1.0, 2.0, 3.0])
    rim = cone[1:] - cone[0]
    angles = np.arccos(rim[:, 2] / np.linalg.norm(rim, axis=1))
    np.testing.assert_allclose(angles, math.atan(math.tan(0.3)), atol=1e-12)
