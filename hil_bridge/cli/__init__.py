"""The ``echoloop`` command: one dispatcher, one module per sub-command, imported lazily.

Each sub-command module exposes ``main(argv: list[str]) -> int`` with its own ``argparse`` parser
(``prog="echoloop <name>"``). User errors (``ValueError``, ``OSError``, :class:`HilError`, and
running out of memory) are printed as one line on stderr and exit with status 1; a usage error
exits 2 (argparse). Readers of input files name the file in their error
(``tests/hil_bridge/cli/test_cli_bad_inputs.py`` feeds every command a corpus of bad files).
``echoloop --version`` prints the installed distribution's version.
"""

from __future__ import annotations

import importlib
import sys

from hil_bridge.errors import HilError

__all__ = ["COMMANDS", "main"]

#: sub-command -> (module, one-line summary)
COMMANDS: dict[str, tuple[str, str]] = {
    "forest": ("hil_bridge.cli.forest", "generate procedural trees and forests (sim_core.world)"),
    "echo": ("hil_bridge.cli.echo", "synthesise one foliage echo (sim_core.sonar)"),
    "scenario": ("hil_bridge.cli.scenario", "run the seed 000 sonar scenarios (Figs 6-7, Table 1)"),
    "swarm": ("hil_bridge.cli.swarm", "run or sweep thermal-soaring swarms (sim_core.soaring)"),
    "launch": ("hil_bridge.cli.launch", "run a YAML launch file (a node graph)"),
    "run": ("hil_bridge.cli.run", "run one node (a launch entry) alone against a bus"),
    "bus": ("hil_bridge.cli.bus", "run the XSUB/XPUB bus proxy alone"),
    "topic": ("hil_bridge.cli.topic", "list|echo|hz|bw|info: inspect live topics"),
    "bag": ("hil_bridge.cli.bag", "record|play|info|export MCAP recordings"),
    "replay": ("hil_bridge.cli.replay", "drive a vehicle along a logged trajectory"),
    "mock": ("drivers.cli", "run a device mock: sonar-head | autopilot"),
    "ros2": ("ros2_bridge.cli", "bridge|mapping: the live ROS 2 bridge (extra 'ros2')"),
    "ardupilot": ("drivers.ardupilot.cli", "sitl|polar: ArduPilot SITL in the loop (JSON)"),
    "mavlink": ("drivers.mavlink.cli", "px4|rangefinder: PX4 HIL, echo ranges into any autopilot"),
    "dronecan": ("drivers.dronecan.cli", "node: echoloop as DroneCAN peripherals of a flight "
                 "controller"),
}


def version() -> str:
    """The installed ``echoloop`` distribution's version (``pyproject.toml``)."""
    from importlib.metadata import PackageNotFoundError
    from importlib.metadata import version as dist_version

    try:
        return dist_version("echoloop")
    except PackageNotFoundError:
        return "unknown (not installed; pip install -e .)"


def _usage() -> str:
    width = max(map(len, COMMANDS))
    lines = ["usage: echoloop [--version] <command> [options]", "", "commands:"]
    lines += [f"  {name:<{width}}  {summary}" for name, (_, summary) in COMMANDS.items()]
    lines += ["", "Run 'echoloop <command> --help' for the options of one command."]
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    args = sys.argv[1:] if argv is None else list(argv)
    if not args or args[0] in ("-h", "--help"):
        print(_usage())
        return 0 if args else 2
    if args[0] == "--version":
        print(f"echoloop {version()}")
        return 0
    name, rest = args[0], args[1:]
    try:
        module_name, _ = COMMANDS[name]
    except KeyError:
        print(
            f"echoloop: unknown command {name!r}; expected one of {sorted(COMMANDS)}",
            file=sys.stderr,
        )
        return 2
    module = importlib.import_module(module_name)
    try:
        return int(module.main(rest))
    except (ValueError, OSError, HilError) as exc:
        print(f"echoloop {name}: error: {exc}", file=sys.stderr)
        return 1
    except MemoryError as exc:  # an input asked for more than the machine has
        print(f"echoloop {name}: error: out of memory ({exc or 'MemoryError'}); an input "
              "asks for more than this machine holds", file=sys.stderr)
        return 1
    except KeyboardInterrupt:
        return 130


if __name__ == "__main__":
    sys.exit(main())
