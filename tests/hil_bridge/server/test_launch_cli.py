"""`echoloop launch --record --plot --json` and `echoloop replay --json` end to end (mem:// bus)."""

from __future__ import annotations

import json
from pathlib import Path

import pytest
import yaml

from hil_bridge.bag import bag_info
from hil_bridge.cli import main as echoloop

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
