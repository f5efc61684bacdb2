"""``echoloop run ENTRY [--name NAME] [--param KEY=VALUE ...] [--bus URL] [--domain N]``.

Runs one node alone in this process against a bus, as ``ros2 run`` does: the node a launch
file would start, so it can sit on another host (``--bus tcp://HOST:7400``) or be restarted
by hand beside a running launch that leaves it out (``echoloop launch FILE --skip NAME``).
``ENTRY`` is ``package.module:Class`` (a launch entry); ``--param`` sets one of its parameters
(dotted keys reach into mappings; the value is YAML). The node runs until ``--duration`` or
Ctrl-C/SIGTERM; its summary, its failures and the exit status are those of ``echoloop launch``.
"""

from __future__ import annotations

import argparse
import json
import sys

from hil_bridge.cli._args import add_domain_argument, domain_for_run, seconds
from hil_bridge.cli.launch import _jsonable, announcer, format_summary, report_failures
from hil_bridge.files.config import parse_override
from hil_bridge.launch.runner import run
from sim_core.config import apply_overrides


def _parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="echoloop run",
                                description="Run one node (a launch entry) in this process.")
    p.add_argument("entry", help="package.module:Class, e.g. drivers.can.adapter:AutopilotAdapter")
    p.add_argument("--name", default=None,
                   help="the node's name (default: the class name in lower case)")
    p.add_argument("--param", action="append", default=[], metavar="KEY=VALUE",
                   help="a node parameter (VALUE in YAML syntax; dotted KEY reaches into "
                        "mappings); repeatable")
    p.add_argument("--bus", default=None, metavar="URL",
                   help="the bus to join (default: the domain's, tcp://127.0.0.1:7400+10N)")
    add_domain_argument(p)
    p.add_argument("--duration", type=seconds, default=None, metavar="S",
                   help="stop after S seconds (default: run until Ctrl-C)")
    p.add_argument("--expect", action="append", default=[], metavar="'NODE.COUNTER OP VALUE'",
                   help="a check of the node's summary; the run exits 4 unless it holds")
    p.add_argument("--allow-disconnected", action="store_true",
                   help="exit 0 even if a hardware link never connected (otherwise exit 3)")
    p.add_argument("--allow-module", action="append", default=[], metavar="MODULE",
                   help="also allow entries from MODULE (and below it); repeatable")
    p.add_argument("--overwrite", action="store_true",
                   help="let the node replace existing output files (captures, logs)")
    p.add_argument("--json", action="store_true", help="print the run summary as JSON")
    return p


def main(argv: list[str] | None = None) -> int:
    args = _parser().parse_args(sys.argv[1:] if argv is None else argv)
    module, sep, attr = args.entry.partition(":")
    if not sep or not module or not attr:
        raise ValueError(f"ENTRY: expected 'package.module:Class', got {args.entry!r}")
    params: dict[str, object] = {}
    for item in args.param:
        key, value = parse_override(item)
        params = apply_overrides(params, {key: value})
    name = args.name or attr.lower()
    launch: dict[str, object] = {"nodes": [{"name": name, "entry": args.entry,
                                            "params": params}]}
    with domain_for_run(args, "echoloop run") as domain:
        summary = run(
            launch, duration=args.duration, bus=args.bus, on_started=announcer(domain,
                                                                               "echoloop run"),
            domain=domain, expect=args.expect, allow_disconnected=args.allow_disconnected,
            overwrite=args.overwrite, allow_modules=args.allow_module, processes=False,
            monitor=False,
        )
    if args.json:
        print(json.dumps(_jsonable(summary.to_dict()), indent=2, sort_keys=True))
    else:
        print(format_summary(summary))
    return report_failures(summary, "echoloop run")


def node_commands(prog: str, description: str, entries: dict[str, tuple[str, str]],
                  argv: list[str] | None = None, *, node_name: str | None = None) -> int:
    """``PROG COMMAND [RUN OPTIONS]`` for a driver's launchable nodes: ``entries`` maps each
    command to its ``(ENTRY, help)``; the command runs as ``echoloop run ENTRY --name NAME``
    (NAME: ``node_name``, else the command), every option of ``echoloop run`` applying."""
    p = argparse.ArgumentParser(prog=prog, description=description)
    sub = p.add_subparsers(dest="command", required=True)
    for name, (_, text) in entries.items():
        sub.add_parser(name, help=f"{text} (other options: those of `echoloop run`)")
    args, rest = p.parse_known_args(sys.argv[1:] if argv is None else argv)
    return main([entries[args.command][0], "--name", node_name or args.command, *rest])
