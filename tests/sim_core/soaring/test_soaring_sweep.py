"""Parameter grids: the product, errors naming the point (grid files and run keys:
tests/hil_bridge/files; execution: tests/hil_bridge/tools/test_sweep.py)."""

from __future__ import annotations

from typing import Any

import pytest

from sim_core.config import ConfigError
from sim_core.soaring import Law
from sim_core.soaring.sweep import expand_grid

BASE = Law().replace(totalTime=60.0, numAgents=6)


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
    assert points[3][1] == BASE.replace(numThermals=6, controller="baseline")
