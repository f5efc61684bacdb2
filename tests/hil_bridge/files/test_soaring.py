"""hil_bridge.files.soaring: law and grid files (and the packaged ones), traces, run keys."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
import pytest

from hil_bridge.files.soaring import (
    TRACE_CSV_COLUMNS,
    default_grid_path,
    default_law_path,
    load_grid,
    load_law,
    load_trace,
    run_key,
    save_trace,
    save_trace_npz,
)
from sim_core.config import ConfigError
from sim_core.soaring import Law, run
from sim_core.soaring.sweep import expand_grid

BASE = Law().replace(totalTime=60.0, numAgents=6)


def test_packaged_default_is_the_seed_law(data_dir: Path) -> None:
    assert load_law("default") == Law()
    assert load_law(data_dir / "seed002" / "law_40survivors.yaml") == Law()
    assert default_law_path().read_text() == (
        data_dir / "seed002" / "law_40survivors.yaml"
    ).read_text()


def test_overrides_take_precedence(tmp_path: Path) -> None:
    p = tmp_path / "law.yaml"
    p.write_text("numAgents: 20\ncohesion: 3000\n")
    law = load_law(p, {"cohesion": 1e4, "controller": "baseline"})
    assert law.numAgents == 20 and law.cohesion == 1e4 and law.controller == "baseline"
    assert law.separation == Law().separation


def test_bad_file_is_named(tmp_path: Path) -> None:
    p = tmp_path / "bad.yaml"
    p.write_text("dt: -1\n")
    with pytest.raises(ConfigError, match=r"bad\.yaml.*dt"):
        load_law(p)
    p.write_text("- 1\n- 2\n")
    with pytest.raises(ConfigError, match="mapping"):
        load_law(p)
    with pytest.raises(ConfigError, match="cannot read"):
        load_law(tmp_path / "missing.yaml")


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


def test_run_keys_are_stable_per_law() -> None:
    grid: dict[str, list[Any]] = {"numThermals": [3, 6], "controller": ["unified", "baseline"]}
    keys = [run_key(law) for _, law in expand_grid(BASE, grid)]
    assert len(set(keys)) == 4 and all(len(k) == 16 for k in keys)
    assert run_key(BASE.replace(numThermals=6, controller="baseline")) == keys[3]


def test_trace_round_trips_and_csv_rows(tmp_path: Path) -> None:
    trace = run(Law().replace(totalTime=5.0, numAgents=3), seed=1, trace=True).trace
    assert trace is not None
    save_trace_npz(trace, tmp_path / "t.npz")
    back = load_trace(tmp_path / "t.npz")
    for name in ("t", "x", "alive", "thermal_strength"):
        np.testing.assert_array_equal(getattr(back, name), getattr(trace, name))
    save_trace(trace, tmp_path / "t.csv")
    lines = (tmp_path / "t.csv").read_text().splitlines()
    assert lines[0].split(",") == list(TRACE_CSV_COLUMNS)
    rows = np.loadtxt(tmp_path / "t.csv", delimiter=",", skiprows=1)
    assert rows.shape == (trace.n_steps * 3, len(TRACE_CSV_COLUMNS))
    np.testing.assert_array_equal(rows[:, 2], trace.x.ravel())


def test_damaged_trace_is_named(tmp_path: Path) -> None:
    p = tmp_path / "bad.npz"
    np.savez(p, t=np.zeros(3))
    with pytest.raises(ValueError, match=r"bad\.npz: not a soaring trace"):
        load_trace(p)
