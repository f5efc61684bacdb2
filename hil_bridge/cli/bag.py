"""``echoloop bag record|play|info|export``: MCAP recordings of the bus.

    echoloop bag record out.mcap [--topics /glider/0/state /clock] [--duration 30]
    echoloop bag play out.mcap [--rate 2] [--loop] [--start-offset 5] [--topics ...] [--clock]
    echoloop bag info out.mcap [--json]
    echoloop bag export out.mcap --json out_json.mcap      # JSON + JSON Schema, for Foxglove
    echoloop bag export out.mcap --ros2 out_ros2.mcap      # ROS 2 bag (CDR, ros2msg schemas)
    echoloop bag export out.mcap --foxglove out_fox.mcap   # Foxglove well-known schemas (3D)
    echoloop bag export out.mcap --mat out.mat             # MATLAB v5: echoes, pings, tracks
    echoloop bag recover broken.mcap fixed.mcap            # a valid, indexed copy of what reads

``record`` and ``play`` use the domain's bus (``--domain`` or ``ECHOLOOP_DOMAIN``) unless
``--bus`` names one. A corrupt chunk is skipped with a warning on stderr (info, play,
export) and the rest is read; ``recover`` writes everything readable into a new file with a
summary and index (any MCAP reader opens it) and says how many messages it kept and lost.
Outputs are never overwritten without ``--overwrite`` and never written onto their input.
"""

from __future__ import annotations

import argparse
import json
import math
import signal
import sys
import threading
import time
from types import FrameType

from hil_bridge.cli._args import add_domain_argument, domain_from, seconds
from hil_bridge.outputs import atomic_output
from hil_bridge.recording.bag import BagInfo, bag_info
from hil_bridge.recording.bag_player import Player
from hil_bridge.recording.bag_writer import export_json, recover
from hil_bridge.recording.recorder import Recorder


def _rate(text: str) -> float:
    value = float(text)
    if value == 0:
        return math.inf
    if not value > 0:
        raise argparse.ArgumentTypeError(f"rate must be > 0 (0: as fast as possible), got {text}")
    return value


def _stop_on_signals() -> threading.Event:
    stop = threading.Event()

    def on_signal(signum: int, frame: FrameType | None) -> None:
        stop.set()

    for sig in (signal.SIGINT, signal.SIGTERM, signal.SIGHUP):
        signal.signal(sig, on_signal)
    return stop


def _fmt(x: float | None, unit: str) -> str:
    return "-" if x is None else f"{x:.1f} {unit}"


def _record(args: argparse.Namespace) -> int:
    from hil_bridge.launch.runner import RunSummary, judge

    stop = _stop_on_signals()
    recorder = Recorder(args.file, args.topics, bus=args.bus, chunk_size=args.chunk_size,
                        flush_period_s=args.flush_period, compression=args.compression,
                        overwrite=args.overwrite)
    recorder.start()
    t0 = time.monotonic()
    deadline = None if args.duration is None else t0 + args.duration
    stopped_by = "signal"
    try:
        print(f"recording {'all topics' if args.topics is None else args.topics} from "
              f"{args.bus} into {args.file} (Ctrl-C stops)", flush=True)
        while not stop.is_set():
            if recorder.failure() is not None:
                stopped_by = "failure"
                break
            left = None if deadline is None else deadline - time.monotonic()
            if left is not None and left <= 0:
                stopped_by = "duration"
                break
            stop.wait(0.1 if left is None else min(0.1, left))
    finally:
        recorder.stop()
    s = recorder.stats()
    print(f"recorded {s['messages']} messages ({s['bytes']} payload bytes) into {args.file}")
    failure = recorder.failure(final=True)
    summary = RunSummary(wall_s=time.monotonic() - t0, stopped_by=stopped_by, nodes={},
                         record=str(args.file), extras={recorder.name: s}, bus=args.bus)
    reason = (f"{args.file}: the recording is incomplete: {failure} "
              f"({s['lost_after_error'] + s['not_recorded']} messages not recorded)")
    summary.failures = judge(summary, failed=[(recorder.name, reason)] if failure else [])
    for problem in summary.failures:
        print(f"echoloop bag record: error: {problem.message}", file=sys.stderr)
    return summary.exit_status


def _warn_damage(info: BagInfo) -> None:
    """One line on stderr when the file was cut short or corrupt parts were skipped (reading
    went on)."""
    if info.scan is not None and (info.damaged or info.skipped):
        print(f"echoloop bag: warning: {info.path}: {info.scan.describe()}"
              + (f", {info.skipped} messages on channels that are not bus topics"
                 if info.skipped else ""), file=sys.stderr)


def _play(args: argparse.Namespace) -> int:
    stop = _stop_on_signals()
    player = Player(args.file, bus=args.bus, rate=args.rate, loop=args.loop,
                    start_offset_s=args.start_offset, topics=args.topics, clock=args.clock,
                    clock_hz=args.clock_hz, wait_for_subscribers_s=args.wait_subscribers)
    player.start()
    try:
        while not player.wait(0.2):
            if stop.is_set():
                break
    finally:
        player.stop()
    if player.error is not None:
        raise OSError(f"{args.file}: playback failed: {player.error}")
    if player.info is not None:
        _warn_damage(player.info)
    s = player.stats()
    note = " (bag truncated: played up to its last complete chunk)" if s["truncated"] else ""
    print(f"published {s['published']} messages in {s['passes']} pass(es){note}")
    return 0


def _info(args: argparse.Namespace) -> int:
    info = bag_info(args.file)
    _warn_damage(info)
    if args.json:
        print(json.dumps(info.as_dict(), indent=2))
        return 0
    print(f"path:      {info.path}")
    print(f"messages:  {info.messages} on {len(info.topics)} topics, {info.channels} channels")
    print(f"duration:  {info.duration_s:.3f} s")
    if info.truncated:
        print("truncated: yes, no summary (read up to the last complete chunk; "
              "'echoloop bag recover' writes a finished copy)")
    if info.damaged and info.scan is not None:
        print(f"damage:    {info.scan.describe()}")
    width = max((len(t) for t in info.topics), default=5)
    print(f"{'topic':<{width}}  {'count':>7}  {'rate':>10}  {'gaps':>5}  {'lost':>6}  type")
    for topic, st in sorted(info.topics.items()):
        print(f"{topic:<{width}}  {st.count:>7}  {_fmt(st.rate_hz, 'Hz'):>10}  {st.gaps:>5}  "
              f"{st.lost:>6}  {','.join(sorted(st.types))}")
    return 0


def _export(args: argparse.Namespace) -> int:
    if args.json_out is not None:
        info = BagInfo(args.file)
        with atomic_output(args.json_out, overwrite=args.overwrite, inputs=[args.file]) as tmp:
            counts = export_json(args.file, tmp, topics=args.topics, info=info)
        _warn_damage(info)
        print(f"wrote {counts['messages']} JSON messages to {args.json_out}"
              + (f" (skipped {counts['skipped']} undecodable)" if counts["skipped"] else ""))
        return 0
    from hil_bridge.recording.export import EXPORTERS, run_exporter

    kind = next(k for k in EXPORTERS if getattr(args, k) is not None)
    result = run_exporter(kind, args.file, getattr(args, kind), overwrite=args.overwrite)
    skipped = ", ".join(f"{n} {why}" for why, n in result.skipped.items())
    print(f"wrote {result.written} {kind} messages from {result.messages} recorded to "
          f"{getattr(args, kind)}" + (f" (skipped: {skipped})" if skipped else "")
          + (" (bag truncated: read up to its last complete chunk)" if result.truncated else ""))
    return 0


def _recover(args: argparse.Namespace) -> int:
    report = recover(args.file, args.out, overwrite=args.overwrite)
    state = "finished" if report.finished else "unfinished (no summary)"
    print(f"recovered {args.file} ({state}) into {args.out}: kept {report.messages} messages, "
          f"lost {report.lost}" + ("" if report.stated_messages is not None or not report.damaged
                                   else " or more"))
    if report.damaged:
        print(f"echoloop bag: warning: {args.file}: {report.describe()}", file=sys.stderr)
        for line in report.errors:
            print(f"  {line}")
    return 0


def main(argv: list[str]) -> int:
    parser = argparse.ArgumentParser(prog="echoloop bag", description=__doc__,
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    sub = parser.add_subparsers(dest="cmd", required=True)

    rec = sub.add_parser("record", help="record topics into an MCAP file")
    rec.add_argument("file")
    rec.add_argument("--bus", default=None, help="bus URL (default: the domain's)")
    add_domain_argument(rec)
    rec.add_argument("--topics", nargs="+", default=None, help="default: every topic")
    rec.add_argument("--duration", type=seconds, default=None, help="seconds (default: Ctrl-C)")
    rec.add_argument("--chunk-size", type=int, default=64 * 1024, help="bytes per MCAP chunk")
    rec.add_argument("--flush-period", type=float, default=1.0,
                     help="seconds between forced chunk flushes (data at risk on a crash)")
    rec.add_argument("--compression", default="zstd", choices=["zstd", "lz4", "none"])
    rec.add_argument("--overwrite", action="store_true", help="replace an existing file")
    rec.set_defaults(run=_record)

    play = sub.add_parser("play", help="publish a recording on the bus")
    play.add_argument("file")
    play.add_argument("--bus", default=None, help="bus URL (default: the domain's)")
    add_domain_argument(play)
    play.add_argument("--rate", type=_rate, default=1.0, help="speed factor (0: no pacing)")
    play.add_argument("--loop", action="store_true")
    play.add_argument("--start-offset", type=float, default=0.0, help="skip the first S seconds")
    play.add_argument("--topics", nargs="+", default=None)
    play.add_argument("--clock", action="store_true", help="publish /clock from the stamps")
    play.add_argument("--clock-hz", type=float, default=100.0)
    play.add_argument("--wait-subscribers", type=float, default=0.0, metavar="S",
                      help="first wait up to S seconds for a subscriber on every topic")
    play.set_defaults(run=_play)

    info = sub.add_parser("info", help="topics, counts, rates, seq gaps of a recording")
    info.add_argument("file")
    info.add_argument("--json", action="store_true")
    info.set_defaults(run=_info)

    exp = sub.add_parser("export", help="convert a recording for ROS 2, Foxglove or MATLAB")
    exp.add_argument("file")
    fmt = exp.add_mutually_exclusive_group(required=True)
    fmt.add_argument("--json", dest="json_out", metavar="OUT.mcap",
                     help="JSON messages with JSON Schemas")
    fmt.add_argument("--ros2", metavar="OUT.mcap", help="ROS 2 bag: CDR, ros2msg schemas")
    fmt.add_argument("--foxglove", metavar="OUT.mcap", help="Foxglove well-known schemas")
    fmt.add_argument("--mat", metavar="OUT.mat", help="MATLAB v5: echoes, pings, tracks")
    exp.add_argument("--topics", nargs="+", default=None, help="--json only: these topics")
    exp.add_argument("--overwrite", action="store_true", help="replace an existing output")
    exp.set_defaults(run=_export)

    rec = sub.add_parser("recover", help="write a valid, indexed copy of what is readable")
    rec.add_argument("file", help="a recording cut short, killed, or with corrupt chunks")
    rec.add_argument("out", help="the repaired MCAP file to write")
    rec.add_argument("--overwrite", action="store_true", help="replace an existing output")
    rec.set_defaults(run=_recover)

    args = parser.parse_args(argv)
    if args.cmd in ("record", "play") and args.bus is None:
        args.bus = domain_from(args, f"echoloop bag {args.cmd}").bus_url
    return int(args.run(args))
