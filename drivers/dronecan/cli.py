"""``echoloop dronecan node [RUN OPTIONS]``: the DroneCAN node alone.

It is ``echoloop run drivers.dronecan.node:DroneCanNode --name dronecan``: the node against a
bus (the domain's, or ``--bus``), beside a running launch or on the computer a flight
controller's CAN adapter is plugged into; every option of ``echoloop run`` applies
(``--param vehicle_id=7``, ``--param 'interface=slcan:/dev/ttyACM0?baud=1000000'``,
``--param node_id=42``). docs/dronecan.md says how to wire and set up the flight controller.
"""

from __future__ import annotations

import argparse
import sys

from hil_bridge.cli import run as run_cli

ENTRIES = {
    "node": ("drivers.dronecan.node:DroneCanNode",
             "echoloop as DroneCAN peripherals: echo ranges, air data, GNSS out; servos in"),
}


def _parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="echoloop dronecan",
                                description="A stock flight controller on CAN (DroneCAN).")
    sub = p.add_subparsers(dest="command", required=True)
    for name, (_, text) in ENTRIES.items():
        sub.add_parser(name, help=f"{text} (other options: those of `echoloop run`)")
    return p


def main(argv: list[str] | None = None) -> int:
    args, rest = _parser().parse_known_args(sys.argv[1:] if argv is None else argv)
    return run_cli.main([ENTRIES[args.command][0], "--name", "dronecan", *rest])
