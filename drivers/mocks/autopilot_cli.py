"""``echoloop mock autopilot``: run the mock glider autopilot alone on a python-can bus.

Listed in ``drivers.cli.SUBCOMMANDS`` as ``drivers.mocks.autopilot_cli:main``. Output (status
lines and the summary) goes to stdout; this module is a CLI, hence its prints.
"""

from __future__ import annotations

import argparse
import threading
import time
from typing import Any

import numpy as np

from hil_bridge.bus.domain import use
from hil_bridge.cli._args import add_domain_argument, domain_from, seconds

__all__ = ["main"]

_STATUS_KEYS = ("commands_sent", "heartbeats_sent", "rx_states", "rx_samples_torn",
                "rx_nb_sets", "rx_bridge_heartbeats", "rx_decode_errors", "can_state")


def _fmt(value: Any) -> str:
    return f"{value:.3f}" if isinstance(value, float) else str(value)


def main(argv: list[str]) -> int:
    parser = argparse.ArgumentParser(
        prog="echoloop mock autopilot",
        description="Mock glider autopilot on a CAN bus (profile drivers/can/glider.dbc, "
        "docs/can.md): decodes state and neighbour frames, flies seed 002's Boids or a path "
        "follower and sends bank/airspeed commands and heartbeats. python-can's 'virtual' "
        "interface connects buses of one process only (use it from a launch file); across "
        "processes use socketcan on vcan0/can0.",
    )
    parser.add_argument("--interface", default="virtual", help="python-can interface")
    parser.add_argument("--channel", default=None,
                        help="python-can channel (virtual: default the domain's, glider.d<N>)")
    add_domain_argument(parser)
    parser.add_argument("--bitrate", type=int, default=None, help="bits/s (default: interface's)")
    parser.add_argument("--gliders", default="0", metavar="N,N,...",
                        help="node ids to fly (0..15), e.g. 0,1,2")
    parser.add_argument("--controller", default="unified", choices=["unified", "baseline", "path"])
    parser.add_argument("--law", default=None, metavar="FILE", help="law YAML (default: seed law)")
    parser.add_argument("--rate", type=float, default=None, metavar="HZ",
                        help="control rate (default: 1 / law.dt for Boids, 10 Hz for path)")
    parser.add_argument("--waypoints", default=None, metavar="FILE",
                        help="path controller: closed route, two columns x y in metres "
                        "(text/CSV; default: a figure-eight around the origin)")
    parser.add_argument("--path-airspeed", type=float, default=10.0, metavar="M/S",
                        help="path controller: airspeed command")
    parser.add_argument("--lookahead", type=float, default=25.0, metavar="M",
                        help="path controller: pure-pursuit look-ahead distance")
    parser.add_argument("--can-log", default=None, metavar="PATH",
                        help="candump-format log of the mock's traffic (.log)")
    parser.add_argument("--overwrite", action="store_true",
                        help="replace an existing --can-log file")
    parser.add_argument("--duration", type=seconds, default=None, metavar="S",
                        help="stop after S seconds (default: until Ctrl-C)")
    parser.add_argument("--every", type=float, default=2.0, metavar="S",
                        help="print a status line every S seconds (0: only at the end)")
    args = parser.parse_args(argv)

    from drivers.mocks.autopilot import MockAutopilot
    from hil_bridge.files.config import read_text

    waypoints = None
    if args.waypoints is not None:
        delimiter = "," if args.waypoints.endswith(".csv") else None
        text = read_text(args.waypoints)
        if not text.strip():
            raise ValueError(f"{args.waypoints}: empty; expected rows of two columns x y")
        try:
            waypoints = np.loadtxt(text.splitlines(), delimiter=delimiter, ndmin=2)
        except ValueError as exc:
            raise ValueError(f"{args.waypoints}: expected two numeric columns x y "
                             f"({exc})") from None
        if waypoints.ndim != 2 or waypoints.shape[0] < 2 or waypoints.shape[1] != 2:
            raise ValueError(f"{args.waypoints}: expected at least 2 rows of two columns x y, "
                             f"got shape {waypoints.shape}")
        if not np.all(np.isfinite(waypoints)):
            row = int(np.argwhere(~np.isfinite(waypoints))[0][0])
            raise ValueError(f"{args.waypoints}: row {row + 1} is not finite")
    with use(domain_from(args, "echoloop mock autopilot")):
        mock = MockAutopilot(
            "mock_autopilot", interface=args.interface, channel=args.channel,
            bitrate=args.bitrate, gliders=args.gliders, controller=args.controller, law=args.law,
            rate_hz=args.rate, waypoints=waypoints, path_airspeed_mps=args.path_airspeed,
            lookahead_m=args.lookahead, can_log=args.can_log, overwrite=args.overwrite,
        )
    done = threading.Event()
    try:
        mock.start()
        print(f"mock autopilot on {args.interface}:{mock.bus_config.channel}, nodes "
              f"{list(mock.nodes)}, "
              f"controller {args.controller}, {mock.rate_hz:g} Hz", flush=True)
        t_end = None if args.duration is None else time.monotonic() + args.duration
        while True:
            left = None if t_end is None else t_end - time.monotonic()
            if left is not None and left <= 0:
                break
            step = args.every if args.every > 0 else 3600.0
            done.wait(step if left is None else min(step, left))
            if args.every > 0:
                st = mock.stats()
                print("  ".join(f"{k}={_fmt(st.get(k, 0))}" for k in _STATUS_KEYS), flush=True)
    except KeyboardInterrupt:
        pass
    finally:
        mock.stop()
    st = mock.stats()
    print("summary: " + ", ".join(f"{k}={_fmt(v)}" for k, v in sorted(st.items())))
    return 0
