"""Nodes over both backends: delivery, QoS (latched, command), drops, decode errors, timers."""

from __future__ import annotations

import threading
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import pytest
import zmq

from hil_bridge.bus.clock import SimClock
from hil_bridge.bus.codec import Envelope, encode
from hil_bridge.bus.messages import Clock, Diagnostics, GliderCmd, GliderState
from hil_bridge.bus.node import Node
from hil_bridge.bus.proxy import Proxy
from hil_bridge.bus.qos import COMMAND, LATCHED, SENSOR, QoSProfile
from hil_bridge.bus.transport import open_transport
from hil_bridge.recording.recorder import Recorder
from tests.hil_bridge.bus.bus_test_util import poll_until

WAIT = 10.0


def _state(i: int) -> GliderState:
    return GliderState(stamp_ns=i * 4_000_000, x=float(i), y=0.0, z=100.0, heading=0.0,
                       bank=0.0, airspeed=9.0, vz=-0.5, glider_id=1)


class Collector:
    """Callback that records messages and lets a test wait for a count (no sleeping)."""

    def __init__(self) -> None:
        self.items: list[object] = []
        self._cond = threading.Condition()

    def __call__(self, item: object) -> None:
        with self._cond:
            self.items.append(item)
            self._cond.notify_all()

    def wait_for(self, n: int, timeout: float = WAIT) -> bool:
        with self._cond:
            return self._cond.wait_for(lambda: len(self.items) >= n, timeout)


def test_publish_subscribe_with_seq_stamps_and_stats(bus_url: str) -> None:
    got = Collector()
    with Node("talker", bus=bus_url) as a, Node("listener", bus=bus_url) as b:
        a.start()
        b.start()
        pub = a.create_publisher(GliderState, "/glider/1/state", frame_id="world")
        b.create_subscription(GliderState, "/glider/1/state", got, SENSOR, envelope=True)
        assert pub.wait_for_subscribers(WAIT)
        for i in range(3):
            assert pub.publish(_state(i)) == i
        assert got.wait_for(3)
        envs = [e for e in got.items if isinstance(e, Envelope)]
        assert [e.msg for e in envs] == [_state(i) for i in range(3)]
        assert [e.header.seq for e in envs] == [0, 1, 2]
        assert [e.header.stamp_ns for e in envs] == [0, 4_000_000, 8_000_000]
        assert {e.header.frame_id for e in envs} == {"world"}
        assert {e.header.src for e in envs} == {a.src}
        assert a.stats()["topics"]["/glider/1/state"]["sent"] == 3
        bs = b.stats()
        assert bs["received"] == 3 and bs["dropped"] == 0 and bs["decode_errors"] == 0


def test_late_joiner_gets_latched_value(bus_url: str) -> None:
    with Node("scene", bus=bus_url) as a:
        a.start()
        pub = a.create_publisher(Clock, "/scene/epoch", LATCHED)
        pub.publish(Clock(stamp_ns=1))
        pub.publish(Clock(stamp_ns=2))
        early = Collector()
        with Node("early", bus=bus_url) as e:
            e.start()
            e.create_subscription(Clock, "/scene/epoch", early, LATCHED)
            assert early.wait_for(1)
            late = Collector()
            with Node("late", bus=bus_url) as b:
                b.start()
                b.create_subscription(Clock, "/scene/epoch", late, LATCHED)
                assert late.wait_for(1)
                assert late.items == [Clock(stamp_ns=2)]
                assert b.stats()["topics"]["/scene/epoch"]["received"] == 1
            # the re-send for "late" reached "early" too and was dropped as a duplicate
            assert e.stats()["topics"]["/scene/epoch"]["received"] == 1
        assert early.items == [Clock(stamp_ns=2)]


def test_command_is_retransmitted_until_acked_and_delivered_once(bus_url: str) -> None:
    fast = QoSProfile("command", depth=10, reliable=True, retry_period_s=0.01, ack_timeout_s=30.0)
    with Node("pilot", bus=bus_url) as a:
        a.start()
        pub = a.create_publisher(GliderCmd, "/glider/0/cmd", fast)
        seq = pub.publish(GliderCmd(stamp_ns=0, bank_cmd=0.2, airspeed_cmd=10.0))
        assert not pub.wait_for_ack(seq, timeout=0.05)  # nobody listens yet: retransmitting
        got = Collector()
        with Node("sim", bus=bus_url) as b:
            b.start()
            b.create_subscription(GliderCmd, "/glider/0/cmd", got, COMMAND)
            assert pub.wait_for_ack(seq, timeout=WAIT)
            assert got.wait_for(1)
            seq2 = pub.publish(GliderCmd(stamp_ns=1, bank_cmd=-0.2, airspeed_cmd=9.0))
            assert pub.wait_for_ack(seq2, timeout=WAIT)
            assert got.wait_for(2)
            assert got.items == [
                GliderCmd(stamp_ns=0, bank_cmd=0.2, airspeed_cmd=10.0),
                GliderCmd(stamp_ns=1, bank_cmd=-0.2, airspeed_cmd=9.0),
            ]
        stats = a.stats()["topics"]["/glider/0/cmd"]
        assert stats["retransmits"] >= 1 and stats["acked"] == 2 and pub.pending == 0


def test_command_without_subscriber_fails_after_timeout(bus_url: str) -> None:
    short = QoSProfile("command", reliable=True, retry_period_s=0.01, ack_timeout_s=0.1)
    with Node("pilot", bus=bus_url) as a:
        a.start()
        pub = a.create_publisher(GliderCmd, "/glider/0/cmd", short)
        seq = pub.publish(GliderCmd(stamp_ns=0, bank_cmd=0.0, airspeed_cmd=9.0))
        assert not pub.wait_for_ack(seq, timeout=WAIT)
        assert pub.pending == 0
        assert a.stats()["topics"]["/glider/0/cmd"]["ack_failed"] == 1


@pytest.mark.parametrize("fast", [False, True], ids=["handed-on", "fast-mode"])
def test_slow_callback_never_blocks_publisher_and_drops_are_counted(
    bus_url: str, monkeypatch: pytest.MonkeyPatch, fast: bool
) -> None:
    """Reception goes on while a callback is stuck: the other worker leads at once (a low
    rate), or takes reception over after WATCH_S from the leader that runs the callback inline
    (fast mode; hil_bridge.bus.executor)."""
    from hil_bridge.bus import executor

    monkeypatch.setattr(executor, "FAST_RATE_HZ", 0.0 if fast else 1e12)
    release = threading.Event()
    got = Collector()

    def slow(msg: GliderState) -> None:
        release.wait(WAIT)
        got(msg)

    n = 300
    topic = "/glider/1/state"
    with Node("fast", bus=bus_url) as a, Node("slow", bus=bus_url) as b:
        a.start()
        b.start()
        pub = a.create_publisher(GliderState, topic)
        b.create_subscription(GliderState, topic, slow, SENSOR)
        assert poll_until(lambda: b._executor._watch == fast)
        assert pub.wait_for_subscribers(WAIT)
        for i in range(n):  # returns while the callback is still blocked
            pub.publish(_state(i))
        assert not release.is_set()
        # reception went on while the executor was stuck in the callback
        assert poll_until(lambda: b.stats()["topics"][topic]["received"] == n)
        release.set()
        assert poll_until(lambda: any(m.x == n - 1 for m in got.items))  # type: ignore[attr-defined]
        stats = b.stats()["topics"][topic]
        delivered = len(got.items)
        assert delivered <= SENSOR.depth + 1  # keep-last: the one in the callback + depth
        assert stats["dropped"] == n - delivered


@pytest.mark.parametrize("fast", [False, True], ids=["handed-on", "fast-mode"])
def test_two_subscriptions_of_a_topic_get_every_message_in_order(
    bus_url: str, monkeypatch: pytest.MonkeyPatch, fast: bool
) -> None:
    """A message's deliveries run inline together (hil_bridge.bus.executor), in subscription
    order, whether the leader hands leadership on or keeps it."""
    from hil_bridge.bus import executor

    monkeypatch.setattr(executor, "FAST_RATE_HZ", 0.0 if fast else 1e12)
    seen: list[tuple[str, int]] = []
    lock = threading.Lock()

    def record(name: str) -> Callable[[GliderState], None]:
        def cb(msg: GliderState) -> None:
            with lock:
                seen.append((name, int(msg.x)))
        return cb

    n = 50
    topic = "/glider/2/state"
    with Node("pub", bus=bus_url) as a, Node("sub", bus=bus_url) as b:
        a.start()
        b.start()
        pub = a.create_publisher(GliderState, topic)
        b.create_subscription(GliderState, topic, record("first"), SENSOR)
        b.create_subscription(GliderState, topic, record("second"), SENSOR)
        assert poll_until(lambda: b._executor._watch == fast)
        assert pub.wait_for_subscribers(WAIT)
        for i in range(n):
            pub.publish(_state(i))
            time.sleep(0.001)
        assert poll_until(lambda: len(seen) >= 2 * n)
    assert [x for name, x in seen if name == "first"] == list(range(n))
    assert [x for name, x in seen if name == "second"] == list(range(n))
    assert all(seen[2 * i] == ("first", i) and seen[2 * i + 1] == ("second", i)
               for i in range(n))


def test_decode_errors_are_counted_and_reception_goes_on(bus_url: str) -> None:
    got = Collector()
    with Node("victim", bus=bus_url) as b, open_transport(bus_url) as raw:
        b.start()
        b.create_subscription(Clock, "/clock", got)
        assert raw.wait_for_subscriber("/clock", WAIT)
        good = encode("/clock", Clock(stamp_ns=1), seq=0, pub_ns=0, src="raw")
        raw.publish([good[0], b"\xc1garbage", good[2]])
        raw.publish([good[0], good[1], b"\x93\x01"])
        wrong = encode("/clock", _state(0), seq=1, pub_ns=0, src="raw")
        raw.publish(wrong)
        newer = encode("/clock", Clock(stamp_ns=2), seq=2, pub_ns=0, src="raw")
        raw.publish([newer[0], newer[1].replace(b"\xa1v\x01", b"\xa1v\x09"), newer[2]])
        raw.publish(encode("/clock", Clock(stamp_ns=3), seq=3, pub_ns=0, src="raw"))
        assert got.wait_for(1)
        assert got.items == [Clock(stamp_ns=3)]
        assert b.stats()["topics"]["/clock"]["decode_errors"] == 4


def test_callback_errors_are_counted_not_fatal(bus_url: str) -> None:
    got = Collector()

    def flaky(msg: Clock) -> None:
        if msg.stamp_ns == 0:
            raise RuntimeError("boom")
        got(msg)

    with Node("n", bus=bus_url) as a:
        a.start()
        pub = a.create_publisher(Clock, "/c")
        a.create_subscription(Clock, "/c", flaky)
        assert pub.wait_for_subscribers(WAIT)
        pub.publish(Clock(stamp_ns=0))
        pub.publish(Clock(stamp_ns=1))
        assert got.wait_for(1)
        assert a.stats()["callback_errors"] == 1
        # counted, and a failure of the node naming the place (the launch run exits 1)
        assert a.failure() == "callback /c: RuntimeError: boom"
        assert a.faults.counts() == {"callback /c": 1} and a.stats()["faults"] == 1


def test_a_timer_that_raises_is_a_failure_naming_it(bus_url: str) -> None:
    clock = SimClock("lockstep")
    fired = Collector()

    def tick() -> None:
        fired(clock.now_ns())
        raise ValueError("bad tick")

    with Node("ticker", bus=bus_url, clock=clock) as a:
        a.start()
        a.create_timer(0.004, tick)
        clock.advance(4_000_000)
        assert fired.wait_for(1)
        assert poll_until(lambda: a.failure() is not None)
        failure = a.failure()
        assert failure is not None and failure.startswith("timer ")
        assert "tick" in failure and failure.endswith("ValueError: bad tick")
        assert a.stats()["topics"]["/timers"]["callback_errors"] >= 1


def test_a_node_shares_the_faults_it_is_given(bus_url: str) -> None:
    from hil_bridge.bus.faults import Faults

    faults = Faults("owner")
    with Node("inner", bus=bus_url, faults=faults) as a:
        assert a.faults is faults
        faults.report("tick loop", RuntimeError("x"))
        assert a.failure() == "tick loop: RuntimeError: x"


def test_timers_follow_a_lockstep_clock(bus_url: str) -> None:
    clock = SimClock("lockstep")
    fired = Collector()
    with Node("stepper", bus=bus_url, clock=clock) as a:
        a.start()
        timer = a.create_timer(0.004, lambda: fired(clock.now_ns()))
        for step in range(1, 6):
            clock.advance(4_000_000)
            assert fired.wait_for(step)
        assert fired.items == [4_000_000 * k for k in range(1, 6)]
        clock.advance(3 * 4_000_000)  # a jump over 3 periods fires once, 2 overruns
        assert fired.wait_for(6)
        assert timer.overruns == 2 and a.stats()["timer_overruns"] == 2
        timer.cancel()


def test_diagnostics_are_published_and_stop_is_idempotent(bus_url: str) -> None:
    diags = Collector()
    with Node("watch", bus=bus_url) as w:
        w.start()
        w.create_subscription(Diagnostics, "/diagnostics", diags)
        node = Node("busy", bus=bus_url, diagnostics_period_s=0.01)
        node.start()
        assert poll_until(lambda: any(
            isinstance(d, Diagnostics) and d.node == "busy" for d in diags.items))
        threads = [t for t in threading.enumerate() if t.name in ("busy-w0", "busy-w1")]
        assert len(threads) == 2
        node.stop()
        node.stop()
        assert not any(t.is_alive() for t in threads)
        assert node.transport.closed
        sample = next(d for d in diags.items if isinstance(d, Diagnostics) and d.node == "busy")
        assert {"sent", "received", "dropped", "decode_errors"} <= set(sample.counters)


def test_diagnostics_are_made_of_counters_not_stats(bus_url: str) -> None:
    """A node whose ``stats()`` summarises samples gives ``/diagnostics`` its ``counters()``:
    the summaries never run on the executor that the node's callbacks run on."""

    class Summarising(Node):
        stats_calls = 0

        def counters(self) -> dict[str, Any]:
            return super().stats() | {"cheap": 7}

        def stats(self) -> dict[str, Any]:
            Summarising.stats_calls += 1
            return self.counters() | {"latency_ms": {"p99": 1.0}}

    diags = Collector()
    with Node("watch", bus=bus_url) as w:
        w.start()
        w.create_subscription(Diagnostics, "/diagnostics", diags)
        with Summarising("summing", bus=bus_url, diagnostics_period_s=0.01) as node:
            node.start()
            assert poll_until(lambda: sum(
                isinstance(d, Diagnostics) and d.node == "summing" for d in diags.items) >= 3)
            assert Summarising.stats_calls == 0
            assert node.stats()["latency_ms"] == {"p99": 1.0}
    sample = next(d for d in diags.items if isinstance(d, Diagnostics) and d.node == "summing")
    assert sample.counters["cheap"] == 7 and "sent" in sample.counters


def test_bad_arguments_are_rejected(bus_url: str) -> None:
    with Node("n", bus=bus_url) as a:
        for bad in ("", "has space", "a/b"):
            with pytest.raises(ValueError, match="node name"):
                Node(bad, bus="mem://never_opened")
        with pytest.raises(ValueError, match="invalid topic"):
            a.create_publisher(Clock, "clock")
        with pytest.raises(TypeError, match="registered message class"):
            a.create_subscription(dict, "/x", print)  # type: ignore[type-var]
        with pytest.raises(ValueError, match="unknown QoS profile"):
            a.create_publisher(Clock, "/x", "bogus")
        pub = a.create_publisher(Clock, "/x")
        with pytest.raises(TypeError, match="sends Clock"):
            pub.publish(_state(0))  # type: ignore[arg-type]
        with pytest.raises(ValueError, match="period"):
            a.create_timer(0.0, lambda: None)


def test_timers_follow_a_realtime_clock_with_a_rate() -> None:
    clock = SimClock("realtime", rate=100.0)  # 0.1 s of sim time per 1 ms of wall time
    fired = Collector()
    with Node("rt", bus="mem://rt_timer", clock=clock) as node:
        node.start()
        t0 = clock.now_ns()
        node.create_timer(0.1, lambda: fired(clock.now_ns()))
        assert fired.wait_for(5)
    # fixed-rate: the k-th firing is never before t0 + k periods (late ones do not shift the grid)
    due = [t0 + k * 100_000_000 for k in range(1, 6)]
    assert all(stamp >= d for stamp, d in zip(fired.items[:5], due, strict=True))  # type: ignore[operator]


def test_foreign_messages_with_a_wrong_frame_count_are_counted_not_fatal(
    tmp_path: Path,
) -> None:
    """A raw ZeroMQ publisher on the proxy may send any number of frames: nodes and the
    recorder drop such messages as decode errors and keep receiving."""
    got = Collector()
    with Proxy("tcp://127.0.0.1:0", "tcp://127.0.0.1:0") as proxy, \
            Node("victim", bus=proxy.url) as node, \
            zmq.Context.instance().socket(zmq.PUB) as raw:
        rec = Recorder(tmp_path / "r.mcap", ["/clock"], bus=proxy.url)
        rec.start()
        try:
            node.create_subscription(Clock, "/clock", got)
            node.start()
            raw.connect(proxy.pub_endpoint)
            good = encode("/clock", Clock(stamp_ns=1), seq=0, pub_ns=0, src="raw")

            def dropped_by_both() -> bool:
                raw.send_multipart(good[:2])
                return (node.stats()["topics"]["/clock"]["decode_errors"] > 0
                        and rec.stats()["decode_errors"] > 0)

            assert poll_until(dropped_by_both)
            raw.send_multipart(good)
            assert got.wait_for(1) and rec.wait_for(1, WAIT)
            assert got.items == [Clock(stamp_ns=1)] and rec.error is None
        finally:
            rec.stop()
