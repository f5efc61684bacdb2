"""A bounded flood of malformed bus messages on one topic, on loopback only (fault injection).

``flood(url, topic, rate_hz=..., count=..., duration_s=...)`` publishes malformed messages
whose topic frame is ``topic`` (so they pass every subscription to it) through the bus proxy of
a ``tcp://`` or ``ipc://`` bus URL, paced at ``rate_hz``, until ``count`` messages or
``duration_s`` seconds, whichever comes first. Both bounds are required and capped
(:data:`MAX_COUNT`, :data:`MAX_DURATION_S`); a URL that is not loopback (``ipc://`` or a
``tcp://`` loopback address) is refused with :class:`~hil_bridge.errors.SecurityError`.
Also runs alone: ``python -m hil_bridge.tools.flood --bus URL --topic /glider/0/state --rate 25000
--duration 20``.

The messages (:func:`malformed_messages`, drawn from a seeded generator) cycle through every
way a frame can be wrong: a header that is not msgpack, not a map or misses keys; a valid header
with a payload that is not msgpack, misses fields, has a malformed array, or is of another type
than the topic's; two or four frames instead of three.
"""

from __future__ import annotations

import argparse
import math
import sys
import time
from collections.abc import Sequence
from dataclasses import dataclass

import msgpack
import numpy as np
import zmq

from hil_bridge.bus.codec import Header, encode, pack_header
from hil_bridge.bus.messages import Clock
from hil_bridge.bus.security import is_loopback_endpoint
from hil_bridge.bus.transport.zmq import parse_zmq_url
from hil_bridge.errors import SecurityError

__all__ = ["MAX_COUNT", "MAX_DURATION_S", "FloodResult", "flood", "main", "malformed_messages"]

#: the most messages one flood may send
MAX_COUNT = 50_000_000
#: the longest a flood may last, seconds
MAX_DURATION_S = 600.0
_KINDS = 9


def malformed_messages(topic: str, n: int, *, seed: int = 0) -> list[list[bytes]]:
    """``n`` malformed messages on ``topic``, every kind of fault in turn (module docstring)."""
    rng = np.random.default_rng(seed)
    frame = topic.encode() + b"\0"
    good = encode(topic, Clock(stamp_ns=1), seq=0, pub_ns=0, src="flood")
    state_header = pack_header(Header("echoloop/GliderState", 1, 0, 0, 0, "", "flood"))
    out: list[list[bytes]] = []
    for i in range(n):
        noise = rng.bytes(int(rng.integers(1, 48)))
        kind = i % _KINDS
        if kind == 0:
            msg = [frame, b"\xc1" + noise, good[2]]
        elif kind == 1:
            msg = [frame, msgpack.packb([1, 2, 3]), good[2]]
        elif kind == 2:
            msg = [frame, msgpack.packb({"type": "echoloop/GliderState", "v": 1}), good[2]]
        elif kind == 3:
            msg = [frame, state_header, b"\xc1" + noise]
        elif kind == 4:
            msg = [frame, state_header, msgpack.packb({"x": "not a number"})]
        elif kind == 5:
            bad = {"dtype": "<f4", "shape": [1 << 40], "data": noise}
            msg = [frame, pack_header(Header("echoloop/GliderNeighbors", 1, i, 0, 0, "",
                                             "flood")),
                   msgpack.packb({"glider_id": 0, "ids": bad}, use_bin_type=True)]
        elif kind == 6:
            msg = [frame, good[1], good[2]]  # a Clock where the topic's type is another
        elif kind == 7:
            msg = [frame, noise]
        else:
            msg = [frame, good[1], good[2], noise]
        out.append(msg)
    return out


@dataclass(frozen=True, slots=True)
class FloodResult:
    """What a flood sent: messages, wall seconds, and the achieved rate (messages/s)."""

    sent: int
    seconds: float

    @property
    def rate_hz(self) -> float:
        return self.sent / self.seconds if self.seconds > 0 else 0.0


def _check(url: str, count: int, duration_s: float, rate_hz: float) -> str:
    ends = parse_zmq_url(url)
    if not is_loopback_endpoint(ends.pub):
        raise SecurityError(f"flood: {ends.pub} is not a loopback endpoint; floods stay on "
                            "this machine (tcp://127.0.0.1:PORT or ipc://PATH)")
    if not 0 < count <= MAX_COUNT:
        raise ValueError(f"flood: count must be in 1..{MAX_COUNT}, got {count}")
    if not 0 < duration_s <= MAX_DURATION_S:
        raise ValueError(f"flood: duration_s must be in (0, {MAX_DURATION_S}], got {duration_s}")
    if not (math.isfinite(rate_hz) and rate_hz > 0):
        raise ValueError(f"flood: rate_hz must be a finite number > 0, got {rate_hz}")
    return ends.pub


def flood(
    url: str, topic: str, *, rate_hz: float, count: int, duration_s: float, seed: int = 0,
    subscriber_timeout_s: float = 5.0,
) -> FloodResult:
    """Publish malformed messages on ``topic`` (module docstring); returns what was sent.

    Waits up to ``subscriber_timeout_s`` for a subscription covering ``topic`` to reach the
    flooding socket first, so the flood is not lost to ZeroMQ's slow-joiner window.
    """
    pub_endpoint = _check(url, count, duration_s, rate_hz)
    pool = malformed_messages(topic, 512, seed=seed)
    frame = topic.encode() + b"\0"
    ctx: zmq.Context[zmq.Socket[bytes]] = zmq.Context.instance()
    sock = ctx.socket(zmq.XPUB)
    try:
        sock.linger = 0
        sock.sndhwm = 100_000
        sock.setsockopt(zmq.XPUB_VERBOSE, 1)
        sock.connect(pub_endpoint)
        deadline = time.monotonic() + subscriber_timeout_s
        while time.monotonic() < deadline:
            if sock.poll(50, zmq.POLLIN):
                event = sock.recv()
                if event[:1] == b"\x01" and frame.startswith(event[1:]):
                    break
        t0 = time.monotonic()
        end = t0 + duration_s
        sent = 0
        while sent < count:
            now = time.monotonic()
            if now >= end:
                break
            due = min(count, int((now - t0) * rate_hz) + 1)
            while sent < due:
                sock.send_multipart(pool[sent % len(pool)])
                sent += 1
            time.sleep(min(0.001, max(0.0, end - time.monotonic())))
        return FloodResult(sent, time.monotonic() - t0)
    finally:
        sock.close(linger=1000)


def main(argv: Sequence[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="python -m hil_bridge.tools.flood", description=__doc__,
                                formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--bus", required=True, help="tcp://127.0.0.1:PORT or ipc://PATH")
    p.add_argument("--topic", required=True)
    p.add_argument("--rate", type=float, required=True, help="messages per second")
    p.add_argument("--duration", type=float, required=True, help="seconds (<= 600)")
    p.add_argument("--count", type=int, default=MAX_COUNT, help="at most this many messages")
    p.add_argument("--seed", type=int, default=0)
    args = p.parse_args(sys.argv[1:] if argv is None else argv)
    result = flood(args.bus, args.topic, rate_hz=args.rate, count=args.count,
                   duration_s=args.duration, seed=args.seed)
    sys.stdout.write(f"sent {result.sent} malformed messages on {args.topic} in "
                     f"{result.seconds:.2f} s ({result.rate_hz:.0f}/s)\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
