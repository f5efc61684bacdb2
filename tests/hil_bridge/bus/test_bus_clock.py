"""SimClock monotonicity across pause/rate changes; lockstep gate stalls; /clock publishing."""

from __future__ import annotations

import threading

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from hil_bridge.bus.clock import SimClock
from hil_bridge.bus.messages import Clock
from hil_bridge.bus.node import Node
from hil_bridge.bus.qos import LATCHED

OPS = st.lists(
    st.one_of(
        st.just(("pause", 0.0)),
        st.just(("resume", 0.0)),
        st.tuples(st.just("rate"), st.floats(min_value=1e-3, max_value=1e3)),
        st.just(("now", 0.0)),
    ),
    max_size=40,
)


@settings(max_examples=60, deadline=None)
@given(ops=OPS)
def test_realtime_clock_is_monotonic_across_pause_and_rate_changes(
    ops: list[tuple[str, float]],
) -> None:
    clock = SimClock("realtime", rate=2.0, start_ns=10)
    last = clock.now_ns()
    assert last >= 10
    for op, arg in ops:
        if op == "pause":
            clock.pause()
            frozen = clock.now_ns()
            assert clock.now_ns() == frozen
        elif op == "resume":
            clock.resume()
        elif op == "rate":
            clock.set_rate(arg)
        now = clock.now_ns()
        assert now >= last
        last = now


def test_pause_freezes_and_resume_continues_without_jump() -> None:
    clock = SimClock("realtime", rate=1000.0)
    clock.pause()
    t = clock.now_ns()
    assert clock.wall_seconds_until(t + 1) is None
    assert not clock.sleep_until(t + 1, timeout=0.01)
    clock.resume()
    assert clock.sleep_until(t + 1_000_000, timeout=10.0)  # 1 ms sim = 1 µs wall at 1000x
    assert clock.now_ns() >= t + 1_000_000


def test_owner_stepped_clock_moves_only_when_told() -> None:
    clock = SimClock("lockstep", start_ns=5)
    assert clock.now_ns() == 5 and clock.owner_stepped
    assert clock.advance(10) == 15
    assert clock.set_ns(20) == 20
    with pytest.raises(ValueError, match="cannot go back"):
        clock.set_ns(19)
    with pytest.raises(ValueError, match=">= 0"):
        clock.advance(-1)
    woke = threading.Event()
    threading.Thread(target=lambda: woke.set() if clock.sleep_until(100, timeout=10) else None,
                     daemon=True).start()
    clock.advance(80)
    assert woke.wait(10.0)
    with pytest.raises(ValueError, match="realtime"):
        SimClock("realtime").advance(1)


@pytest.mark.parametrize(
    ("kwargs", "match"),
    [({"mode": "warp"}, "unknown clock mode"), ({"rate": 0.0}, "real-time factor"),
     ({"rate": float("inf")}, "real-time factor"), ({"start_ns": -1}, "start_ns")],
)
def test_bad_clock_arguments(kwargs: dict[str, object], match: str) -> None:
    with pytest.raises(ValueError, match=match):
        SimClock(**kwargs)  # type: ignore[arg-type]


def test_clock_follower_tracks_published_clock() -> None:
    owner_clock = SimClock("lockstep")
    follower_clock = SimClock("lockstep")
    got: list[Clock] = []
    cond = threading.Condition()

    def on_clock(msg: Clock) -> None:
        with cond:
            got.append(msg)
            cond.notify_all()

    with Node("sim", bus="mem://clocktest", clock=owner_clock) as sim, \
            Node("viewer", bus="mem://clocktest", clock=follower_clock) as viewer:
        sim.start()
        viewer.start()
        viewer.follow_bus_clock()
        viewer.create_subscription(Clock, "/clock", on_clock, LATCHED)
        pub = sim.create_publisher(Clock, "/clock", LATCHED)
        owner_clock.advance(4_000_000)
        pub.publish(Clock(stamp_ns=sim.clock.now_ns()))
        with cond:
            assert cond.wait_for(lambda: got, 10.0)
        assert got == [Clock(stamp_ns=4_000_000)]
        assert follower_clock.sleep_until(4_000_000, timeout=10.0)
        with Node("rt", bus="mem://clocktest", clock=SimClock("realtime")) as rt, \
                pytest.raises(ValueError, match="lockstep"):
            rt.follow_bus_clock()
