"""Sweeps: grid checks, resumable tables, CSV/Parquet, local processes and dask."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import pytest

from sim_core.config import ConfigError
from sim_core.soaring import Law, run
from sim_core.soaring.law import default_grid_path
from sim_core.soaring.sweep import expand_grid, load_grid, read_table, run_key, sweep

BASE = Law().replace(totalTime=60.0, numAgents=6)
GRID: dict[str, list[Any]] = {"numThermals": [3, 6], "rngSeed": [1, 2],
                              "controller": ["unified", "baseline"]}


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


def test_sweep_rows_match_single_runs_and_resume(tmp_path: Path) -> None:
    out = tmp_path / "res.csv"
    seen: list[int] = []
    s1 = sweep(BASE, {"numThermals": [3], "rngSeed": [1, 2]}, out, progress=False,
               on_rows=lambda rows: seen.append(len(rows)))
    assert (s1.total, s1.ran, s1.skipped) == (2, 2, 0)
    s2 = sweep(BASE, GRID, tmp_path / "other.csv", progress=False, batch_size=3)
    assert s2.ran == 8
    # the first table resumes: its 2 finished runs are not recomputed
    s3 = sweep(BASE, {"numThermals": [3, 6], "rngSeed": [1, 2]}, out, progress=False)
    assert (s3.ran, s3.skipped) == (2, 2)
    rows = read_table(out)
    assert len(rows) == 4 and len({r["runKey"] for r in rows}) == 4
    law = BASE.replace(numThermals=6, rngSeed=2)
    row = next(r for r in rows if r["runKey"] == run_key(law))
    m = run(law).metrics
    assert row["heightScore"] == m.heightScore and row["surviving"] == m.surviving
    with pytest.raises(ConfigError, match="columns"):
        sweep(BASE, GRID, out, progress=False)


def test_parquet_and_process_workers(tmp_path: Path) -> None:
    out = tmp_path / "res.parquet"
    summary = sweep(BASE, GRID, out, workers=2, progress=False, batch_size=4)
    assert summary.ran == 8
    rows = read_table(out)
    assert len(rows) == 8 and not (tmp_path / "res.parquet.partial.csv").exists()
    again = sweep(BASE, GRID, out, workers=2, progress=False)
    assert (again.ran, again.skipped) == (0, 8)


def test_dask_scheduler(tmp_path: Path) -> None:
    from distributed import LocalCluster

    with LocalCluster(n_workers=1, threads_per_worker=1, processes=False,
                      dashboard_address=None) as cluster:
        summary = sweep(BASE, GRID, tmp_path / "d.csv", scheduler=cluster.scheduler_address,
                        progress=False, batch_size=4)
    assert summary.ran == 8
    local = read_table(tmp_path / "d.csv")
    sweep(BASE, GRID, tmp_path / "l.csv", progress=False, batch_size=4)
    by_key = {r["runKey"]: r for r in read_table(tmp_path / "l.csv")}
    for r in local:
        assert r == by_key[r["runKey"]]
