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
from pathlib import Path
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
        lines.append(
            f"sonar: {head['pings_sent']} pings, {head['echoes_complete']} echoes complete "
            f"({head.get('echoes_incomplete', 0)} incomplete, {head.get('echo_timeouts', 0)} "
            f"timed out, {head.get('crc_errors', 0)} CRC errors); ping -> last chunk "
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
            f"{srv['echoes_published']} echoes, {srv['stalls']} lockstep stalls"
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
        )
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
    return "\n".join(lines)


def _announce(spec: LaunchSpec) -> None:
    names = ", ".join(n.name for n in spec.nodes)
    print(f"echoloop launch: running {names} on {spec.bus} (Ctrl-C to stop)", file=sys.stderr,
          flush=True)


def plot_recording(mcap: str | Path, png: str | Path) -> dict[str, int]:
    """Plot a recording: swarm tracks + thermals, the sonar vehicle over the forest, an echo.

    The sonar vehicle is the one named by the echoes' ``frame_id`` (``glider/<id>``). Returns
    counts of what was drawn.
    """
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    import numpy as np

    from hil_bridge.bag import read_bag
    from hil_bridge.codec import decode_payload

    tracks: dict[int, list[tuple[float, float]]] = {}
    thermals: Any = None
    leaves: Any = None
    echo: Any = None
    mount: int | None = None
    for m in read_bag(mcap):
        topic = m.topic
        is_state = topic.startswith("/glider/") and topic.endswith("/state")
        if not (is_state or topic in ("/thermals", "/forest/points") or topic.endswith("/echo")):
            continue
        msg: Any = decode_payload(m.header.type, m.header.v, m.payload)
        if is_state:
            tracks.setdefault(int(topic.split("/")[2]), []).append((msg.x, msg.y))
        elif topic == "/thermals":
            thermals = msg
        elif topic == "/forest/points":
            leaves = msg
        else:
            # show the last echo that heard leaves (an empty one says little), else the last
            if echo is None or msg.leaves_in_beam > 0 or echo.leaves_in_beam == 0:
                echo = msg
            frame = m.header.frame_id
            if frame.startswith("glider/") and frame[7:].isdigit():
                mount = int(frame[7:])
    fig, axes = plt.subplots(1, 3, figsize=(16, 5.2))
    ax = axes[0]
    if thermals is not None:
        for x, y, r in zip(thermals.x, thermals.y, thermals.radius, strict=True):
            ax.add_patch(plt.Circle((x / 1e3, y / 1e3), r / 1e3, color="tab:orange", alpha=0.25))
    for gid, pts in sorted(tracks.items()):
        if gid == mount:
            continue
        a = np.asarray(pts)
        ax.plot(a[:, 0] / 1e3, a[:, 1] / 1e3, lw=1.2)
        ax.plot(a[-1, 0] / 1e3, a[-1, 1] / 1e3, "k^", ms=4)
    ax.set(title="soaring swarm (CAN autopilots), thermals", xlabel="x [km]", ylabel="y [km]",
           aspect="equal")
    ax = axes[1]
    if leaves is not None:
        ax.scatter(leaves.points[:, 0], leaves.points[:, 1], s=0.3, c="tab:green", alpha=0.3,
                   label="leaves")
    if mount is not None and mount in tracks:
        a = np.asarray(tracks[mount])
        ax.plot(a[:, 0], a[:, 1], "k-", lw=1.2, label=f"sonar vehicle {mount}")
        ax.plot(a[-1, 0], a[-1, 1], "r^", ms=6)
    ax.set(title="sonar vehicle in the forest", xlabel="x [m]", ylabel="y [m]", aspect="equal")
    if ax.get_legend_handles_labels()[1]:
        ax.legend(loc="upper right", fontsize=8)
    ax = axes[2]
    if echo is not None:
        samples = np.asarray(echo.samples, dtype=np.float64).reshape(-1, echo.samples.shape[-1])
        rng_m = np.arange(samples.shape[1]) / echo.fs * 340.0 / 2.0
        ax.plot(rng_m, samples[0], lw=0.5)
        ax.set(title=f"echo of ping {echo.ping_seq} ({echo.leaves_in_beam} leaves in beam)",
               xlabel="range [m] (c = 340 m/s)", ylabel="amplitude")
    fig.tight_layout()
    Path(png).parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(png, dpi=110)
    plt.close(fig)
    return {"tracks": len(tracks), "echo": int(echo is not None),
            "leaves": 0 if leaves is None else len(leaves.points)}


def main(argv: list[str] | None = None) -> int:
    args = _parser().parse_args(sys.argv[1:] if argv is None else argv)
    if args.plot and not args.record:
        raise ValueError("--plot needs --record FILE.mcap (the plot is drawn from the recording)")
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
        print(format_summary(summary, verbose=args.verbose))
    if args.plot:
        plot_recording(args.record, args.plot)
        if not args.json:
            print(f"plot: {args.plot}")
    return 0
