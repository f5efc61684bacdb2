"""``echoloop topic list|echo|hz|bw|info``: inspect live topics (like ``ros2 topic``).

    echoloop topic list [--duration 2]                 # topics heard, with types and rates
    echoloop topic echo /glider/0/state [--count 5] [--header] [--json] [--full-arrays]
    echoloop topic hz /glider/0/state [--duration 10]  # rate from stamps, gaps from seq jumps
    echoloop topic bw /sonar/0/echo
    echoloop topic info /glider/0/state                # type, publishers, frame ids, rate

Every command listens passively on the bus (``--bus``, default the domain's: ``--domain`` or
``ECHOLOOP_DOMAIN``, tcp://127.0.0.1:7400 in domain 0) for ``--duration`` seconds (Ctrl-C ends
earlier); latched topics answer at once.
"""

from __future__ import annotations

import argparse
import json
import time
from typing import Any

import numpy as np

from hil_bridge.bus.codec import Header, decode_payload, payload_to_jsonable, validate_topic
from hil_bridge.bus.messages import Message
from hil_bridge.bus.stats import TopicStats
from hil_bridge.bus.transport import Frames
from hil_bridge.cli._args import add_domain_argument, domain_from, seconds
from hil_bridge.errors import CodecError
from hil_bridge.tools.topic import TopicMonitor


def _fmt(x: float | None, unit: str, scale: float = 1.0) -> str:
    return "-" if x is None else f"{x * scale:.2f} {unit}"


def _array_summary(arr: np.ndarray) -> str:
    if arr.size == 0:
        return f"<{arr.dtype.str} {list(arr.shape)} empty>"
    finite = arr[np.isfinite(arr)] if arr.dtype.kind in "fc" else arr
    if finite.size == 0:
        return f"<{arr.dtype.str} {list(arr.shape)} all non-finite>"
    return (f"<{arr.dtype.str} {list(arr.shape)} min {finite.min():.4g} "
            f"max {finite.max():.4g}>")


def _render(msg: Message, full_arrays: bool) -> dict[str, Any]:
    body = payload_to_jsonable(msg)
    if not full_arrays:
        for name in msg.ARRAYS:
            body[name] = _array_summary(getattr(msg, name))
    return body


def _list(args: argparse.Namespace) -> int:
    topics = TopicMonitor(args.bus).run(args.duration)
    if args.json:
        print(json.dumps({t: s.as_dict() for t, s in sorted(topics.items())}, indent=2))
        return 0
    if not topics:
        print(f"no messages heard on {args.bus} in {args.duration} s")
        return 0
    width = max(len(t) for t in topics)
    for topic, st in sorted(topics.items()):
        print(f"{topic:<{width}}  {','.join(sorted(st.types)):<26}  "
              f"{_fmt(st.recv_rate_hz, 'Hz'):>11}  {len(st.publishers)} publisher(s)")
    return 0


def _echo(args: argparse.Namespace) -> int:
    count = 0
    errors = 0

    def on_message(topic: str, header: Header, frames: Frames, st: TopicStats) -> None:
        nonlocal count, errors
        try:
            msg = decode_payload(header.type, header.v, frames[2])
        except CodecError as exc:
            errors += 1
            print(f"# undecodable message on {topic}: {exc}")
            return
        body = _render(msg, args.full_arrays)
        if args.header:
            body = {"header": {"type": header.type, "v": header.v, "seq": header.seq,
                               "stamp_ns": header.stamp_ns, "pub_ns": header.pub_ns,
                               "frame_id": header.frame_id, "src": header.src},
                    "msg": body}
        if args.json:
            print(json.dumps(body), flush=True)
        else:
            for key, value in body.items():
                print(f"{key}: {value}")
            print("---", flush=True)
        count += 1

    TopicMonitor(args.bus, args.topic + "\0").run(args.duration, on_message, args.count)
    if count == 0:
        print(f"# no message on {args.topic} in {args.duration} s")
    return 0


def _rates(args: argparse.Namespace, show: str) -> int:
    last_print = time.monotonic()

    def report(st: TopicStats) -> None:
        if show == "hz":
            iv = st.interval_summary() or {}
            print(f"rate {_fmt(st.rate_hz, 'Hz')} (sim), {_fmt(st.recv_rate_hz, 'Hz')} (recv); "
                  f"n={st.count} gaps={st.gaps} lost={st.lost} dup={st.duplicates}; "
                  f"interval min {_fmt(iv.get('min_s'), 'ms', 1e3)} "
                  f"max {_fmt(iv.get('max_s'), 'ms', 1e3)} "
                  f"std {_fmt(iv.get('std_s'), 'ms', 1e3)}", flush=True)
        else:
            mean = st.bytes / st.count if st.count else None
            print(f"bandwidth {_fmt(st.bandwidth_bps, 'kB/s', 1e-3)}; n={st.count} "
                  f"mean {_fmt(mean, 'B')}", flush=True)

    def on_message(topic: str, header: Header, frames: Frames, st: TopicStats) -> None:
        nonlocal last_print
        now = time.monotonic()
        if now - last_print >= args.every:
            last_print = now
            report(st)

    topics = TopicMonitor(args.bus, args.topic + "\0").run(args.duration, on_message)
    st = topics.get(args.topic)
    if st is None:
        print(f"no message on {args.topic} in {args.duration} s")
        return 0
    if args.json:
        print(json.dumps(st.as_dict(), indent=2))
    else:
        report(st)
    return 0


def _info(args: argparse.Namespace) -> int:
    topics = TopicMonitor(args.bus, args.topic + "\0").run(args.duration)
    st = topics.get(args.topic)
    if st is None:
        print(f"no message on {args.topic} in {args.duration} s")
        return 0
    if args.json:
        print(json.dumps(st.as_dict(), indent=2))
        return 0
    print(f"topic:      {args.topic}")
    print(f"type:       {', '.join(sorted(st.types))}")
    print(f"publishers: {', '.join(sorted(st.publishers))}")
    print(f"frame_ids:  {', '.join(repr(f) for f in sorted(st.frame_ids))}")
    print(f"messages:   {st.count} in {args.duration} s, rate {_fmt(st.rate_hz, 'Hz')}, "
          f"gaps {st.gaps}, lost {st.lost}")
    return 0


def main(argv: list[str]) -> int:
    parser = argparse.ArgumentParser(prog="echoloop topic", description=__doc__,
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    sub = parser.add_subparsers(dest="cmd", required=True)

    def common(p: argparse.ArgumentParser, duration: float | None) -> None:
        p.add_argument("--bus", default=None, help="bus URL (default: the domain's)")
        add_domain_argument(p)
        p.add_argument("--duration", type=seconds, default=duration,
                       help="seconds to listen (default %(default)s; none: until Ctrl-C)")
        p.add_argument("--json", action="store_true", help="machine-readable output")

    p = sub.add_parser("list", help="topics heard on the bus")
    common(p, 2.0)
    p.set_defaults(run=_list)
    p = sub.add_parser("echo", help="print messages of one topic")
    p.add_argument("topic", type=validate_topic)
    p.add_argument("--count", type=int, default=None, help="stop after N messages")
    p.add_argument("--header", action="store_true", help="also print the header")
    p.add_argument("--full-arrays", action="store_true", help="print arrays in full")
    common(p, None)
    p.set_defaults(run=_echo)
    for name, helptext in (("hz", "publishing rate, seq gaps"), ("bw", "bandwidth")):
        p = sub.add_parser(name, help=helptext)
        p.add_argument("topic", type=validate_topic)
        p.add_argument("--every", type=float, default=1.0, help="seconds between reports")
        common(p, None)
        p.set_defaults(run=lambda a, show=name: _rates(a, show))
    p = sub.add_parser("info", help="type, publishers, frame ids and rate of one topic")
    p.add_argument("topic", type=validate_topic)
    common(p, 2.0)
    p.set_defaults(run=_info)
    args = parser.parse_args(argv)
    if args.bus is None:
        args.bus = domain_from(args, "echoloop topic").bus_url
    return int(args.run(args))
