"""``echoloop replay LOG [--id N] [--topic T] [--origin LAT,LON,ALT] [--sonar HZ] [--rate R] ...``.

Drives a vehicle along a logged trajectory (linear position, shortest-arc heading, slerped
attitude) through a scene's forest and answers pings along it with echoes, in real time times
``--rate`` (or as fast as the CPU allows with ``--fast``: every node on the sim clock, the
built-in pinger a lockstep sonar head pinging every ``1 / HZ`` sim seconds, each ping answered
before the next). ``LOG`` is a PX4 ULog, an ArduPilot DataFlash log, a MAVLink tlog, a ROS 2
bag, an echoloop recording, or a CSV/NPZ table (:mod:`hil_bridge.recording.logs`); what was
read, the origin, any time gaps and position jumps (with the segments they split the log
into, and the one flown) are printed first. ``--sonar HZ`` pings over the bus at that rate (0:
no built-in pinger; a sonar-head adapter or any other node pings ``/sonar/0/ping``). The run
ends when the trajectory does (the server served its last pose and every ping has its echo),
or after ``--duration`` wall seconds. See docs/server.md for the file formats.
"""

from __future__ import annotations

import argparse
import json
import sys

from hil_bridge.cli._args import add_domain_argument, domain_for_run, seconds
from hil_bridge.cli.launch import _jsonable, announcer, format_summary, report_failures
from hil_bridge.launch.runner import run
from hil_bridge.recording.logs import MAX_SPEED_MPS, read_log
from hil_bridge.replay.trajectory import build_replay_launch


def _parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(
        prog="echoloop replay",
        description="Drive a vehicle along a logged trajectory; pings get echoes from the scene.",
    )
    p.add_argument("file", help="flight log: .ulg, .bin, .tlog, ROS 2 bag, echoloop .mcap, "
                                "CSV or NPZ (see docs/server.md)")
    p.add_argument("--id", type=int, default=None,
                   help="vehicle of a multi-vehicle log (trace id, glider id, MAVLink system "
                        "id); also the replayed vehicle's id (default 0)")
    p.add_argument("--topic", default=None,
                   help="the position source by name: a ROS 2 bag's pose topic; a ULog topic "
                        "(vehicle_global_position, vehicle_local_position, "
                        "vehicle_gps_position, sensor_gps; NAME[N]: instance N); a tlog's "
                        "GLOBAL_POSITION_INT or LOCAL_POSITION_NED; a DataFlash POS, AHR2, "
                        "GPS[N] (GPS2 = GPS[1]); a recording's /glider/ID/state (default: "
                        "the first of these the file has; a wrong name lists the file's)")
    p.add_argument("--origin", default=None, metavar="LAT,LON,ALT",
                   help="local ENU origin of a geodetic log (deg, deg, m; default: first fix); "
                        "write --origin=-33.9,... for a negative latitude")
    p.add_argument("--max-gap", type=float, default=1.0, metavar="S",
                   help="report intervals between poses longer than this (default 1 s)")
    p.add_argument("--max-speed", type=float, default=MAX_SPEED_MPS, metavar="M/S",
                   help="a step between two poses implying a faster speed is a position "
                        "jump (an origin reset, a GPS glitch): reported, never flown; the log "
                        f"is split there into segments (default {MAX_SPEED_MPS:g} m/s)")
    p.add_argument("--segment", type=int, default=None, metavar="K",
                   help="the segment between position jumps to fly (0-based; default the "
                        "longest in time)")
    p.add_argument("--sonar", type=float, default=10.0, metavar="HZ",
                   help="built-in pinger rate in Hz, of the wall clock (with --fast: of sim "
                        "time) (0: none, pings come from other nodes)")
    p.add_argument("--beamwidth", type=float, default=None, metavar="RAD",
                   help="fixed beamwidth of the built-in pings (default: U(30°, 65°) per ping)")
    p.add_argument("--fidelity", default="fast", help="echo fidelity (sim_core.sonar.FIDELITIES)")
    p.add_argument("--rate", type=float, default=1.0, help="real-time factor (default 1)")
    p.add_argument("--fast", action="store_true",
                   help="step as fast as the CPU allows, every node on the sim clock (the "
                        "pinger waits for each echo)")
    p.add_argument("--scene", default=None, metavar="FILE.yaml",
                   help="scene file whose forest is used (default: the seed 000 Fig 5(d) "
                        "forest)")
    p.add_argument("--state-rate", type=float, default=50.0, metavar="HZ",
                   help="state stream rate (default 50)")
    p.add_argument("--duration", type=seconds, default=None, metavar="S",
                   help="wall seconds to run at most (default: until the trajectory ends)")
    p.add_argument("--bus", default=None, metavar="URL", help="bus URL (default: the domain's)")
    add_domain_argument(p, auto=True)
    p.add_argument("--record", default=None, metavar="FILE.mcap", help="record every topic")
    p.add_argument("--overwrite", action="store_true", help="replace an existing --record file")
    p.add_argument("--json", action="store_true", help="print the run summary as JSON")
    return p


def main(argv: list[str] | None = None) -> int:
    args = _parser().parse_args(sys.argv[1:] if argv is None else argv)
    if not args.rate > 0:
        raise ValueError(f"--rate: expected a real-time factor > 0, got {args.rate}")
    if args.sonar < 0:
        raise ValueError(f"--sonar: expected a rate >= 0 Hz, got {args.sonar}")
    pinger = {} if args.beamwidth is None else {"beamwidth": args.beamwidth}
    origin = None
    if args.origin is not None:
        from hil_bridge.cli.echo import parse_floats

        lat, lon, alt = parse_floats(args.origin, 3, "--origin")
        origin = (lat, lon, alt)
    _, report = read_log(args.file, vehicle_id=args.id, topic=args.topic, origin=origin,
                         max_gap_s=args.max_gap, max_speed_mps=args.max_speed,
                         segment=args.segment)
    print("\n".join(report.lines()), file=sys.stderr if args.json else sys.stdout, flush=True)
    launch, _ = build_replay_launch(
        args.file,
        vehicle_id=args.id,
        scene=args.scene,
        sonar_rate_hz=args.sonar or None,
        sonar={"fidelity": args.fidelity},
        pinger=pinger,
        rate=args.rate,
        state_rate_hz=args.state_rate,
        bus=args.bus,
        clock_mode="fast" if args.fast else "realtime",
        topic=args.topic,
        origin=origin,
        max_speed_mps=args.max_speed,
        segment=args.segment,
    )
    with domain_for_run(args, "echoloop replay") as domain:
        summary = run(launch, duration=args.duration, record=args.record, domain=domain,
                      on_started=announcer(domain, "echoloop replay"),
                      overwrite=args.overwrite, until_finished=True)
    if args.json:
        out = _jsonable(summary.to_dict())
        out["log"] = report.as_dict()
        print(json.dumps(out, indent=2, sort_keys=True))
    else:
        print(format_summary(summary))
    return report_failures(summary, "echoloop replay")
