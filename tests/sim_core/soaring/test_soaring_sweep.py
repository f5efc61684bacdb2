"""Parameter grids: file checks, the Megarun 7 grid, errors naming the point (execution:
tests/hil_bridge/tools/test_sweep.py)."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import pytest

from sim_core.config import ConfigError
from sim_core.soaring import Law
from sim_core.soaring.law import default_grid_path
from sim_core.soaring.sweep import expand_grid, load_grid, run_key

BASE = Law().replace(totalTime=60.0, numAgents=6)


def test_megarun7_grid_has_18000_runs(data_dir: Path) -> None:
    grid = load_grid(default_grid_path())
    assert grid == load_grid(data_dir / "seed002" / "megarun7_grid.yaml")
    n = 1
    for values in grid.values():
        n *= len(values)
    assert n == 18000


@pytest.mark.parametrize(
    ("text", "match"),
    [("{}\n", "non-empty"), ("numAgents: []\n", "empty list"), ("cohesoin: [1]\n", "cohesoin"),
     ("numAgents: 3\n", "list"), ("agents: [[]]\n", "agents")],
)
def test_bad_grids_are_clear_errors(tmp_path: Path, text: str, match: str) -> None:
    p = tmp_path / "grid.yaml"
    p.write_text(text)
    with pytest.raises(ConfigError, match=match):
        load_grid(p)


def test_bad_grid_value_names_the_point() -> None:
    with pytest.raises(ConfigError, match="numAgents"):
        expand_grid(BASE, {"numAgents": [4, -1]})


def test_grid_points_and_keys() -> None:
    grid: dict[str, list[Any]] = {"numThermals": [3, 6], "controller": ["unified", "baseline"]}
    points = expand_grid(BASE, grid)
    assert [p[0] for p in points] == [
        {"numThermals": 3, "controller": "unified"}, {"numThermals": 3, "controller": "baseline"},
        {"numThermals": 6, "controller": "unified"}, {"numThermals": 6, "controller": "baseline"},
    ]
    keys = [run_key(law) for _, law in points]
    assert len(set(keys)) == 4 and all(len(k) == 16 for k in keys)
    assert run_key(BASE.replace(numThermals=6, controller="baseline")) == keys[3]
