"""Sequence accounting: forged, wrapped and restarted sequences never freeze a stream."""

from __future__ import annotations

import threading
from typing import Any

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from hil_bridge.bus import intra
from hil_bridge.bus.codec import encode
from hil_bridge.bus.messages import Clock, GliderCmd, GliderState
from hil_bridge.bus.node import Node
from hil_bridge.bus.qos import COMMAND, LATCHED, SENSOR, QoSProfile
from hil_bridge.bus.seq import MAX_GAP, SeqTracker, Verdict
from hil_bridge.bus.transport import open_transport
from tests.hil_bridge.bus.bus_test_util import WAIT, poll_until

U64 = (1 << 64) - 1


def test_in_order_gaps_and_true_duplicates() -> None:
    t = SeqTracker()
    assert [t.observe("a", s, s, s) for s in (0, 1, 2)] == [Verdict.NEXT] * 3
    assert t.observe("a", 6, 6, 6) is Verdict.GAP
    assert (t.gaps, t.lost) == (1, 3)
    assert t.observe("a", 6, 6, 6) is Verdict.DUPLICATE  # a latched re-send, byte for byte
    assert t.observe("b", 6, 0, 0) is Verdict.NEXT  # publishers are counted apart
    assert (t.duplicates, t.epochs) == (1, 0)


@pytest.mark.parametrize("forged", [U64, 0, 3, 1 << 40], ids=["max", "zero", "back", "jump"])
def test_a_forged_value_costs_no_real_message(forged: int) -> None:
    t = SeqTracker()
    for s in range(10):
        t.observe("srv", s, s, 100 + s)
    assert t.observe("srv", forged, 0, 1).delivered
    verdicts = [t.observe("srv", s, s, 100 + s) for s in range(10, 20)]
    assert all(v.delivered for v in verdicts)
    assert verdicts[1:] == [Verdict.NEXT] * 9  # back in order at the first real message
    assert t.lost <= MAX_GAP and t.duplicates == 0


def test_restart_and_wrap_start_new_epochs() -> None:
    t = SeqTracker()
    for s in range(5):
        t.observe("node#1", s, s, 10 + s)
    # the same src restarts from 0: new pub_ns, so nothing is a duplicate
    assert [t.observe("node#1", s, s, 50 + s) for s in range(3)] == [
        Verdict.EPOCH, Verdict.NEXT, Verdict.NEXT]
    t.observe("w", (1 << 32) - 1, 0, 0)
    assert t.observe("w", 0, 1, 1) is Verdict.EPOCH  # a 32-bit counter wrapped (MCAP seq)
    assert (t.epochs, t.lost) == (2, 0)


def test_reliable_streams_accept_late_retransmissions_once() -> None:
    t = SeqTracker(reliable=True)
    assert t.observe("p", 0, 0, 0) is Verdict.NEXT
    assert t.observe("p", 2, 2, 2) is Verdict.GAP  # 1 is on its way again (retransmit)
    assert t.observe("p", 1, 1, 1) is Verdict.LATE
    assert t.observe("p", 1, 1, 1) is Verdict.DUPLICATE
    assert t.observe("p", 3, 3, 3) is Verdict.NEXT
    assert (t.lost, t.late, t.duplicates) == (0, 1, 1)


def test_memory_is_bounded_per_publisher_and_per_tracker() -> None:
    t = SeqTracker(max_sources=8, window=4)
    for i in range(100):
        t.observe(f"spoof{i}", i, 0, 0)
    assert t.sources == 8
    for s in range(100):
        t.observe("real", s, s, s)
    assert t.observe("real", 90, 90, 90) is Verdict.EPOCH  # out of the window: not a duplicate


@settings(max_examples=200, deadline=None)
@given(st.lists(st.tuples(st.integers(0, 40), st.integers(0, U64)), max_size=30))
def test_forgeries_never_cost_more_than_themselves(forgeries: list[tuple[int, int]]) -> None:
    """A real stream 0..59 with forged messages (same src, any seq) slipped in anywhere: each
    forged message can take the place of at most one real message."""
    at: dict[int, list[int]] = {}
    for pos, seq in forgeries:
        at.setdefault(pos, []).append(seq)
    t = SeqTracker()
    delivered_real = 0
    for s in range(60):
        for k, seq in enumerate(at.get(s, [])):
            t.observe("srv", seq, seq, -1 - k)  # forged: it cannot know the real pub_ns
        delivered_real += t.observe("srv", s, s, s).delivered
    assert delivered_real >= 60 - len(forgeries)


def _state(i: int) -> GliderState:
    return GliderState(stamp_ns=i * 20_000_000, x=float(i), y=0.0, z=100.0, heading=0.0,
                       bank=0.0, airspeed=10.0, vz=0.0, glider_id=0)


class _Got:
    def __init__(self) -> None:
        self.items: list[Any] = []
        self.cond = threading.Condition()

    def __call__(self, msg: Any) -> None:
        with self.cond:
            self.items.append(msg)
            self.cond.notify_all()

    def wait_for(self, pred: Any) -> bool:
        with self.cond:
            return self.cond.wait_for(lambda: pred(self.items), WAIT)


@pytest.mark.parametrize("forged", [U64, 0, 2], ids=["max", "zero", "backwards"])
@pytest.mark.parametrize("kind", ["state", "clock"])
def test_forged_seq_on_the_bus_does_not_freeze_a_subscription(
    bus_url: str, forged: int, kind: str
) -> None:
    """A spoofed message with the real publisher's ``src`` and a forged ``seq``: the stream
    continues within one message (the next real one is delivered). On a composed bus the
    spoof claims a publisher of this process, whose messages come in-process: it is never
    delivered (skipped unread as ``loopback`` when it arrives)."""
    if kind == "state":
        topic, cls, qos, make = "/glider/0/state", GliderState, SENSOR, _state
    else:
        topic, cls, qos, make = "/clock", Clock, LATCHED, (lambda i: Clock(stamp_ns=i))
    got = _Got()
    with Node("server", bus=bus_url, diagnostics_period_s=0) as srv, \
            Node("adapter", bus=bus_url, diagnostics_period_s=0) as ad, \
            open_transport(bus_url) as attacker:
        srv.start()
        ad.start()
        pub = srv.create_publisher(cls, topic, SENSOR)
        ad.create_subscription(cls, topic, got, qos)
        assert pub.wait_for_subscribers(WAIT)
        for i in range(5):  # one at a time: a LATCHED subscription keeps only the newest
            pub.publish(make(i))
            assert got.wait_for(lambda items, n=i + 1: len(items) == n)
        attacker.publish(encode(topic, make(999), seq=forged, pub_ns=0, src=srv.src))
        spoofed = 0 if intra.composed(bus_url) else 1
        if spoofed:
            assert got.wait_for(lambda items: len(items) == 6)
        pub.publish(make(5))
        assert got.wait_for(lambda items: len(items) == 6 + spoofed)
        assert got.items[-1] == make(5)
        counters = ad.stats()["topics"][topic]
        assert counters["dropped"] <= MAX_GAP and counters["duplicates"] == 0


def test_publisher_restart_with_the_same_src_keeps_flowing(bus_url: str) -> None:
    got = _Got()
    with Node("sub", bus=bus_url, diagnostics_period_s=0) as sub, \
            open_transport(bus_url) as raw:
        sub.start()
        # a queue deeper than the burst: the 8 messages arrive at once, and a keep-last queue
        # of SENSOR's depth (5) drops the oldest when the executor is busy (a drop, not a gap)
        deep = QoSProfile("deep", depth=16)
        sub.create_subscription(GliderState, "/glider/0/state", got, deep)
        assert raw.wait_for_subscriber("/glider/0/state", WAIT)
        for life in range(2):  # the same src counts from 0 again after a restart
            for s in range(4):
                raw.publish(encode("/glider/0/state", _state(10 * life + s), seq=s,
                                   pub_ns=1000 * life + s, src="firmware#1"))
        assert got.wait_for(lambda items: len(items) == 8)
        counters = sub.stats()["topics"]["/glider/0/state"]
        assert (counters["epochs"], counters["dropped"], counters["duplicates"]) == (1, 0, 0)


def test_command_dedup_still_drops_true_retransmissions(bus_url: str) -> None:
    got = _Got()
    with Node("sim", bus=bus_url, diagnostics_period_s=0) as sim, \
            open_transport(bus_url) as raw:
        sim.start()
        sim.create_subscription(GliderCmd, "/glider/0/cmd", got, COMMAND)
        assert raw.wait_for_subscriber("/glider/0/cmd", WAIT)
        frames = [encode("/glider/0/cmd", GliderCmd(stamp_ns=s, bank_cmd=0.1, airspeed_cmd=9.0),
                         seq=s, pub_ns=s, src="pilot#1") for s in range(3)]
        for f in (frames[0], frames[2], frames[0], frames[1], frames[2], frames[1]):
            raw.publish(f)
        assert poll_until(lambda: sim.stats()["topics"]["/glider/0/cmd"]["duplicates"] == 3)
        assert sorted(m.stamp_ns for m in got.items) == [0, 1, 2]
