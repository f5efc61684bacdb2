"""Isolation under load: a flood of malformed messages on one topic is dropped and counted
before it queues, cannot hold back another topic, and is logged once per topic per interval.

Every assertion counts messages; none measures time."""

from __future__ import annotations

import itertools
import logging
import threading
from collections.abc import Iterator
from typing import Any

import pytest

from hil_bridge.bus.codec import encode
from hil_bridge.bus.messages import Clock, GliderState
from hil_bridge.bus.node import Node
from hil_bridge.bus.proxy import Proxy
from hil_bridge.bus.qos import SENSOR, QoSProfile
from hil_bridge.bus.transport import open_transport
from hil_bridge.errors import SecurityError
from hil_bridge.tools.flood import flood, malformed_messages
from tests.hil_bridge.bus.bus_test_util import WAIT, poll_until

FLOODED = "/glider/0/state"
_names = itertools.count()


@pytest.fixture(params=["mem", "zmq"])
def deep_bus(request: pytest.FixtureRequest) -> Iterator[str]:
    """A bus whose queues hold a whole flood, so no message is lost to a queue bound."""
    if request.param == "mem":
        yield f"mem://flood{next(_names)}?depth=100000"
        return
    with Proxy("tcp://127.0.0.1:0", "tcp://127.0.0.1:0", hwm=100_000) as proxy:
        yield f"{proxy.url}&hwm=100000"


def _three_frame_garbage(n: int) -> list[list[bytes]]:
    pool = [m for m in malformed_messages(FLOODED, 64) if len(m) == 3]
    return [pool[i % len(pool)] for i in range(n)]


def test_a_flood_on_one_topic_does_not_hold_back_the_clock(deep_bus: str) -> None:
    """20000 malformed messages queue on /glider/0/state before one /clock message: the node
    delivers the clock long before it has worked through the flood (at most a thread switch
    of the interpreter later, not after the backlog), then counts every flood message."""
    n = 20_000
    url = deep_bus
    at_clock: list[int] = []
    with Node("adapter", bus=url, diagnostics_period_s=0) as node, open_transport(url) as raw:
        node.create_subscription(GliderState, FLOODED, lambda m: None)

        def on_clock(msg: Clock) -> None:
            at_clock.append(node.stats()["topics"][FLOODED]["decode_errors"])

        node.create_subscription(Clock, "/clock", on_clock, priority=True)
        assert raw.wait_for_subscriber(FLOODED, WAIT)
        assert raw.wait_for_subscriber("/clock", WAIT)
        for frames in _three_frame_garbage(n):
            raw.publish(frames)
        raw.publish(encode("/clock", Clock(stamp_ns=1), seq=0, pub_ns=0, src="server"))
        node.start()
        assert poll_until(lambda: bool(at_clock))
        assert poll_until(lambda: node.stats()["decode_errors"] == n)
    assert at_clock[0] < n // 2, f"the clock waited for {at_clock[0]} of {n} flood messages"
    counters = node.stats()["topics"][FLOODED]
    assert counters["received"] == 0 and counters["dropped"] == 0  # rejected before queueing


def test_flood_is_counted_and_logged_once_per_topic(deep_bus: str,
                                                    caplog: pytest.LogCaptureFixture) -> None:
    n = 2000
    url = deep_bus
    got: list[GliderState] = []
    caplog.set_level(logging.WARNING, logger="hil_bridge.bus.node")
    with Node("victim", bus=url, diagnostics_period_s=0) as node, open_transport(url) as raw:
        node.start()
        node.create_subscription(GliderState, FLOODED, got.append)
        assert raw.wait_for_subscriber(FLOODED, WAIT)
        garbage = _three_frame_garbage(n)
        for i, frames in enumerate(garbage):
            raw.publish(frames)
            if i % 500 == 499:  # real states in the middle of the flood still get through
                state = GliderState(stamp_ns=i, x=float(i), y=0.0, z=0.0, heading=0.0,
                                    bank=0.0, airspeed=10.0, vz=0.0)
                raw.publish(encode(FLOODED, state, seq=i // 500, pub_ns=i, src="server"))
        assert poll_until(lambda: node.stats()["decode_errors"] == n and len(got) == 4)
    lines = [r for r in caplog.records if FLOODED in r.getMessage()]
    assert 1 <= len(lines) <= 2, [r.getMessage() for r in lines]  # not one per message
    assert not any(r.exc_info for r in caplog.records)  # and never a traceback


def test_priority_callbacks_run_before_queued_sensor_data(bus_url: str) -> None:
    release = threading.Event()
    order: list[str] = []

    def on_state(msg: GliderState) -> None:
        order.append(f"state{int(msg.x)}")
        if msg.x == 0:
            release.wait(WAIT)

    with Node("adapter", bus=bus_url, diagnostics_period_s=0) as node, \
            Node("server", bus=bus_url, diagnostics_period_s=0) as srv:
        node.start()
        srv.start()
        node.create_subscription(GliderState, "/glider/1/neighbors_like", on_state, SENSOR)
        node.create_subscription(Clock, "/clock", lambda m: order.append("clock"),
                                 priority=True)
        states = srv.create_publisher(GliderState, "/glider/1/neighbors_like")
        clock = srv.create_publisher(Clock, "/clock")
        assert states.wait_for_subscribers(WAIT) and clock.wait_for_subscribers(WAIT)
        for i in range(4):
            states.publish(GliderState(stamp_ns=i, x=float(i), y=0.0, z=0.0, heading=0.0,
                                       bank=0.0, airspeed=10.0, vz=0.0))
        assert poll_until(lambda: order == ["state0"])  # the executor is held in state0

        def received(topic: str) -> int:
            return int(node.stats()["topics"][topic]["received"])

        assert poll_until(lambda: received("/glider/1/neighbors_like") == 4)
        clock.publish(Clock(stamp_ns=1))
        assert poll_until(lambda: received("/clock") == 1)
        release.set()
        assert poll_until(lambda: len(order) == 5)
    assert order == ["state0", "clock", "state1", "state2", "state3"]


def test_the_flood_tool_stays_on_loopback_and_within_its_bounds() -> None:
    with pytest.raises(SecurityError, match="not a loopback endpoint"):
        flood("tcp://10.1.2.3:7400", FLOODED, rate_hz=10, count=10, duration_s=1)
    with pytest.raises(ValueError, match="count"):
        flood("tcp://127.0.0.1:7400", FLOODED, rate_hz=10, count=0, duration_s=1)
    with pytest.raises(ValueError, match="duration_s"):
        flood("tcp://127.0.0.1:7400", FLOODED, rate_hz=10, count=10, duration_s=1e6)
    kinds: set[Any] = {len(m) for m in malformed_messages(FLOODED, 9)}
    assert kinds == {2, 3, 4}


def test_the_flood_tool_over_zeromq_every_message_is_counted() -> None:
    n = 3000
    with Proxy("tcp://127.0.0.1:0", "tcp://127.0.0.1:0", hwm=100_000) as proxy:
        url = f"{proxy.url}&hwm=100000"
        with Node("victim", bus=url, diagnostics_period_s=0) as node:
            node.start()
            node.create_subscription(GliderState, FLOODED, lambda m: None)
            result = flood(url, FLOODED, rate_hz=1e9, count=n, duration_s=60)
            assert result.sent == n
            assert poll_until(lambda: node.stats()["decode_errors"] == n)


def test_stale_messages_are_dropped_and_their_backlog_reset(deep_bus: str) -> None:
    """A subscription with ``max_age_s`` never delivers a message older than that in sim time
    (the node's clock); meeting one drops the backlog queued behind it, and fresh messages
    flow again at once."""
    from hil_bridge.bus.clock import SimClock
    from hil_bridge.bus.qos import QoSProfile

    clock = SimClock("lockstep")
    clock.set_ns(10_000_000_000)  # sim time 10 s
    got: list[GliderState] = []
    fresh_qos = QoSProfile("state", max_age_s=0.1)

    def state(stamp_ns: int, x: float) -> GliderState:
        return GliderState(stamp_ns=stamp_ns, x=x, y=0.0, z=0.0, heading=0.0, bank=0.0,
                           airspeed=10.0, vz=0.0)

    with Node("adapter", bus=deep_bus, clock=clock, diagnostics_period_s=0) as node, \
            open_transport(deep_bus) as raw:
        node.create_subscription(GliderState, FLOODED, got.append, fresh_qos)
        assert raw.wait_for_subscriber(FLOODED, WAIT)
        for i in range(500):  # a backlog from 2 s of sim time ago
            raw.publish(encode(FLOODED, state(8_000_000_000 + i, -1.0), seq=i, pub_ns=i,
                               src="server"))
        node.start()
        assert poll_until(lambda: node.stats()["topics"][FLOODED]["stale"] >= 1)
        counters = node.stats()["topics"][FLOODED]
        assert counters.get("queue_resets", 0) >= 1 and counters["received"] == 0
        # over ZeroMQ the reset re-made the topic's socket: publish until it is joined again
        for i in range(200):
            raw.publish(encode(FLOODED, state(10_000_000_000 + i, float(i)), seq=1000 + i,
                               pub_ns=i, src="server"))
            if poll_until(lambda: len(got) >= 3, timeout=0.05):
                break
        assert len(got) >= 3
    assert all(m.x >= 0 for m in got)  # nothing stale ever reached the callback
    assert node.stats()["topics"][FLOODED]["stale"] < 500  # the reset dropped the rest unread


def test_transport_queues_per_prefix_are_served_in_turn(deep_bus: str) -> None:
    """Transport contract 3: a backlog under one prefix does not hold back another."""
    n = 20_000
    with open_transport(deep_bus) as pub, open_transport(deep_bus) as sub:
        sub.subscribe(b"/flood\0")
        sub.subscribe(b"/clock\0")
        assert pub.wait_for_subscriber("/flood", WAIT) and pub.wait_for_subscriber("/clock", WAIT)
        for i in range(n):
            pub.publish(encode("/flood", Clock(stamp_ns=i), seq=i, pub_ns=0, src="p"))
        pub.publish(encode("/clock", Clock(stamp_ns=0), seq=0, pub_ns=0, src="p"))
        topics = []
        while len(topics) < n + 1 and (frames := sub.recv(timeout=WAIT)) is not None:
            topics.append(frames[0])
    assert len(topics) == n + 1
    assert topics.index(b"/clock\0") < n // 2, "the clock waited behind the backlog"


def test_subscriptions_sharing_a_lane_keep_their_order(deep_bus: str) -> None:
    """Topics whose order matters (a state and the neighbour list of its step) share a lane:
    their callbacks run in publishing order, even from a backlog."""
    order: list[tuple[str, int]] = []
    release = threading.Event()

    def on(kind: str) -> Any:
        def callback(msg: Any) -> None:
            order.append((kind, msg.stamp_ns))
            if not release.is_set():
                release.wait(WAIT)
        return callback

    with Node("adapter", bus=deep_bus, diagnostics_period_s=0) as node, \
            Node("server", bus=deep_bus, diagnostics_period_s=0) as srv:
        node.start()
        srv.start()
        deep = QoSProfile("deep", depth=100)
        node.create_subscription(Clock, "/glider/0/neighbors_like", on("nb"), deep,
                                 lane="glider0")
        node.create_subscription(Clock, "/glider/0/state_like", on("state"), deep,
                                 priority=True, lane="glider0")
        nbs = srv.create_publisher(Clock, "/glider/0/neighbors_like")
        states = srv.create_publisher(Clock, "/glider/0/state_like")
        assert nbs.wait_for_subscribers(WAIT) and states.wait_for_subscribers(WAIT)
        for step in range(20):  # the first callback holds the executor: the rest queue up
            nbs.publish(Clock(stamp_ns=step))
            states.publish(Clock(stamp_ns=step))
        assert poll_until(lambda: node.stats()["received"] == 40)
        release.set()
        assert poll_until(lambda: len(order) == 40)
    assert order == [(kind, step) for step in range(20) for kind in ("nb", "state")]
