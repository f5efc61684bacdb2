"""``echoloop ros2 bridge [--mapping FILE] [--param KEY=VALUE ...]`` and ``echoloop ros2 mapping``.

``bridge`` runs :class:`ros2_bridge.bridge.Ros2Bridge` alone against a bus (the domain's, or
``--bus``), as ``echoloop run ros2_bridge.bridge:Ros2Bridge`` would: until ``--duration`` or
Ctrl-C, then its summary; a bridge that fails exits 1. ``mapping`` prints the default mapping
as YAML, a file to start a mapping of one's own from.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import sys

import yaml

from hil_bridge.cli._args import add_domain_argument, domain_for_run, seconds
from hil_bridge.cli.launch import _jsonable, announcer, format_summary, report_failures
from hil_bridge.files.config import parse_override
from hil_bridge.launch.runner import run
from ros2_bridge.config import DEFAULT_MAPPING, load_mapping
from sim_core.config import apply_overrides

ENTRY = "ros2_bridge.bridge:Ros2Bridge"


def _parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="echoloop ros2",
                                description="Bridge echoloop's bus and a ROS 2 graph.")
    sub = p.add_subparsers(dest="command", required=True)
    b = sub.add_parser("bridge", help="run the ROS 2 bridge node against a bus")
    b.add_argument("--mapping", default=None, metavar="FILE",
                   help="topic mapping (YAML list; default: `echoloop ros2 mapping`)")
    b.add_argument("--param", action="append", default=[], metavar="KEY=VALUE",
                   help="a bridge parameter (world_frame, ros_domain_id, discovery, "
                        "dds_transport; VALUE in YAML syntax); repeatable")
    b.add_argument("--name", default="ros2_bridge", help="the node's name")
    b.add_argument("--bus", default=None, metavar="URL",
                   help="the bus to join (default: the domain's, tcp://127.0.0.1:7400+10N)")
    add_domain_argument(b)
    b.add_argument("--duration", type=seconds, default=None, metavar="S",
                   help="stop after S seconds (default: run until Ctrl-C)")
    b.add_argument("--expect", action="append", default=[], metavar="'NODE.COUNTER OP VALUE'",
                   help="a check of the summary; the run exits 4 unless it holds")
    b.add_argument("--json", action="store_true", help="print the run summary as JSON")
    sub.add_parser("mapping", help="print the default topic mapping (YAML)")
    return p


def main(argv: list[str] | None = None) -> int:
    args = _parser().parse_args(sys.argv[1:] if argv is None else argv)
    if args.command == "mapping":
        print(yaml.safe_dump([dataclasses.asdict(m) for m in DEFAULT_MAPPING],
                             sort_keys=False), end="")
        return 0
    params: dict[str, object] = {}
    if args.mapping is not None:
        load_mapping(args.mapping)  # a bad file fails here, naming the file and the entry
        params["mapping"] = args.mapping
    for item in args.param:
        key, value = parse_override(item)
        params = apply_overrides(params, {key: value})
    launch = {"nodes": [{"name": args.name, "entry": ENTRY, "params": params}]}
    with domain_for_run(args, "echoloop ros2 bridge") as domain:
        summary = run(launch, duration=args.duration, bus=args.bus,
                      on_started=announcer(domain, "echoloop ros2 bridge"), domain=domain,
                      expect=args.expect, processes=False, monitor=False)
    if args.json:
        print(json.dumps(_jsonable(summary.to_dict()), indent=2, sort_keys=True))
    else:
        print(format_summary(summary))
    return report_failures(summary, "echoloop ros2 bridge")
