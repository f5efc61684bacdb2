"""``echoloop launch FILE [--param NODE.KEY=VALUE ...] [--duration S] [--record F] [--json]``.

Runs the nodes of a launch file as threads of this process (see :mod:`hil_bridge.launch`) until
``--duration`` seconds have passed or Ctrl-C/SIGTERM arrives, then stops them in reverse order.
``--json`` prints the run summary (messages per topic, drops, stalls, latency percentiles, every
node's ``stats()``) as one JSON document on stdout; otherwise a short human summary is printed.
"""

from __future__ import annotations

import argparse
import json
import sys
from typing import Any

from hil_bridge.launch import LaunchSpec, RunSummary, parse_param_overrides, run


def _parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(
        prog="echoloop launch", description="Run a YAML launch file (a node graph) as threads."
    )
    p.add_argument("file", help="launch file, e.g. launch/demo.yaml")
    p.add_argument(
        "--param", action="append", default=[], metavar="NODE.KEY=VALUE",
        help="override a node parameter (VALUE in YAML syntax); repeatable",
    )
    p.add_argument("--duration", type=float, default=None, metavar="S",
                   help="stop after S seconds (default: the file's, else run until Ctrl-C)")
    p.add_argument("--record", default=None, metavar="FILE.mcap",
                   help="record every topic to an MCAP file")
    p.add_argument("--bus", default=None, metavar="URL",
                   help="bus URL replacing the file's (e.g. tcp://127.0.0.1:7410, mem://demo)")
    p.add_argument("--live", action="store_true", help="serve a Foxglove live view on 127.0.0.1")
    p.add_argument("--json", action="store_true", help="print the run summary as JSON")
    return p


def _jsonable(obj: Any) -> Any:
    if isinstance(obj, dict):
        return {str(k): _jsonable(v) for k, v in obj.items()}
    if isinstance(obj, list | tuple):
        return [_jsonable(v) for v in obj]
    if hasattr(obj, "item") and callable(obj.item):
        return obj.item()
    if isinstance(obj, float) and obj != obj:
        return None
    return obj


def format_summary(summary: RunSummary) -> str:
    """Human-readable lines of a run summary."""
    mon = summary.monitor
    lines = [
        f"ran {summary.wall_s:.1f} s (stopped by {summary.stopped_by})"
        + (f", recorded to {summary.record}" if summary.record else ""),
    ]
    topics = mon.get("topics", {})
    if topics:
        lines.append("messages per topic:")
        width = max(map(len, topics))
        for topic, row in sorted(topics.items()):
            lines.append(f"  {topic:<{width}}  {row['count']:>7d}  ({row['rate_hz']:.1f} Hz)")
    for key, label in (("ping_echo_ms", "ping -> echo"), ("state_latency_ms", "state pub -> recv")):
        pct = mon.get(key)
        if pct and pct.get("n"):
            lines.append(
                f"{label} latency: p50 {pct['p50']:.2f} ms, p99 {pct['p99']:.2f} ms, "
                f"max {pct['max']:.2f} ms (n={pct['n']})"
            )
    for name, stats in summary.nodes.items():
        shown = ", ".join(
            f"{k}={v}" for k, v in stats.items() if isinstance(v, int | float | str | bool)
        )
        lines.append(f"node {name}: {shown}")
    return "\n".join(lines)


def _announce(spec: LaunchSpec) -> None:
    names = ", ".join(n.name for n in spec.nodes)
    print(f"echoloop launch: running {names} on {spec.bus} (Ctrl-C to stop)", file=sys.stderr,
          flush=True)


def main(argv: list[str] | None = None) -> int:
    args = _parser().parse_args(sys.argv[1:] if argv is None else argv)
    summary = run(
        args.file,
        params_overrides=parse_param_overrides(args.param),
        duration=args.duration,
        record=args.record,
        live=True if args.live else None,
        bus=args.bus,
        on_started=_announce,
    )
    if args.json:
        print(json.dumps(_jsonable(summary.to_dict()), indent=2, sort_keys=True))
    else:
        print(format_summary(summary))
    return 0
