"""``echoloop bus``: run the XSUB/XPUB bus proxy alone (multi-host set-ups), or make CURVE keys.

    echoloop bus                                   # tcp://127.0.0.1:7400 (pub) / :7401 (sub)
    echoloop bus --domain 3                        # domain 3: tcp://127.0.0.1:7430 / :7431
    echoloop bus --pub tcp://0.0.0.0:7400 --curve-keys keys/   # off loopback: CURVE required
    echoloop bus --keygen keys/ --clients sim,viewer           # write server + client key pairs
"""

from __future__ import annotations

import argparse
import signal
import threading
from types import FrameType

from hil_bridge.bus.proxy import Proxy
from hil_bridge.bus.security import CurveKeys, generate_keys
from hil_bridge.bus.transport.zmq import parse_zmq_url
from hil_bridge.cli._args import add_domain_argument, domain_from


def main(argv: list[str]) -> int:
    parser = argparse.ArgumentParser(prog="echoloop bus", description=__doc__,
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--pub", default=None,
                        help="publish endpoint (XSUB) to bind (default: the domain's bus, "
                             "tcp://127.0.0.1:7400 in domain 0)")
    add_domain_argument(parser)
    parser.add_argument("--sub", default=None,
                        help="subscribe endpoint (XPUB) to bind (default: pub port + 1)")
    parser.add_argument("--curve-keys", metavar="DIR", default=None,
                        help="CURVE key directory (server.key_secret + authorized/*.key)")
    parser.add_argument("--hwm", type=int, default=1000, help="queue bound per peer (messages)")
    parser.add_argument("--keygen", metavar="DIR", default=None,
                        help="write a server key pair and client key pairs into DIR, then exit")
    parser.add_argument("--clients", default="client",
                        help="comma-separated client names for --keygen (default %(default)s)")
    parser.add_argument("--overwrite", action="store_true",
                        help="--keygen: replace existing key files")
    args = parser.parse_args(argv)

    if args.keygen is not None:
        names = [n for n in args.clients.split(",") if n]
        root = generate_keys(args.keygen, names, overwrite=args.overwrite)
        print(f"wrote CURVE keys to {root}: server.key(_secret), "
              + ", ".join(f"{n}.key(_secret)" for n in names) + "; authorized/ holds the clients")
        return 0

    if args.pub is None:
        args.pub = domain_from(args, "echoloop bus").bus_url
    sub = args.sub if args.sub is not None else parse_zmq_url(args.pub).sub
    curve = CurveKeys.from_dir(args.curve_keys) if args.curve_keys is not None else None
    stop = threading.Event()

    def on_signal(signum: int, frame: FrameType | None) -> None:
        stop.set()

    signal.signal(signal.SIGTERM, on_signal)
    signal.signal(signal.SIGINT, on_signal)
    with Proxy(args.pub, sub, curve=curve, hwm=args.hwm) as proxy:
        security = f"CURVE, {len(curve.allowed)} allowed client keys" if curve else "no CURVE"
        print(f"bus proxy: publish {proxy.pub_endpoint}, subscribe {proxy.sub_endpoint} "
              f"({security}); clients use {proxy.url}", flush=True)
        while not stop.wait(0.5):
            if not proxy.running:
                raise OSError(f"proxy thread ended: {proxy.error}")
        if curve is not None:
            print(f"bus proxy: {proxy.stats()}")
    return 0
