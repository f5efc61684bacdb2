"""Sweep execution: a grid × a base law → a results table, one row per run (``echoloop swarm
sweep``).

The grid itself (file checks, the Cartesian product, each run's law and ``runKey``) is pure and
lives in :mod:`sim_core.soaring.sweep`; the runs are :func:`sim_core.soaring.run_batch`. This
module does what sim_core must not: files, processes and the dask client.

Execution: runs are grouped into batches of at most ``batch_size`` sharing a
:func:`~sim_core.soaring.swarm.batch_key`, each stepped by one ``run_batch`` call (the task);
tasks run in this process, on local worker processes (``workers``) or on a dask.distributed
scheduler (``scheduler``). Every path runs the same task on the same batches, so the table is the
same whichever executes it (rows in completion order). Rows are appended as each task ends, so
an interrupted sweep resumes where it stopped: runs whose ``runKey`` is already in the output are
not recomputed. Output: CSV, or Parquet for a ``.parquet`` path (rows collect in
``<out>.partial.csv`` until the sweep completes). Each row holds ``runKey``, the swept inputs,
``steps`` flown and the metrics of :class:`~sim_core.soaring.Metrics`.
"""

from __future__ import annotations

import csv
import json
import math
import multiprocessing
import sys
from collections.abc import Callable, Iterator, Mapping, Sequence
from concurrent.futures import Future, ProcessPoolExecutor, as_completed
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from hil_bridge.files.soaring import run_key
from sim_core.config import ConfigError
from sim_core.soaring.law import Law
from sim_core.soaring.swarm import METRIC_NAMES, batch_key, run_batch
from sim_core.soaring.sweep import check_grid, expand_grid

__all__ = ["SweepSummary", "read_table", "run_task", "sweep"]

#: One task: (runKey, swept inputs, full law as plain data) per run.
Task = list[tuple[str, dict[str, Any], dict[str, Any]]]


@dataclass(frozen=True, slots=True)
class SweepSummary:
    """What a sweep did: grid size, runs already present (skipped), runs computed, output."""

    total: int
    skipped: int
    ran: int
    out: Path


def run_task(items: Task) -> list[dict[str, Any]]:
    """The unit of work a worker runs: one batch of runs → their result rows."""
    laws = [Law.from_dict(d) for _, _, d in items]
    results = run_batch(laws)
    return [{"runKey": key, **inputs, "steps": res.steps, **res.metrics.to_dict()}
            for (key, inputs, _), res in zip(items, results, strict=True)]


def read_table(path: str | Path) -> list[dict[str, Any]]:
    """Rows of a results table (CSV or Parquet) as dicts; numbers parsed from CSV."""
    p = Path(path)
    if p.suffix.lower() == ".parquet":
        import pyarrow.parquet as pq

        return list(pq.read_table(p).to_pylist())
    with p.open(newline="", encoding="utf-8") as fh:
        return [{k: _parse(v) for k, v in row.items()} for row in csv.DictReader(fh)]


def _parse(text: str) -> Any:
    if text in ("", "None"):
        return None
    try:
        return json.loads(text)
    except ValueError:
        pass
    try:
        return float(text)
    except ValueError:
        return text


def _fmt(value: Any) -> str:
    if isinstance(value, float):
        return "nan" if math.isnan(value) else repr(value)
    if isinstance(value, bool | int | str):
        return json.dumps(value) if isinstance(value, bool) else str(value)
    return json.dumps(value)


class _CsvSink:
    """Append rows to a CSV with a fixed header; knows the runKeys already present."""

    def __init__(self, path: Path, columns: list[str]) -> None:
        self.path = path
        self.columns = columns
        self.done: set[str] = set()
        if path.exists() and path.stat().st_size > 0:
            with path.open(newline="", encoding="utf-8") as fh:
                reader = csv.DictReader(fh)
                if reader.fieldnames != columns:
                    raise ConfigError(
                        f"{path}: existing table has columns {reader.fieldnames}, this sweep "
                        f"writes {columns}; choose another --out"
                    )
                self.done = {row["runKey"] for row in reader}
        else:
            path.parent.mkdir(parents=True, exist_ok=True)
            with path.open("w", newline="", encoding="utf-8") as fh:
                csv.writer(fh).writerow(columns)

    def append(self, rows: list[dict[str, Any]]) -> None:
        with self.path.open("a", newline="", encoding="utf-8") as fh:
            w = csv.writer(fh)
            for row in rows:
                w.writerow([_fmt(row[c]) for c in self.columns])
                self.done.add(str(row["runKey"]))


def sweep(
    base: Law,
    grid: Mapping[str, Sequence[Any]],
    out: str | Path,
    *,
    workers: int = 1,
    scheduler: str | None = None,
    batch_size: int = 64,
    progress: bool = True,
    on_rows: Callable[[list[dict[str, Any]]], None] | None = None,
) -> SweepSummary:
    """Run every grid point not yet in ``out`` and append its row (see the module docstring).

    ``workers`` local processes (1 = in this process); ``scheduler`` a dask.distributed address
    (``tcp://host:8786``), which takes precedence. ``batch_size`` runs are stepped together.
    """
    if workers < 1:
        raise ValueError(f"workers must be >= 1, got {workers}")
    if batch_size < 1:
        raise ValueError(f"batch_size must be >= 1, got {batch_size}")
    grid = check_grid(dict(grid))
    points = expand_grid(base, grid)
    out_path = Path(out)
    parquet = out_path.suffix.lower() == ".parquet"
    columns = ["runKey", *grid, "steps", *METRIC_NAMES]
    sink_path = out_path.with_name(out_path.name + ".partial.csv") if parquet else out_path
    sink = _CsvSink(sink_path, columns)
    if parquet and out_path.exists():
        sink.done |= {str(r["runKey"]) for r in read_table(out_path)}
    todo: list[tuple[str, dict[str, Any], Law]] = []
    seen: set[str] = set()
    for inputs, law in points:
        key = run_key(law)
        if key in sink.done or key in seen:
            continue
        seen.add(key)
        todo.append((key, inputs, law))
    skipped = len(points) - len(todo)
    tasks = list(_tasks(todo, batch_size))
    from tqdm import tqdm

    bar = tqdm(total=len(points), initial=skipped, file=sys.stderr, disable=not progress,
               unit="run", desc="sweep")
    try:
        for rows in _execute(tasks, workers=workers, scheduler=scheduler):
            sink.append(rows)
            if on_rows is not None:
                on_rows(rows)
            bar.update(len(rows))
    finally:
        bar.close()
    if parquet:
        _finish_parquet(out_path, sink_path, columns)
    return SweepSummary(total=len(points), skipped=skipped, ran=len(todo), out=out_path)


def _tasks(todo: list[tuple[str, dict[str, Any], Law]], size: int) -> Iterator[Task]:
    """Batches of at most ``size`` runs sharing a batch key, as plain data for the workers."""
    groups: dict[tuple[Any, ...], list[tuple[str, dict[str, Any], Law]]] = {}
    for item in todo:
        groups.setdefault(batch_key(item[2]), []).append(item)
    for items in groups.values():
        for i in range(0, len(items), size):
            yield [(key, inputs, law.to_dict()) for key, inputs, law in items[i : i + size]]


def _execute(
    tasks: list[Task], *, workers: int, scheduler: str | None
) -> Iterator[list[dict[str, Any]]]:
    if not tasks:
        return
    if scheduler is not None:
        from distributed import Client
        from distributed import as_completed as dask_completed

        with Client(scheduler, timeout="10s") as client:
            futures = client.map(run_task, tasks, pure=False)
            for fut in dask_completed(futures):
                yield fut.result()
        return
    if workers == 1:
        for task in tasks:
            yield run_task(task)
        return
    ctx = multiprocessing.get_context("spawn")
    with ProcessPoolExecutor(max_workers=workers, mp_context=ctx) as pool:
        pending: list[Future[list[dict[str, Any]]]] = [pool.submit(run_task, t) for t in tasks]
        for fut in as_completed(pending):
            yield fut.result()


def _finish_parquet(out_path: Path, partial: Path, columns: list[str]) -> None:
    import pyarrow as pa
    import pyarrow.parquet as pq

    rows = read_table(out_path) if out_path.exists() else []
    rows += read_table(partial)
    table = pa.Table.from_pylist([{c: r.get(c) for c in columns} for r in rows])
    pq.write_table(table, out_path)
    partial.unlink()
