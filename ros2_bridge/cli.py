"""``echoloop ros2 bridge [--mapping FILE] [RUN OPTIONS]`` and ``echoloop ros2 mapping``.

``bridge`` is ``echoloop run ros2_bridge.bridge:Ros2Bridge --name ros2_bridge``: the bridge alone
against a bus (the domain's, or ``--bus``), until ``--duration`` or Ctrl-C, then its summary; a
bridge that fails exits 1. Every option of ``echoloop run`` applies (``--param``, ``--bus``,
``--domain``, ``--duration``, ``--expect``, ``--json``, ``--name``); ``--mapping FILE`` is checked
here, so a bad file fails before anything starts. ``mapping`` prints the default mapping as
YAML, a file to start a mapping of one's own from.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import sys

import yaml

from hil_bridge.cli import run as run_cli
from ros2_bridge.config import DEFAULT_MAPPING, load_mapping

ENTRY = "ros2_bridge.bridge:Ros2Bridge"


def _parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="echoloop ros2",
                                description="Bridge echoloop's bus and a ROS 2 graph.")
    sub = p.add_subparsers(dest="command", required=True)
    b = sub.add_parser("bridge", help="run the ROS 2 bridge node against a bus (other options: "
                                      "those of `echoloop run`)")
    b.add_argument("--mapping", default=None, metavar="FILE",
                   help="topic mapping (YAML list; default: `echoloop ros2 mapping`)")
    sub.add_parser("mapping", help="print the default topic mapping (YAML)")
    return p


def main(argv: list[str] | None = None) -> int:
    args, rest = _parser().parse_known_args(sys.argv[1:] if argv is None else argv)
    if args.command == "mapping":
        if rest:
            raise ValueError(f"echoloop ros2 mapping takes no options, got {rest}")
        print(yaml.safe_dump([dataclasses.asdict(m) for m in DEFAULT_MAPPING],
                             sort_keys=False), end="")
        return 0
    forwarded = [ENTRY, "--name", "ros2_bridge"]
    if args.mapping is not None:
        load_mapping(args.mapping)  # a bad file fails here, naming the file and the entry
        forwarded += ["--param", f"mapping={json.dumps(args.mapping)}"]  # JSON is YAML
    return run_cli.main(forwarded + rest)
