"""``echoloop mavlink px4 [RUN OPTIONS]`` and ``echoloop mavlink rangefinder [RUN OPTIONS]``.

Each is ``echoloop run ENTRY --name NAME``: the node alone against a bus (the domain's, or
``--bus``), e.g. beside a launch, or on the computer a flight controller is plugged into;
every option of ``echoloop run`` applies (``--param vehicle_id=7``,
``--param 'link=serial:///dev/ttyACM0?baud=921600'``).
"""

from __future__ import annotations

import argparse
import sys

from hil_bridge.cli import run as run_cli

ENTRIES = {
    "px4": ("drivers.mavlink.px4:Px4Hil", "PX4's simulator interface (SITL on TCP 4560 + N, "
                                          "HITL on USB serial)"),
    "rangefinder": ("drivers.mavlink.rangefinder:MavlinkRangefinder",
                    "sonar echoes as DISTANCE_SENSOR/OBSTACLE_DISTANCE for any MAVLink "
                    "autopilot"),
}


def _parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="echoloop mavlink",
                                description="Stock autopilots in the loop over MAVLink.")
    sub = p.add_subparsers(dest="command", required=True)
    for name, (_, text) in ENTRIES.items():
        sub.add_parser(name, help=f"{text} (other options: those of `echoloop run`)")
    return p


def main(argv: list[str] | None = None) -> int:
    args, rest = _parser().parse_known_args(sys.argv[1:] if argv is None else argv)
    entry = ENTRIES[args.command][0]
    return run_cli.main([entry, "--name", args.command, *rest])
