"""The launch run summary's bus monitor: gaps are lost messages, retransmissions are not."""

from __future__ import annotations

import time

from hil_bridge.bus.codec import encode
from hil_bridge.bus.messages import GliderCmd
from hil_bridge.bus.transport import open_transport
from hil_bridge.launch.monitor import BusMonitor


def test_monitor_counts_gaps_and_not_retransmissions() -> None:
    bus = "mem://launch_monitor"
    monitor = BusMonitor("monitor", bus=bus)
    monitor.start()
    try:
        with open_transport(bus) as pub:
            msg = GliderCmd(stamp_ns=0, bank_cmd=0.1, airspeed_cmd=10.0)
            frames = {seq: encode("/glider/0/cmd", msg, seq=seq, pub_ns=time.monotonic_ns(),
                                  src="pilot") for seq in (0, 1, 2, 3, 6)}
            # a late retransmission of 1 (the same frames again), then 3 (nothing lost there),
            # then 6 (4, 5 lost)
            for seq in (0, 1, 2, 1, 3, 6):
                pub.publish(frames[seq])
            deadline = time.monotonic() + 10.0
            while monitor.stats()["messages"] + monitor.stats()["duplicates"] < 6:
                assert time.monotonic() < deadline, monitor.stats()
                time.sleep(0.005)
    finally:
        monitor.stop()
    stats = monitor.stats()
    assert stats["messages"] == 5
    assert stats["duplicates"] == 1
    assert stats["seq_gaps"] == 2
    assert stats["topics"]["/glider/0/cmd"]["count"] == 5


def test_monitor_counts_forged_states_as_bad_not_as_latency() -> None:
    """A valid header over a garbage payload on a state topic (pub_ns = 0) is undecodable, not
    a state whose latency is the age of the machine."""
    from hil_bridge.bus.codec import Header, pack_header
    from hil_bridge.bus.messages import GliderState

    bus = "mem://launch_monitor_forged"
    monitor = BusMonitor("monitor", bus=bus)
    monitor.start()
    try:
        with open_transport(bus) as pub:
            header = pack_header(Header("echoloop/GliderState", 1, 0, 0, 0, "", "flood"))
            for _ in range(20):
                pub.publish([b"/glider/0/state\0", header, b"\xc1garbage"])
            real = GliderState(stamp_ns=1, x=0.0, y=0.0, z=0.0, heading=0.0, bank=0.0,
                               airspeed=10.0, vz=0.0)
            pub.publish(encode("/glider/0/state", real, seq=0, pub_ns=time.monotonic_ns(),
                               src="server"))
            deadline = time.monotonic() + 10.0
            while monitor.stats()["bad"] + monitor.stats()["messages"] < 21:
                assert time.monotonic() < deadline, monitor.stats()
                time.sleep(0.005)
    finally:
        monitor.stop()
    stats = monitor.stats()
    assert stats["bad"] == 20 and stats["state_latency_ms"]["n"] == 1
    assert stats["state_latency_ms"]["max"] < 10_000


def test_monitor_throttles_itself_under_a_flood_of_garbage() -> None:
    """Undecodable messages outnumbering good ones: the monitor keeps to its flood share of a
    core (it sleeps, says for how long) and still counts what it receives."""
    bus = "mem://launch_monitor_flood?depth=100000"
    monitor = BusMonitor("monitor", bus=bus)
    monitor.start()
    n = 3000
    try:
        with open_transport(bus) as pub:
            for _ in range(n):
                pub.publish([b"/glider/0/state\0", b"\xc1", b""])
            deadline = time.monotonic() + 60.0
            while monitor.stats()["bad"] < n:
                assert time.monotonic() < deadline, monitor.stats()
                time.sleep(0.01)
    finally:
        monitor.stop()
    stats = monitor.stats()
    assert stats["bad"] == n and stats["messages"] == 0
    assert stats["throttled_s"] > 0


def test_monitor_measures_the_gaps_between_consecutive_state_publishes() -> None:
    """From the headers' ``pub_ns``: one publisher's consecutive ``seq`` only (a lost state or
    another publisher starts over), whenever the monitor itself received them."""
    from hil_bridge.bus.messages import GliderState

    bus = "mem://launch_monitor_gaps"
    monitor = BusMonitor("monitor", bus=bus)
    monitor.start()
    state = GliderState(stamp_ns=0, x=0.0, y=0.0, z=0.0, heading=0.0, bank=0.0, airspeed=10.0,
                        vz=0.0)
    ms = 1_000_000
    sent = [("server", 0, 0), ("server", 1, 4 * ms), ("server", 2, 8 * ms),
            ("server", 3, 20 * ms), ("server", 5, 60 * ms), ("server", 6, 64 * ms),
            ("other", 7, 90 * ms)]
    base = time.monotonic_ns()
    try:
        with open_transport(bus) as pub:
            for src, seq, at in sent:
                pub.publish(encode("/glider/0/state", state, seq=seq, pub_ns=base + at, src=src))
            deadline = time.monotonic() + 10.0
            while monitor.stats()["messages"] < len(sent):
                assert time.monotonic() < deadline, monitor.stats()
                time.sleep(0.005)
    finally:
        monitor.stop()
    gaps = monitor.stats()["state_gap_ms"]
    assert gaps["n"] == 4 and gaps["max"] == 12.0 and gaps["p50"] == 4.0
