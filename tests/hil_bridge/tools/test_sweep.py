"""Sweep execution (hil_bridge.tools.sweep): resumable tables, CSV/Parquet, local worker processes
and
a dask.distributed cluster giving the same table."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import pytest

from hil_bridge.files.soaring import run_key
from hil_bridge.tools.sweep import read_table, sweep
from sim_core.config import ConfigError
from sim_core.soaring import Law, run

BASE = Law().replace(totalTime=60.0, numAgents=6)
GRID: dict[str, list[Any]] = {"numThermals": [3, 6], "rngSeed": [1, 2],
                              "controller": ["unified", "baseline"]}


def _by_key(path: Path) -> dict[str, str]:
    """Rows by runKey, each as its repr (so that NaN equals NaN)."""
    return {str(r["runKey"]): repr(r) for r in read_table(path)}


def test_sweep_rows_match_single_runs_and_resume(tmp_path: Path) -> None:
    out = tmp_path / "res.csv"
    seen: list[int] = []
    s1 = sweep(BASE, {"numThermals": [3], "rngSeed": [1, 2]}, out, progress=False,
               on_rows=lambda rows: seen.append(len(rows)))
    assert (s1.total, s1.ran, s1.skipped) == (2, 2, 0) and sum(seen) == 2
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
    assert not (tmp_path / "res.parquet.partial.csv").exists()
    again = sweep(BASE, GRID, out, workers=2, progress=False)
    assert (again.ran, again.skipped) == (0, 8)
    sweep(BASE, GRID, tmp_path / "here.csv", progress=False, batch_size=4)
    assert _by_key(out) == _by_key(tmp_path / "here.csv")


def test_dask_cluster_gives_the_table_of_local_workers(tmp_path: Path) -> None:
    from distributed import LocalCluster

    with LocalCluster(n_workers=1, threads_per_worker=1, processes=True,
                      dashboard_address=None) as cluster:
        summary = sweep(BASE, GRID, tmp_path / "dask.csv", scheduler=cluster.scheduler_address,
                        progress=False, batch_size=3)
    assert summary.ran == 8
    sweep(BASE, GRID, tmp_path / "local.csv", workers=2, progress=False, batch_size=3)
    dask_lines = (tmp_path / "dask.csv").read_text().splitlines()
    local_lines = (tmp_path / "local.csv").read_text().splitlines()
    assert len(dask_lines) == 9 and dask_lines[0] == local_lines[0]
    assert sorted(dask_lines[1:]) == sorted(local_lines[1:])  # rows come in completion order
