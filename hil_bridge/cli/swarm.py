"""``echoloop swarm run|sweep|plot``: seed 002 thermal-soaring swarms, grids, figures.

``--law`` takes a YAML law file or ``default`` (the packaged Law_40SurvivorsExample).
``--set KEY=VALUE`` overrides a law parameter (VALUE in YAML syntax); overrides beat the file.
``run --physics continuous`` flies the law with the simulation server's continuous flight model
(``sim_core.continuous_swarm``: the controller every ``dt``, the gliders integrated at
``--physics-rate`` Hz in between, ``--flight KEY=VALUE`` for ``sim_core.flight.FlightParams``);
the default ``discrete`` is the seed's own step.
"""

from __future__ import annotations

import argparse
import csv
import json
import math
import sys
import time
from pathlib import Path
from typing import Any

from hil_bridge.files.config import parse_override
from hil_bridge.outputs import atomic_output, check_output

__all__ = ["main"]

JSON_KEYS = (
    "surviving", "survivingPercent", "flightTime", "heightScore", "thermalUseScore",
    "explorationPercent", "collisionDeaths", "groundDeaths", "finalHeightMax",
    "finalHeightMin", "finalHeightAvg", "seconds",
)


def _parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="echoloop swarm", description=__doc__)
    sub = parser.add_subparsers(dest="action", required=True)

    def law_args(p: argparse.ArgumentParser) -> None:
        p.add_argument("--law", required=True, metavar="FILE.yaml",
                       help="law file, or 'default' for the packaged seed law")
        p.add_argument("--set", action="append", default=[], metavar="KEY=VALUE",
                       dest="overrides", help="override a law parameter (repeatable)")

    r = sub.add_parser("run", help="fly one run and print its metrics")
    law_args(r)
    r.add_argument("--seed", type=int, default=None,
                   help="random seed (default: the law's rngSeed)")
    r.add_argument("--trace", metavar="FILE.npz",
                   help="write the per-step trajectory (.npz, or .csv for replay)")
    r.add_argument("--plot", metavar="FILE.png",
                   help="write the paths coloured by time and by vertical speed")
    r.add_argument("--json", action="store_true", help="print the metrics as one JSON object")
    r.add_argument("--physics", choices=("discrete", "continuous"), default="discrete",
                   help="discrete: the seed's step (default); continuous: the server's flight "
                        "model between the controller's steps")
    r.add_argument("--physics-rate", type=float, default=50.0, metavar="HZ",
                   help="integration rate of --physics continuous (default 50 Hz)")
    r.add_argument("--flight", action="append", default=[], metavar="KEY=VALUE",
                   help="flight model parameter of --physics continuous, e.g. bank_tau_s=0.5")
    r.add_argument("--overwrite", action="store_true", help="replace existing --trace/--plot")

    s = sub.add_parser("sweep", help="run a parameter grid into a results table")
    law_args(s)
    s.add_argument("--grid", required=True, metavar="FILE.yaml",
                   help="grid file: law parameter -> list of values (e.g. megarun7_grid.yaml)")
    s.add_argument("--out", required=True, metavar="FILE",
                   help="results table: .csv, or .parquet; an existing table is resumed")
    s.add_argument("--workers", type=int, default=1, help="local worker processes (default 1)")
    s.add_argument("--scheduler", metavar="ADDRESS",
                   help="dask.distributed scheduler address, e.g. tcp://10.0.0.5:8786")
    s.add_argument("--batch-size", type=int, default=64,
                   help="runs stepped together in one vectorised batch (default 64)")
    s.add_argument("--no-progress", action="store_true", help="hide the progress bar")

    p = sub.add_parser("plot", help="figures from a trace (.npz) or a sweep table")
    p.add_argument("--out", required=True, metavar="FILE.png", help="the PNG to write")
    src = p.add_mutually_exclusive_group(required=True)
    src.add_argument("--trace", metavar="FILE.npz",
                     help="paths coloured by time and vertical speed (Figs 3-4), or with "
                          "--agents their height, vertical speed and cohesion (Figs 7, 9, 10)")
    src.add_argument("--table", metavar="FILE",
                     help="sweep results (.csv/.parquet): histograms split by --by (Figs 11-14)")
    p.add_argument("--agents", metavar="I,J,...", help="glider ids for the time series")
    p.add_argument("--from", dest="t0", type=float, default=None, help="series start time, s")
    p.add_argument("--to", dest="t1", type=float, default=None, help="series end time, s")
    p.add_argument("--by", metavar="PARAM", help="table column to split the histograms by")
    p.add_argument("--metric", default="survivingPercent",
                   help="table column to histogram (default survivingPercent)")
    p.add_argument("--overwrite", action="store_true", help="replace an existing --out")
    return parser


def _overrides(items: list[str]) -> dict[str, Any]:
    return dict(parse_override(item) for item in items)


def main(argv: list[str]) -> int:
    args = _parser().parse_args(argv)
    if args.action == "plot":
        return _plot(args)
    from hil_bridge.files.soaring import load_law

    law = load_law(args.law, _overrides(args.overrides))
    if args.action == "run":
        return _run(law, args)
    return _sweep(law, args)


def _run(law: Any, args: argparse.Namespace) -> int:
    from hil_bridge.files.soaring import save_trace
    from sim_core.soaring.swarm import run

    if args.trace and Path(args.trace).suffix.lower() not in (".npz", ".csv"):
        raise ValueError(f"--trace must name a .npz or .csv file, got {args.trace!r}")
    inputs = [] if args.law == "default" else [args.law]
    for out in (args.trace, args.plot):
        if out:  # refuse before flying anything
            check_output(out, overwrite=args.overwrite, inputs=inputs)
    want_trace = bool(args.trace or args.plot)
    if args.physics == "continuous":
        from sim_core.config import from_dict
        from sim_core.continuous_swarm import run_continuous
        from sim_core.flight import FlightParams

        flight = from_dict(FlightParams, _overrides(args.flight), path="--flight")
        t0 = time.perf_counter()
        result = run_continuous(
            law, seeds=None if args.seed is None else [args.seed], flight=flight,
            physics_rate_hz=args.physics_rate, trace=want_trace,
        )[0]
    else:
        if args.flight:
            raise ValueError("--flight: only with --physics continuous")
        t0 = time.perf_counter()
        result = run(law, seed=args.seed, trace=want_trace)
    seconds = time.perf_counter() - t0
    if result.trace is not None:
        if args.trace:
            with atomic_output(args.trace, overwrite=args.overwrite, inputs=inputs) as tmp:
                save_trace(result.trace, tmp)
        if args.plot:
            from hil_bridge.plots.soaring import plot_paths

            with atomic_output(args.plot, overwrite=args.overwrite, inputs=inputs) as tmp:
                plot_paths(result.trace, tmp)
    metrics = {**result.metrics.to_json(), "seconds": round(seconds, 4)}
    if args.json:
        print(json.dumps({k: metrics[k] for k in JSON_KEYS}))
    else:
        seed = law.rngSeed if args.seed is None else args.seed
        print(f"seed {seed}: {result.steps} steps of {law.dt} s ({args.physics} physics) in "
              f"{seconds:.2f} s")
        width = max(map(len, JSON_KEYS))
        for k in JSON_KEYS[:-1]:
            print(f"  {k:<{width}}  {metrics[k]}")
    return 0


def _sweep(law: Any, args: argparse.Namespace) -> int:
    from hil_bridge.files.soaring import load_grid
    from hil_bridge.tools.sweep import sweep
    from sim_core.soaring.sweep import expand_grid

    grid = load_grid(args.grid)
    try:  # every grid point is a valid law before the first run
        expand_grid(law, grid)
    except ValueError as exc:
        raise ValueError(f"{args.grid}: {exc}") from None
    summary = sweep(
        law, grid, Path(args.out), workers=args.workers, scheduler=args.scheduler,
        batch_size=args.batch_size, progress=not args.no_progress,
    )
    print(
        f"{summary.total} runs in the grid: {summary.ran} computed, {summary.skipped} already "
        f"in {summary.out}",
        file=sys.stdout,
    )
    return 0


def _plot(args: argparse.Namespace) -> int:
    from hil_bridge.plots import soaring as plots

    if args.table is not None and not args.by:
        raise ValueError("--table needs --by PARAM (the column to split the histograms by)")
    ids: list[int] | None = None
    if args.agents:
        try:
            ids = [int(a) for a in args.agents.split(",")]
        except ValueError:
            raise ValueError(f"--agents: expected ids like 3,7,19, got {args.agents!r}") from None
    source = args.table if args.table is not None else args.trace
    check_output(args.out, overwrite=args.overwrite, inputs=[source])
    if args.table is not None:
        table = _read_plot_table(args.table, [args.metric, args.by])
        with atomic_output(args.out, overwrite=args.overwrite, inputs=[source]) as tmp:
            plots.plot_survival_histograms(table, args.by, tmp, metric=args.metric)
    else:
        from hil_bridge.files.soaring import load_trace

        trace = load_trace(args.trace)
        with atomic_output(args.out, overwrite=args.overwrite, inputs=[source]) as tmp:
            if ids is not None:
                lo = -math.inf if args.t0 is None else args.t0
                hi = math.inf if args.t1 is None else args.t1
                plots.plot_agent_series(trace, ids, tmp, t_range=(lo, hi))
            else:
                plots.plot_paths(trace, tmp)
    print(f"wrote {args.out}")
    return 0


def _read_plot_table(path: str, columns: list[str]) -> list[dict[str, Any]]:
    """Rows of a sweep table with finite numbers in ``columns``; errors name the file."""
    from hil_bridge.files.config import read_text
    from hil_bridge.tools.sweep import read_table

    if not path.lower().endswith(".parquet"):
        text = read_text(path)  # not UTF-8 text: one clear line, not a decode error
        if text and not text.endswith("\n"):
            raise ValueError(f"{path}: the last line has no line end: the file was cut short?")
    try:
        rows = read_table(path)
    except (OSError, ValueError, csv.Error) as exc:
        raise ValueError(f"{path}: not a results table ({exc})") from None
    except Exception as exc:  # pyarrow raises its own error types for damaged files
        raise ValueError(f"{path}: not a results table ({type(exc).__name__}: {exc})") from None
    if not rows:
        raise ValueError(f"{path}: no rows to plot")
    for i, row in enumerate(rows, start=1):
        for col in columns:
            value = row.get(col)
            if col not in row:
                raise ValueError(f"{path}: no column {col!r}; columns are {sorted(row)}")
            if isinstance(value, float) and not math.isfinite(value):
                raise ValueError(f"{path}: row {i}: {col} is {value}")
            if value is None:
                raise ValueError(f"{path}: row {i}: {col} is empty")
    return rows
