"""The binding `echoloop swarm` CLI contract (issue 4)."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from hil_bridge.cli import main
from hil_bridge.files.soaring import TRACE_CSV_COLUMNS, load_trace
from sim_core.soaring import Law, run

KEYS = ["surviving", "survivingPercent", "flightTime", "heightScore", "thermalUseScore",
        "explorationPercent", "collisionDeaths", "groundDeaths", "finalHeightMax",
        "finalHeightMin", "finalHeightAvg", "seconds"]


def test_run_json_keys_and_values(capsys: pytest.CaptureFixture[str], tmp_path: Path) -> None:
    npz = tmp_path / "t.npz"
    png = tmp_path / "p.png"
    rc = main(["swarm", "run", "--law", "default", "--set", "totalTime=60", "--set",
               "numAgents=5", "--seed", "3", "--json", "--trace", str(npz), "--plot", str(png)])
    assert rc == 0
    out = json.loads(capsys.readouterr().out)
    assert list(out) == KEYS
    m = run(Law().replace(totalTime=60.0, numAgents=5), seed=3).metrics
    assert out["heightScore"] == m.heightScore and out["surviving"] == m.surviving
    assert 0 <= out["survivingPercent"] <= 100 and out["seconds"] >= 0
    tr = load_trace(npz)
    assert tr.x.shape == (121, 5)
    assert png.stat().st_size > 10_000


def test_run_csv_trace_columns(capsys: pytest.CaptureFixture[str], tmp_path: Path) -> None:
    law = tmp_path / "law.yaml"
    law.write_text("totalTime: 5\nnumAgents: 3\n")
    csv = tmp_path / "t.csv"
    assert main(["swarm", "run", "--law", str(law), "--trace", str(csv)]) == 0
    assert "surviving" in capsys.readouterr().out
    lines = csv.read_text().splitlines()
    assert lines[0].split(",") == list(TRACE_CSV_COLUMNS)
    data = np.loadtxt(csv, delimiter=",", skiprows=1)
    assert data.shape == (11 * 3, 10)
    assert np.all(data[:3, 0] == 0.0) and data[-1, 0] == 5.0 and data[-1, 1] == 2


def test_all_dead_reports_null_average(capsys: pytest.CaptureFixture[str]) -> None:
    rc = main(["swarm", "run", "--law", "default", "--set", "totalTime=600", "--set",
               "agentSpawnAltiRange=[5, 10]", "--set", "numThermals=0", "--json"])
    assert rc == 0
    out = json.loads(capsys.readouterr().out)
    assert out["surviving"] == 0 and out["finalHeightAvg"] is None
    assert out["groundDeaths"] + out["collisionDeaths"] == 40


@pytest.mark.parametrize(
    ("extra", "match"),
    [(["--set", "cohesoin=1"], "cohesoin"), (["--set", "dt=-0.5"], "dt"),
     (["--set", "numAgents=many"], "numAgents")],
)
def test_bad_law_is_one_line_error(capsys: pytest.CaptureFixture[str], extra: list[str],
                                   match: str) -> None:
    assert main(["swarm", "run", "--law", "default", *extra]) == 1
    err = capsys.readouterr().err
    assert match in err and err.count("\n") == 1


def test_sweep_cli(capsys: pytest.CaptureFixture[str], tmp_path: Path) -> None:
    grid = tmp_path / "g.yaml"
    grid.write_text("rngSeed: [1, 2]\nnumThermals: [3]\n")
    out = tmp_path / "r.csv"
    args = ["swarm", "sweep", "--law", "default", "--grid", str(grid), "--out", str(out),
            "--set", "totalTime=30", "--set", "numAgents=4", "--no-progress"]
    assert main(args) == 0
    assert "2 computed" in capsys.readouterr().out
    assert main(args) == 0
    assert "0 computed, 2 already" in capsys.readouterr().out
    grid.write_text("rngSeed: []\n")
    assert main(args) == 1
    assert "empty" in capsys.readouterr().err


def test_plot_cli(capsys: pytest.CaptureFixture[str], tmp_path: Path) -> None:
    npz = tmp_path / "t.npz"
    assert main(["swarm", "run", "--law", "default", "--set", "totalTime=20", "--set",
                 "numAgents=3", "--trace", str(npz)]) == 0
    series = tmp_path / "s.png"
    assert main(["swarm", "plot", "--trace", str(npz), "--agents", "0,2", "--from", "5",
                 "--out", str(series)]) == 0
    assert series.read_bytes()[:4] == b"\x89PNG"
    table = tmp_path / "r.csv"
    grid = tmp_path / "g.yaml"
    grid.write_text("rngSeed: [1, 2]\nnumThermals: [3, 9]\n")
    assert main(["swarm", "sweep", "--law", "default", "--grid", str(grid), "--out", str(table),
                 "--set", "totalTime=20", "--set", "numAgents=3", "--no-progress"]) == 0
    hist = tmp_path / "h.png"
    assert main(["swarm", "plot", "--table", str(table), "--by", "numThermals", "--out",
                 str(hist)]) == 0
    assert hist.exists()
    capsys.readouterr()
    assert main(["swarm", "plot", "--table", str(table), "--out", str(hist)]) == 1
    assert "--by" in capsys.readouterr().err
    assert main(["swarm", "plot", "--trace", str(npz), "--agents", "0,x", "--out",
                 str(series)]) == 1
