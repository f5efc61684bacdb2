"""``echoloop mock <device>``: run a device mock alone, e.g. the far end of a pty for an adapter.

``SUBCOMMANDS`` maps each device to ``("module:function", summary)``; the function takes the
remaining argv and returns an exit status (imported lazily, so one device's dependencies never
load for another).
"""

from __future__ import annotations

import argparse
import importlib
import sys
import threading
import time
from collections.abc import Callable
from typing import Any

from hil_bridge.bus.domain import use
from hil_bridge.cli._args import add_domain_argument, domain_from, seconds

__all__ = ["SUBCOMMANDS", "main", "sonar_head"]

#: device -> ("module:function", one-line summary)
SUBCOMMANDS: dict[str, tuple[str, str]] = {
    "sonar-head": ("drivers.cli:sonar_head", "mock sonar head on a pty or serial URL (spec §2)"),
    "autopilot": ("drivers.mocks.autopilot_cli:main", "mock glider autopilot on a CAN bus (§3)"),
}


def _resolve(target: str) -> Callable[[list[str]], int]:
    module, _, attr = target.partition(":")
    fn: Callable[[list[str]], int] = getattr(importlib.import_module(module), attr)
    return fn


def main(argv: list[str]) -> int:
    names = sorted(SUBCOMMANDS)
    if not argv or argv[0] in ("-h", "--help"):
        width = max(map(len, names))
        print("usage: echoloop mock <device> [options]\n\ndevices:")
        for name in names:
            print(f"  {name:<{width}}  {SUBCOMMANDS[name][1]}")
        return 0 if argv else 2
    name, rest = argv[0], argv[1:]
    if name not in SUBCOMMANDS:
        print(f"echoloop mock: unknown device {name!r}; expected one of {names}", file=sys.stderr)
        return 2
    return int(_resolve(SUBCOMMANDS[name][0])(rest))


def _beamwidth(text: str) -> float | str:
    if text == "random":
        return text
    try:
        return float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected degrees or 'random', got {text!r}") from None


def _fmt(v: Any) -> str:
    return f"{v:.2f}" if isinstance(v, float) else str(v)


def sonar_head(argv: list[str]) -> int:
    """``echoloop mock sonar-head``: ping at a rate, check echoes, print latency and range."""
    parser = argparse.ArgumentParser(
        prog="echoloop mock sonar-head",
        description="Mock biomimetic sonar head (the device end of a serial link, spec §2). "
        "With --pty it creates a pseudo-terminal and prints the path for the adapter "
        "(sonar_head.port); with --port it opens a serial device or URL.",
    )
    where = parser.add_mutually_exclusive_group(required=True)
    where.add_argument("--port", metavar="URL", help="serial device or URL to act as the head on")
    where.add_argument("--pty", action="store_true", help="create a pty and act as its device")
    parser.add_argument("--link", metavar="PATH",
                        help="with --pty: symlink PATH to the pty slave (default: the domain's "
                             "sonar0, where the sonar_head adapter looks by default)")
    add_domain_argument(parser)
    parser.add_argument("--rate", type=float, default=10.0, metavar="HZ", help="pings per second")
    parser.add_argument("--beamwidth", type=_beamwidth, default="random", metavar="DEG|random",
                        help="full -3 dB beamwidth, or 'random' = uniform in [30, 65] per ping")
    parser.add_argument("--encoding", default="int16", choices=["int16", "iq16", "float32"])
    parser.add_argument("--baud", type=int, default=921600, metavar="B",
                        help="baud rate to throttle to (8N1)")
    parser.add_argument("--channels", type=int, default=1)
    parser.add_argument("--seed", type=int, default=0, help="seed of the beamwidth draws")
    parser.add_argument("--no-throttle", action="store_true",
                        help="do not pace bytes to the baud rate (real UARTs pace themselves)")
    parser.add_argument("--duration", type=seconds, default=None, metavar="S",
                        help="stop after S seconds (default: until Ctrl-C)")
    parser.add_argument("--every", type=float, default=2.0, metavar="S",
                        help="print a status line every S seconds (0: only at the end)")
    args = parser.parse_args(argv)
    if args.link is not None and not args.pty:
        parser.error("--link needs --pty")

    from drivers.mocks.sonar_head import MockSonarHead

    with use(domain_from(args, "echoloop mock sonar-head")):
        mock = MockSonarHead(
            "sonar_head_mock", port=args.port, pty=args.pty, link=args.link, rate_hz=args.rate,
            beamwidth=args.beamwidth, encoding=args.encoding, baudrate=args.baud,
            channels=args.channels, seed=args.seed, throttle=not args.no_throttle)
    done = threading.Event()
    mock.start()
    try:
        print(f"mock sonar head on {mock.path} ({args.baud} baud, {args.rate:g} pings/s, "
              f"{args.encoding}); open it with sonar_head.port={mock.path}", flush=True)
        t_end = None if args.duration is None else time.monotonic() + args.duration
        while not done.is_set():
            left = None if t_end is None else t_end - time.monotonic()
            if left is not None and left <= 0:
                break
            step = args.every if args.every > 0 else (left if left is not None else 3600.0)
            done.wait(step if left is None else min(step, left))
            if args.every > 0:
                _print_status(mock.stats())
    except KeyboardInterrupt:
        pass
    finally:
        mock.stop()
    st = mock.stats()
    print("summary: " + ", ".join(f"{k}={_fmt(v)}" for k, v in sorted(st.items())
                                  if not k.startswith("decoder_")))
    return 0


def _print_status(st: dict[str, Any]) -> None:
    keys = ("pings_sent", "echoes_complete", "echoes_incomplete", "echo_timeouts", "crc_errors",
            "latency_p50_ms", "latency_p99_ms", "last_range_m")
    print("  ".join(f"{k}={_fmt(st.get(k))}" for k in keys), flush=True)
