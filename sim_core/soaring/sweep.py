"""Parameter sweeps: a grid file × a base law → a results table, one row per run.

Grid file (seed 002 "megarun" form, e.g. ``data/megarun7_grid.yaml``): a mapping of law
parameter names to non-empty lists of values; the runs are the Cartesian product, in file order
with the last key varying fastest. Each row holds ``runKey`` (a stable hash of the run's full
law), the swept inputs, ``steps`` flown and the metrics of :class:`~sim_core.soaring.Metrics`.

Execution: runs are grouped into batches (same :func:`~sim_core.soaring.swarm.batch_key`) and
stepped together by :func:`~sim_core.soaring.run_batch`; batches go to local worker processes
(``workers``) or to a dask.distributed scheduler (``scheduler``). Results are appended as each
batch finishes, so an interrupted sweep resumes where it stopped: runs whose ``runKey`` is
already in the output are not recomputed. Output: CSV, or Parquet for a ``.parquet`` path
(rows collect in ``<out>.partial.csv`` until the sweep completes).
"""

from __future__ import annotations

import csv
import hashlib
import itertools
import json
import math
import sys
from collections.abc import Callable, Iterator, Mapping, Sequence
from concurrent.futures import Future, ProcessPoolExecutor, as_completed
from dataclasses import dataclass, fields
from pathlib import Path
from typing import Any

from sim_core.config import ConfigError, load_yaml
from sim_core.soaring.law import Law
from sim_core.soaring.swarm import METRIC_NAMES, batch_key, run_batch

__all__ = [
    "SweepSummary",
    "expand_grid",
    "load_grid",
    "read_table",
    "run_key",
    "sweep",
]

_LAW_FIELDS = {f.name for f in fields(Law)}
_STRUCTURED = {"thermals", "agents"}


def load_grid(path: str | Path) -> dict[str, list[Any]]:
    """Read and check a grid file: a non-empty mapping of law keys to non-empty lists."""
    data = load_yaml(path)
    return check_grid(data, where=str(path))


def check_grid(data: Any, *, where: str = "grid") -> dict[str, list[Any]]:
    """Validate a grid mapping (see :func:`load_grid`)."""
    if not isinstance(data, Mapping) or not data:
        raise ConfigError(f"{where}: expected a non-empty mapping of law parameters to lists")
    grid: dict[str, list[Any]] = {}
    for key, values in data.items():
        if key not in _LAW_FIELDS or key in _STRUCTURED:
            raise ConfigError(
                f"{where}: unknown grid key {key!r}; expected law parameters such as "
                "numAgents, numThermals, rngSeed, cohesion, separation, alignment, migration"
            )
        if not isinstance(values, list):
            raise ConfigError(f"{where}: {key}: expected a list of values, got {values!r}")
        if not values:
            raise ConfigError(f"{where}: {key}: empty list, the grid would have no runs")
        grid[str(key)] = list(values)
    return grid


def expand_grid(base: Law, grid: Mapping[str, Sequence[Any]]) -> list[tuple[dict[str, Any], Law]]:
    """(swept inputs, law) for every point of the grid, validated (errors name the key)."""
    keys = list(grid)
    base_dict = base.to_dict()
    out: list[tuple[dict[str, Any], Law]] = []
    for combo in itertools.product(*(grid[k] for k in keys)):
        inputs = dict(zip(keys, combo, strict=True))
        try:
            law = Law.from_dict({**base_dict, **inputs})
        except ConfigError as exc:
            raise ConfigError(f"grid point {inputs}: {exc}") from None
        out.append((inputs, law))
    return out


def run_key(law: Law) -> str:
    """Stable 16-hex-digit hash of a run's full law (its seed is ``rngSeed``)."""
    text = json.dumps(law.to_dict(), sort_keys=True, separators=(",", ":"))
    return hashlib.sha256(text.encode("utf-8")).hexdigest()[:16]


@dataclass(frozen=True, slots=True)
class SweepSummary:
    """What a sweep did: grid size, runs already present (skipped), runs computed, output."""

    total: int
    skipped: int
    ran: int
    out: Path


def _run_chunk(items: list[tuple[str, dict[str, Any], dict[str, Any]]]) -> list[dict[str, Any]]:
    """Worker task: (runKey, inputs, law dict) items → result rows."""
    laws = [Law.from_dict(d) for _, _, d in items]
    results = run_batch(laws)
    rows = []
    for (key, inputs, _), res in zip(items, results, strict=True):
        rows.append({"runKey": key, **inputs, "steps": res.steps, **res.metrics.to_dict()})
    return rows


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
    chunks = list(_chunks(todo, batch_size))
    from tqdm import tqdm

    bar = tqdm(total=len(points), initial=skipped, file=sys.stderr, disable=not progress,
               unit="run", desc="sweep")
    try:
        for rows in _execute(chunks, workers=workers, scheduler=scheduler):
            sink.append(rows)
            if on_rows is not None:
                on_rows(rows)
            bar.update(len(rows))
    finally:
        bar.close()
    if parquet:
        _finish_parquet(out_path, sink_path, columns)
    return SweepSummary(total=len(points), skipped=skipped, ran=len(todo), out=out_path)


def _chunks(
    todo: list[tuple[str, dict[str, Any], Law]], size: int
) -> Iterator[list[tuple[str, dict[str, Any], dict[str, Any]]]]:
    """Batches of at most ``size`` runs sharing a batch key, as plain data for the workers."""
    groups: dict[tuple[Any, ...], list[tuple[str, dict[str, Any], Law]]] = {}
    for item in todo:
        groups.setdefault(batch_key(item[2]), []).append(item)
    for items in groups.values():
        for i in range(0, len(items), size):
            yield [(key, inputs, law.to_dict()) for key, inputs, law in items[i : i + size]]


def _execute(
    chunks: list[list[tuple[str, dict[str, Any], dict[str, Any]]]],
    *,
    workers: int,
    scheduler: str | None,
) -> Iterator[list[dict[str, Any]]]:
    if not chunks:
        return
    if scheduler is not None:
        from distributed import Client
        from distributed import as_completed as dask_completed

        with Client(scheduler, timeout="10s") as client:
            futures = client.map(_run_chunk, chunks, pure=False)
            for fut in dask_completed(futures):
                yield fut.result()
        return
    if workers == 1:
        for chunk in chunks:
            yield _run_chunk(chunk)
        return
    import multiprocessing

    ctx = multiprocessing.get_context("spawn")
    with ProcessPoolExecutor(max_workers=workers, mp_context=ctx) as pool:
        pending: list[Future[list[dict[str, Any]]]] = [
            pool.submit(_run_chunk, c) for c in chunks
        ]
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
