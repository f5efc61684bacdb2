"""``echoloop launch FILE [--param NODE.KEY=VALUE ...] [--duration S] [--expect CHECK ...]``.

Runs the nodes of a launch file, each in a process of its own (nodes that share a
``container:`` share one; ``--threads``, or a ``mem://`` bus, runs them as threads of this
process instead: see :mod:`hil_bridge.launch.runner`), until ``--duration`` seconds have passed
or Ctrl-C/SIGTERM arrives, then stops them in reverse order. ``--only``/``--skip`` leave nodes
out (to run one elsewhere, e.g. with ``echoloop run``). ``--no-realtime`` runs every node at
normal scheduling, whatever the file's ``realtime`` keys (docs/launch.md, *Real time*).
``--speed FACTOR|max`` paces the run (:func:`hil_bridge.launch.spec.with_speed`);
``--isolate`` keeps a lockstep server and its firmware nodes apart
(:func:`~hil_bridge.launch.spec.compose_lockstep`).
``--json`` prints the run summary (messages per topic, drops, stalls, latency percentiles, every
node's ``stats()``, link states, failures) as one JSON document on stdout; otherwise a short
human summary is printed. What failed (a node, an ``--expect`` that did not hold, a hardware
link that never connected, the ``--plot`` drawn after the run) is printed on stderr, one line
each, and sets the exit status (:attr:`hil_bridge.launch.runner.RunSummary.exit_status`, judged
in one place: a failed plot never hides or replaces the run's own status).
"""

from __future__ import annotations

import argparse
import json
import sys
from typing import Any, Literal

from hil_bridge.bus.domain import Domain
from hil_bridge.cli._args import add_domain_argument, domain_for_run, seconds
from hil_bridge.launch.runner import LaunchSpec, RunSummary, parse_param_overrides, run
from hil_bridge.launch.spec import parse_speed
from hil_bridge.lifetime import freeze_heap
from hil_bridge.outputs import atomic_output, check_output
from hil_bridge.plots.recording import plot_recording


def _parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(
        prog="echoloop launch",
        description="Run a YAML launch file (a node graph), each node in its own process.",
    )
    p.add_argument("file", help="launch file, e.g. launch/demo.yaml")
    p.add_argument(
        "--param", action="append", default=[], metavar="NODE.KEY=VALUE",
        help="override a node parameter (VALUE in YAML syntax); repeatable",
    )
    p.add_argument("--duration", type=seconds, default=None, metavar="S",
                   help="stop after S seconds (default: the file's, else run until Ctrl-C)")
    p.add_argument(
        "--expect", action="append", default=[], metavar="'NODE.COUNTER OP VALUE'",
        help="a check of the run summary, e.g. 'server.stalls == 0' (OP: > >= < <= == !=); "
             "the run exits 4 unless every one holds; repeatable",
    )
    p.add_argument("--allow-disconnected", action="store_true",
                   help="exit 0 even if a hardware link (serial port, CAN bus) never connected "
                        "(otherwise exit 3)")
    p.add_argument("--record", default=None, metavar="FILE.mcap",
                   help="record every topic to an MCAP file")
    p.add_argument("--allow-module", action="append", default=[], metavar="MODULE",
                   help="also allow launch entries from MODULE (and below it); repeatable. "
                        "A launch file runs the code its entries name")
    p.add_argument("--overwrite", action="store_true",
                   help="replace existing output files (--record, --plot, node captures/logs)")
    p.add_argument("--bus", default=None, metavar="URL",
                   help="bus URL replacing the file's and the domain's (e.g. mem://demo)")
    add_domain_argument(p, auto=True)
    p.add_argument("--threads", action="store_true",
                   help="run every node as a thread of this process (as a mem:// bus must)")
    p.add_argument("--speed", default=None, metavar="FACTOR|max",
                   help="sim seconds per wall second: a realtime clock at that rate, a lockstep "
                        "or fast one at most that fast; max: as fast as the loop goes "
                        "(default: the file's clock)")
    p.add_argument("--isolate", action="store_true",
                   help="keep a lockstep server and its firmware nodes in processes of their "
                        "own (by default they share one: docs/launch.md, Composition)")
    p.add_argument("--no-realtime", action="store_true",
                   help="run every node at normal scheduling, whatever the file's realtime keys")
    p.add_argument("--only", action="append", default=[], metavar="NODE",
                   help="run only this node of the file; repeatable")
    p.add_argument("--skip", action="append", default=[], metavar="NODE",
                   help="leave this node of the file out; repeatable")
    p.add_argument("--log-dir", default=None, metavar="DIR",
                   help="also write each node process's log lines to DIR/<node>.log")
    p.add_argument("--live", action="store_true", help="serve a Foxglove live view on 127.0.0.1")
    p.add_argument("--json", action="store_true", help="print the run summary as JSON")
    p.add_argument("--verbose", "-v", action="store_true",
                   help="human summary with messages per topic and every node's counters")
    p.add_argument("--plot", default=None, metavar="FILE.png",
                   help="after the run, plot the recording (needs --record): glider tracks, "
                        "sonar vehicle path over the forest, the last echo")
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


def _find(summary: RunSummary, key: str) -> list[dict[str, Any]]:
    return [stats for stats in summary.nodes.values() if key in stats]


def headline(summary: RunSummary) -> list[str]:
    """The closed-loop figures, from whichever nodes report them (server, mocks, adapters)."""
    lines: list[str] = []
    for head in _find(summary, "echoes_complete"):
        late = head.get("echoes_late", 0)
        lines.append(  # the four outcomes of a ping add up to the pings sent
            f"sonar: {head['pings_sent']} pings = {head['echoes_complete']} echoes complete "
            f"+ {head.get('echoes_incomplete', 0)} incomplete + {head.get('echo_timeouts', 0)} "
            f"timed out{f' ({late} arrived late)' if late else ''} + "
            f"{head.get('pings_in_flight', 0)} in flight; "
            f"{head.get('crc_errors', 0)} CRC errors; ping -> last chunk "
            f"p50 {head.get('latency_p50_ms', float('nan')):.1f} ms, "
            f"p99 {head.get('latency_p99_ms', float('nan')):.1f} ms"
        )
    for pinger in _find(summary, "echoes_received"):
        pct = pinger.get("ping_echo_ms", {})
        lines.append(
            f"pinger: {pinger['pings_sent']} pings, {pinger['echoes_received']} echoes back; "
            f"ping -> echo p50 {pct.get('p50', float('nan')):.1f} ms, "
            f"p99 {pct.get('p99', float('nan')):.1f} ms"
        )
    for ap in _find(summary, "cmd_forwarded"):
        lines.append(
            f"CAN: {ap.get('can_tx_frames', 0)} frames sent, "
            f"{ap.get('can_rx_frames', 0)} received by the adapter; "
            f"{ap['cmd_forwarded']} autopilot commands forwarded"
            + (f"; bus failed to open {ap['can_open_failures']} times"
               if ap.get("can_open_failures") else "")
        )
    for srv in _find(summary, "cmd_applied"):
        alive = srv.get("gliders_alive")
        lines.append(
            f"server: {srv['ticks']} ticks ({srv['sim_time_s']:.1f} s sim), "
            f"{srv['cmd_applied']} commands applied ({srv['cmd_rejected']} rejected), "
            f"{srv['echoes_published']} echoes"
            + (f" ({srv['echo_worker']} echo worker)" if srv.get("echo_worker") else "")
            + f", {srv['stalls']} lockstep stalls, {srv.get('late_ticks', 0)} late ticks"
            + (f" (tick thread at {srv['tick_priority']})"
               if srv.get("tick_priority", "unchanged") != "unchanged" else "")
            + (f", gliders alive {alive}" if alive is not None else "")
        )
    return lines


def format_summary(summary: RunSummary, *, verbose: bool = False) -> str:
    """Human-readable lines of a run summary (``verbose``: every node's counters too)."""
    mon = summary.monitor
    lines = [
        f"ran {summary.wall_s:.1f} s (stopped by {summary.stopped_by})"
        + (f", recorded to {summary.record}" if summary.record else ""),
        *headline(summary),
    ]
    topics = mon.get("topics", {})
    if topics and verbose:
        lines.append("messages per topic:")
        width = max(map(len, topics))
        for topic, row in sorted(topics.items()):
            lines.append(f"  {topic:<{width}}  {row['count']:>7d}  ({row['rate_hz']:.1f} Hz)")
    if mon:
        dropped = sum(int(st.get("dropped", 0)) for st in summary.nodes.values()
                      if isinstance(st.get("dropped", 0), int))
        lines.append(
            f"bus: {mon.get('messages', 0)} messages seen, {mon.get('seq_gaps', 0)} lost "
            f"(sequence gaps), {mon.get('bad', 0)} undecodable; nodes dropped {dropped}"
            + (f"; the monitor was throttled {mon['throttled_s']:.1f} s (its own counts are "
               "partial)" if mon.get("throttled_s") else "")
        )
    lines.extend(format_link(key, link) for key, link in summary.links.items())
    for key, label in (("ping_echo_ms", "ping -> echo"), ("state_latency_ms", "state pub -> recv")):
        pct = mon.get(key)
        if pct and pct.get("n"):
            lines.append(
                f"{label} latency: p50 {pct['p50']:.2f} ms, p99 {pct['p99']:.2f} ms, "
                f"max {pct['max']:.2f} ms (n={pct['n']})"
            )
    for name, stats in summary.nodes.items() if verbose else ():
        shown = ", ".join(
            f"{k}={v}" for k, v in stats.items() if isinstance(v, int | float | str | bool)
        )
        lines.append(f"node {name}: {shown}")
    lines += [f"FAILED {f.source}: {f.message}" for f in summary.failures]
    return "\n".join(lines)


def format_link(key: str, link: dict[str, Any]) -> str:
    """One line of a link report (:func:`hil_bridge.launch.runner.collect_links`)."""
    head = f"link {key}: {link.get('kind', '?')} {link.get('target', '?')}"
    if not link.get("connected"):
        return f"{head}: NEVER CONNECTED ({link.get('error') or 'no error reported'})"
    extra = f", {link['reconnects']} reconnects" if link.get("reconnects") else ""
    return f"{head}: {link.get('state', '?')} at the end of the run{extra}"


def announcer(domain: Domain, prog: str = "echoloop launch") -> Any:
    """``on_started`` callback of a command's run: prints what runs where (stderr), then
    freezes this process's heap (:func:`hil_bridge.lifetime.freeze_heap`; its bus monitor, and
    with ``--threads`` its nodes, are running: no collection first)."""

    def announce(spec: LaunchSpec) -> None:
        names = ", ".join(n.name for n in spec.nodes)
        print(f"{prog}: running {names} in {domain} on {spec.bus} (Ctrl-C to stop)",
              file=sys.stderr, flush=True)
        freeze_heap()

    return announce


def report_failures(summary: RunSummary, prog: str = "echoloop launch") -> int:
    """Print each failure on stderr (one line each) and return the run's exit status."""
    for failure in summary.failures:
        print(f"{prog}: {failure.message}", file=sys.stderr)
    return summary.exit_status


def main(argv: list[str] | None = None) -> int:
    args = _parser().parse_args(sys.argv[1:] if argv is None else argv)
    speed: float | Literal["file"] | None = (
        "file" if args.speed is None else parse_speed(args.speed))
    if args.plot and not args.record:
        raise ValueError("--plot needs --record FILE.mcap (the plot is drawn from the recording)")
    after_run: dict[str, Any] = {}
    if args.plot:
        check_output(args.plot, overwrite=args.overwrite, inputs=[args.record])

        def plot(_summary: RunSummary) -> None:
            with atomic_output(args.plot, overwrite=args.overwrite, inputs=[args.record]) as tmp:
                plot_recording(args.record, tmp)

        after_run["plot"] = plot
    with domain_for_run(args, "echoloop launch") as domain:
        summary = run(
            args.file,
            params_overrides=parse_param_overrides(args.param),
            duration=args.duration,
            record=args.record,
            live=True if args.live else None,
            bus=args.bus,
            on_started=announcer(domain),
            domain=domain,
            expect=args.expect,
            allow_disconnected=args.allow_disconnected,
            overwrite=args.overwrite,
            allow_modules=args.allow_module,
            after_run=after_run,
            processes=False if args.threads else None,
            only=args.only,
            skip=args.skip,
            log_dir=args.log_dir,
            realtime=not args.no_realtime,
            speed=speed,
            compose=not args.isolate,
        )
    if args.json:
        print(json.dumps(_jsonable(summary.to_dict()), indent=2, sort_keys=True))
    else:
        print(format_summary(summary, verbose=args.verbose))
    if args.plot and not args.json and not any(f.source == "plot" for f in summary.failures):
        print(f"plot: {args.plot}")
    return report_failures(summary)
