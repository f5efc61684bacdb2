"""AutopilotAdapter against the mock autopilot (virtual CAN) and the bus (mem://)."""

from __future__ import annotations

import math
import threading
from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import can
import numpy as np
import pytest

from drivers.can.adapter import AutopilotAdapter, parse_gliders
from drivers.can.codec import GliderCanCodec
from drivers.can.supervision import CMD_STATES, best_glide_speed
from drivers.faults.can_bus import FaultInjectingBus
from drivers.mocks.autopilot import MockAutopilot
from hil_bridge.bus.messages import GliderCmd, GliderNeighbors, GliderState
from hil_bridge.bus.node import Node, Publisher
from sim_core.soaring.boids import controller_command
from sim_core.soaring.law import Law
from tests.drivers.can._util import unique, wait_until

GLIDERS = (3, 5)


@dataclass
class Sim:
    """The server's side of the bus: publishes states/neighbours, collects commands."""

    node: Node
    states: dict[int, Publisher[GliderState]]
    neighbours: dict[int, Publisher[GliderNeighbors]]
    cmds: dict[int, list[GliderCmd]] = field(default_factory=dict)
    lock: threading.Lock = field(default_factory=threading.Lock)

    def publish_state(self, gid: int, **kw: Any) -> GliderState:
        fields = {"x": 100.0, "y": -50.0, "z": 1200.0, "heading": 0.3, "bank": 0.0,
                  "airspeed": 10.0, "vz": -0.5} | kw
        msg = GliderState(stamp_ns=1_000_000, glider_id=gid, **fields)
        self.states[gid].publish(msg)
        return msg

    def got(self, gid: int) -> list[GliderCmd]:
        with self.lock:
            return list(self.cmds.get(gid, []))


@pytest.fixture
def bus_url() -> str:
    return f"mem://{unique('can-')}"


@pytest.fixture
def channel() -> str:
    return unique("glider-")


@pytest.fixture
def sim(bus_url: str) -> Iterator[Sim]:
    node = Node("sim", bus=bus_url, diagnostics_period_s=0)
    s = Sim(
        node,
        {g: node.create_publisher(GliderState, f"/glider/{g}/state") for g in GLIDERS},
        {g: node.create_publisher(GliderNeighbors, f"/glider/{g}/neighbors") for g in GLIDERS},
    )
    for g in GLIDERS:
        def on_cmd(msg: GliderCmd, g: int = g) -> None:
            with s.lock:
                s.cmds.setdefault(g, []).append(msg)
        node.create_subscription(GliderCmd, f"/glider/{g}/cmd", on_cmd)
    node.start()
    yield s
    node.stop()


@pytest.fixture
def make_adapter(bus_url: str, channel: str) -> Iterator[Any]:
    made: list[AutopilotAdapter] = []

    def make(**params: Any) -> AutopilotAdapter:
        ad = AutopilotAdapter("autopilot", bus=bus_url, channel=channel, gliders=list(GLIDERS),
                              diagnostics_period_s=0.2, **params)
        made.append(ad)
        return ad.start()

    yield make
    for ad in made:
        ad.stop()


@pytest.fixture
def make_mock(channel: str) -> Iterator[Any]:
    made: list[MockAutopilot] = []

    def make(**params: Any) -> MockAutopilot:
        mock = MockAutopilot("mock", channel=channel, **({"gliders": "0,1"} | params))
        made.append(mock)
        mock.start()
        return mock

    yield make
    for mock in made:
        mock.stop()


def _tol(scale: float) -> float:
    return 0.5 * scale + 1e-9


def test_conformance_state_neighbours_and_commands(sim: Sim, make_adapter: Any,
                                                   make_mock: Any) -> None:
    make_adapter()
    mock = make_mock(rate_hz=20.0)
    own = sim.publish_state(3, x=-19876.543, y=12345.678, z=4321.987, heading=-2.5, bank=0.2,
                            airspeed=11.234, vz=1.876)
    sim.publish_state(5, x=250.0, z=900.0)
    rng = np.random.default_rng(4)
    k = 12
    nb = GliderNeighbors(
        stamp_ns=1_000_000, glider_id=3, ids=np.arange(k, dtype=np.int32) + 10,
        x=own.x + rng.uniform(-999, 999, k), y=own.y + rng.uniform(-999, 999, k),
        z=own.z + rng.uniform(-300, 300, k), heading=rng.uniform(-3.1, 3.1, k),
        bank=np.zeros(k), airspeed=rng.uniform(8, 13, k), vz=rng.uniform(-2, 5, k),
    )
    sim.neighbours[3].publish(nb)
    # the list can beat the first whole state sample (the mock drops the first, unverified)
    assert wait_until(lambda: len(mock.receiver.view(0).neighbours) == k
                      and mock.receiver.view(0).own is not None)
    view = mock.receiver.view(0)
    assert view.own is not None and view.alive
    got = view.own
    assert abs(got.x - own.x) <= _tol(0.01) and abs(got.y - own.y) <= _tol(0.01)
    assert abs(got.z - own.z) <= _tol(0.01)
    assert abs(got.heading - own.heading) <= _tol(1e-4)
    assert abs(got.speed - own.airspeed) <= _tol(0.01) and abs(got.vz - own.vz) <= _tol(0.01)
    cols = np.stack([nb.x, nb.y, nb.z, nb.heading, nb.airspeed, nb.vz], axis=1)
    err = np.abs(view.neighbours - cols)
    assert np.all(err[:, :3] <= 2 * _tol(0.01)), err[:, :3].max()
    assert np.all(err[:, 3] <= _tol(1e-4)) and np.all(err[:, 4:] <= _tol(0.01))
    # commands: what the mock computed from what it decoded reaches /glider/3/cmd
    law = Law()
    bank, speed = controller_command(view.own, view.neighbours, law, controller="unified")
    expected = (min(max(bank, law.bankMin), law.bankMax),
                min(max(speed, law.forwardSpeedMin), law.forwardSpeedMax))
    assert wait_until(lambda: mock.last_command(0) is not None)
    assert wait_until(lambda: len(sim.got(3)) >= 3 and len(sim.got(5)) >= 3)
    last = mock.last_command(0)
    assert last is not None and last == pytest.approx(expected, abs=1e-12)
    cmd = sim.got(3)[-1]
    assert abs(cmd.bank_cmd - expected[0]) <= _tol(1e-4)
    assert abs(cmd.airspeed_cmd - expected[1]) <= _tol(0.01)
    assert cmd.glider_id == 3 and cmd.stamp_ns >= own.stamp_ns


def test_attitude_frames_follow_the_state(sim: Sim, make_adapter: Any, make_mock: Any) -> None:
    from sim_core.pose import quat_from_euler

    ad = make_adapter()
    mock = make_mock(rate_hz=20.0)
    q = quat_from_euler(-0.4, 0.05, 2.9)
    sim.publish_state(3, bank=0.4, roll=-0.4, pitch=0.05, yaw=2.9, qw=q[0], qx=q[1], qy=q[2],
                      qz=q[3], roll_rate=-0.25, pitch_rate=0.012, yaw_rate=0.6)
    assert wait_until(lambda: bool(np.all(np.isfinite(mock.receiver.view(0).body_rates))))
    view = mock.receiver.view(0)
    np.testing.assert_allclose(view.attitude, q, atol=_tol(5e-5))
    np.testing.assert_allclose(view.body_rates, [-0.25, 0.012, 0.6], atol=_tol(1e-4))
    # a state without attitude (an older publisher): the attitude frames are left out
    sim.publish_state(5)
    assert wait_until(lambda: ad.stats().get("attitude_missing", 0) > 0)
    # the adapter counts before its frames cross the bus to the mock
    assert wait_until(lambda: mock.receiver.view(1).own is not None)
    assert not np.any(np.isfinite(mock.receiver.view(1).attitude))


def test_diagnostics_and_stats_report_the_link(sim: Sim, make_adapter: Any,
                                               make_mock: Any, bus_url: str) -> None:
    from hil_bridge.bus.messages import Diagnostics

    seen: list[Diagnostics] = []
    sim.node.create_subscription(Diagnostics, "/diagnostics", seen.append)
    ad = make_adapter()
    make_mock(rate_hz=20.0)
    sim.publish_state(3)
    assert wait_until(lambda: ad.stats().get("cmd_forwarded", 0) > 0)
    assert wait_until(lambda: any(d.node == "autopilot" and "can_tx_frames" in d.counters
                                  for d in seen))
    diag = next(d for d in reversed(seen) if d.node == "autopilot")
    assert diag.counters["can_state"] == 0 and diag.counters["can_tx_frames"] > 0
    # the latency percentiles are in stats() alone, not in what /diagnostics is made of
    assert "state_latency_ms" not in ad.counters() and "states_in" in ad.counters()
    assert "state_latency_ms" in ad.stats()
    # the first command can beat the mock's first heartbeat, and that heartbeat its switch to
    # AUTO: wait for a heartbeat that says AUTO
    assert wait_until(lambda: ad.stats().get("ap_mode:3") == 1)
    stats = ad.stats()
    assert stats["ap_alive:3"] == 1
    assert stats["can_link"] == "up" and stats["cmd_state:3"] == CMD_STATES["FRESH"]
    assert stats["ap_heartbeats_in"] > 0
    assert stats["ap_mode:3"] == 1  # the mock flies it: AUTO


class RawAutopilot:
    """A hand-driven autopilot on a raw python-can bus (frames encoded with the DBC)."""

    def __init__(self, channel: str) -> None:
        self.bus = can.Bus(interface="virtual", channel=channel)
        self.codec = GliderCanCodec()
        self.counter = 0

    def command(self, node: int, bank: float, speed: float) -> None:
        self.counter = (self.counter + 1) % 256
        self.bus.send(self.codec.encode("AUTOPILOT_CMD", node, {
            "bank_cmd_rad": bank, "airspeed_cmd_mps": speed, "cmd_counter": self.counter}))

    def heartbeat(self, node: int, mode: int) -> None:
        self.bus.send(self.codec.encode("AUTOPILOT_HEARTBEAT", node, {
            "ap_counter": 1, "ap_mode": mode, "ap_controller": 0, "ap_state_age_ms": 0,
            "ap_rx_errors": 0}))

    def bridge_cmd_state(self, node: int) -> int | None:
        """cmd_state of the newest BRIDGE_HEARTBEAT for ``node`` waiting on the bus."""
        state = None
        while (msg := self.bus.recv(0.0)) is not None:
            frame = self.codec.decode(msg)
            if frame.name == "BRIDGE_HEARTBEAT" and frame.node_id == node:
                state = int(frame.signals["cmd_state"])
        return state


@pytest.fixture
def raw(channel: str) -> Iterator[RawAutopilot]:
    ap = RawAutopilot(channel)
    yield ap
    ap.bus.shutdown()


def test_heartbeat_and_command_timeout_hold_then_failsafe(sim: Sim, make_adapter: Any,
                                                          raw: RawAutopilot) -> None:
    ad = make_adapter(cmd_timeout_s=0.1, failsafe_after_s=0.4, heartbeat_hz=50.0)
    sim.publish_state(3)
    raw.command(0, 0.1234, 9.87)
    assert wait_until(lambda: any(abs(c.bank_cmd - 0.1234) < 1e-9 for c in sim.got(3)))
    assert ad.cmd_state(3) == "FRESH"
    assert wait_until(lambda: ad.cmd_state(3) == "HOLD")
    n = len(sim.got(3))
    assert wait_until(lambda: len(sim.got(3)) > n + 2)
    assert all(abs(c.bank_cmd - 0.1234) < 1e-9 for c in sim.got(3)[n:n + 2])
    assert wait_until(lambda: ad.cmd_state(3) == "FAILSAFE")
    assert wait_until(lambda: sim.got(3)[-1].bank_cmd == 0.0)
    last = sim.got(3)[-1]
    assert last.airspeed_cmd == pytest.approx(best_glide_speed()) == pytest.approx(11.3596, 1e-4)
    assert wait_until(lambda: raw.bridge_cmd_state(0) == CMD_STATES["FAILSAFE"])
    raw.command(0, -0.05, 10.5)
    assert wait_until(lambda: sim.got(3)[-1].bank_cmd == pytest.approx(-0.05, abs=1e-4))
    assert ad.cmd_state(3) == "FRESH"
    stats = ad.stats()
    assert stats["hold_entries"] == 1
    assert stats["failsafe_entries"] == 2  # glider 3 after its hold, glider 5 never commanded
    assert stats["failsafe_exits"] == 1 and stats["cmd_frames_in"] == 2
    # glider 5 never had an autopilot: WAITING, then the failsafe too
    assert stats["cmd_state:5"] == CMD_STATES["FAILSAFE"]
    assert sim.got(5) and sim.got(5)[-1].bank_cmd == 0.0


def test_autopilot_fault_heartbeat_forces_failsafe(sim: Sim, make_adapter: Any,
                                                   raw: RawAutopilot) -> None:
    ad = make_adapter(heartbeat_hz=50.0, failsafe_after_s=30.0, cmd_timeout_s=10.0)
    raw.command(0, 0.2, 10.0)
    assert wait_until(lambda: ad.cmd_state(3) == "FRESH")
    raw.heartbeat(0, mode=3)
    assert wait_until(lambda: ad.cmd_state(3) == "FAILSAFE")
    assert wait_until(lambda: bool(sim.got(3)) and sim.got(3)[-1].bank_cmd == 0.0)
    assert ad.stats()["ap_alive:3"] == 1


def test_state_saturates_and_is_counted(sim: Sim, make_adapter: Any, make_mock: Any) -> None:
    ad = make_adapter()
    mock = make_mock(gliders=[0])
    sim.publish_state(3, x=31000.0, z=-5.0)
    assert wait_until(lambda: mock.receiver.view(0).own is not None)
    own = mock.receiver.view(0).own
    assert own is not None and own.x == pytest.approx(20000.0) and own.z == 0.0
    assert ad.stats()["saturated_tx"] >= 2


def test_adapter_keeps_commanding_through_faults(sim: Sim, make_adapter: Any,
                                                 make_mock: Any) -> None:
    faults = {"seed": 5, "error_frame_rate": 0.05, "truncate_rate": 0.05, "foreign_rate": 0.05,
              "drop_rate": 0.02, "enobufs_rate": 0.05, "enobufs_burst": 2, "delay_s": 0.002}
    ad = make_adapter(faults=faults, cmd_timeout_s=0.5, failsafe_after_s=5.0)
    make_mock(rate_hz=50.0)
    sim.publish_state(3)
    sim.publish_state(5)
    assert wait_until(lambda: len(sim.got(3)) >= 20)
    link = ad.can.link
    assert link is not None
    bus = link.bus
    assert isinstance(bus, FaultInjectingBus)
    bus.inject_bus_off(30.0)  # only a re-open gets out of this one
    assert wait_until(lambda: ad.stats().get("can_bus_off_recoveries", 0) >= 1)
    n = len(sim.got(3))
    assert wait_until(lambda: len(sim.got(3)) >= n + 20)
    stats = ad.stats()
    assert stats["can_bus_off"] >= 1 and stats["can_reopens"] >= 1
    assert stats["can_error_frames"] > 0 and stats["rx_decode_errors"] > 0
    assert stats["can_tx_buffer_full"] > 0
    assert stats.get("cmd_failsafe_published", 0) == 0
    assert all(t.is_alive() for t in ad.can.threads)


def test_candump_log_of_the_adapter(sim: Sim, make_adapter: Any, make_mock: Any,
                                    tmp_path: Path) -> None:
    path = tmp_path / "out" / "autopilot.log"
    ad = make_adapter(can_log=str(path))
    make_mock(rate_hz=20.0)
    sim.publish_state(3)
    assert wait_until(lambda: ad.stats().get("cmd_forwarded", 0) >= 2)
    ad.stop()
    frames = list(can.LogReader(path))
    sent = {m.arbitration_id for m in frames if not m.is_rx}
    received = {m.arbitration_id for m in frames if m.is_rx}
    assert {0x120, 0x130, 0x160} <= sent
    assert {0x100, 0x110} <= received
    codec = GliderCanCodec()
    pos = next(m for m in frames if m.arbitration_id == 0x120)
    assert codec.decode(pos).signals["x_m"] == pytest.approx(100.0)


@pytest.mark.parametrize(
    ("gliders", "expected"),
    [([3, 5], {3: 0, 5: 1}), ({7: 15, 2: 0}, {7: 15, 2: 0}), ("4,9", {4: 0, 9: 1}), (6, {6: 0})],
)
def test_parse_gliders(gliders: Any, expected: dict[int, int]) -> None:
    assert parse_gliders(gliders) == expected


@pytest.mark.parametrize(
    ("gliders", "match"),
    [([], "at least one"), ([1, 1], "duplicate"), ({1: 0, 2: 0}, "unique"),
     ({1: 16}, "0..15"), (["a"], "expected a list")],
)
def test_parse_gliders_rejects(gliders: Any, match: str) -> None:
    with pytest.raises(ValueError, match=match):
        parse_gliders(gliders)


@pytest.mark.parametrize(
    ("params", "match"),
    [({"interface": "nope"}, "interface"), ({"state_rate_hz": 0}, "state_rate_hz"),
     ({"cmd_timeout_s": 2.0, "failsafe_after_s": 1.0}, "failsafe_after_s"),
     ({"failsafe_bank_rad": 2.0}, "failsafe_bank_rad"),
     ({"faults": {"drop_rate": 3}}, "drop_rate"), ({"faults": {"typo": 1}}, "typo")],
)
def test_bad_params_fail_at_construction(bus_url: str, params: dict[str, Any],
                                         match: str) -> None:
    with pytest.raises(ValueError, match=match):
        AutopilotAdapter("autopilot", bus=bus_url, **params)


def test_best_glide_speed_is_the_polar_optimum() -> None:
    law = Law()
    v = np.linspace(5, 20, 20001)
    sink = law.Sink_A * v**2 + law.Sink_B * v + law.Sink_C
    assert best_glide_speed(law) == pytest.approx(v[np.argmax(v / -sink)], abs=1e-3)
    assert math.isclose(best_glide_speed(), math.sqrt(2.3782 / 0.01843))


def test_unexpected_errors_are_counted_and_loops_survive(sim: Sim, make_adapter: Any,
                                                         raw: RawAutopilot) -> None:
    ad = make_adapter()
    real = ad._on_frame
    calls = {"n": 0}

    def flaky(frame: Any) -> None:
        calls["n"] += 1
        if calls["n"] == 1:
            raise RuntimeError("injected handler bug")
        real(frame)

    ad._on_frame = flaky
    sim.publish_state(3)
    raw.command(0, 0.1, 10.0)
    raw.command(0, 0.2, 10.0)
    assert wait_until(lambda: ad.stats().get("cmd_forwarded", 0) == 1)
    assert ad.stats()["loop_errors"] == 1
    assert all(t.is_alive() for t in ad.can.threads)


@pytest.mark.parametrize("forged", [(1 << 64) - 1, 0], ids=["max", "zero"])
def test_spoofed_state_and_clock_do_not_freeze_the_adapter(sim: Sim, make_adapter: Any,
                                                          forged: int) -> None:
    """The issue's attack: one spoofed /glider/<id>/state and /clock carrying the server's
    ``src`` and a forged ``seq``. The next real message of each stream still gets through."""
    from hil_bridge.bus.codec import encode
    from hil_bridge.bus.messages import Clock
    from hil_bridge.bus.transport import open_transport

    ad = make_adapter()
    clock_pub = sim.node.create_publisher(Clock, "/clock")
    assert clock_pub.wait_for_subscribers(5.0) and sim.states[3].wait_for_subscribers(5.0)
    for i in range(3):
        sim.publish_state(3, x=float(i))
        clock_pub.publish(Clock(stamp_ns=(i + 1) * 1_000_000))
    assert wait_until(lambda: ad.stats().get("states_in") == 3 and ad.now_ns() == 3_000_000)
    with open_transport(sim.node.bus) as attacker:
        state = GliderState(stamp_ns=0, x=0.0, y=0.0, z=0.0, heading=0.0, bank=0.0,
                            airspeed=10.0, vz=0.0, glider_id=3)
        attacker.publish(encode("/glider/3/state", state, seq=forged, pub_ns=0,
                                src=sim.node.src))
        attacker.publish(encode("/clock", Clock(stamp_ns=0), seq=forged, pub_ns=0,
                                src=sim.node.src))
    assert wait_until(lambda: ad.stats().get("states_in") == 4)
    sim.publish_state(3, x=42.0)
    clock_pub.publish(Clock(stamp_ns=9_000_000))
    assert wait_until(lambda: ad.stats().get("states_in") == 5 and ad.now_ns() == 9_000_000)
    # counted as a new epoch, not as 1.8e19 lost: at most the 3 steps the forged seq went back,
    # per subscription (the adapter subscribes to /clock twice: its clock and lockstep mode)
    for topic, subscriptions in (("/glider/3/state", 1), ("/clock", 2)):
        counters = ad.stats()["topics"][topic]
        assert counters["epochs"] >= 1 and counters["dropped"] <= 3 * subscriptions


def test_state_samples_are_spread_over_the_period(bus_url: str, channel: str) -> None:
    """12 gliders: 10 slots per 20 ms period (two gliders share slots 0 and 1); each call sends
    the slots due by its time, a late one every slot it missed (at most a period's), so every
    glider keeps 50 Hz whatever the calls' timing."""
    ids = list(range(20, 32))
    ad = AutopilotAdapter("autopilot", bus=bus_url, channel=channel, gliders=ids,
                          state_rate_hz=50.0, diagnostics_period_s=0)
    sent: list[list[int]] = []
    ad._send_sample = lambda g, now: sent[-1].append(g.gid)  # type: ignore[method-assign]
    try:
        ad._start_wall = 100.0

        def call(t: float) -> list[int]:
            sent.append([])
            ad._send_states(100.0 + t)
            return sent[-1]

        assert call(0.0005) == [20, 30]
        assert call(0.0015) == []  # slot 1 is due at 2 ms
        assert call(0.0025) == [21, 31]
        assert call(0.0105) == [22, 23, 24, 25]  # late: slots 2..5 at once
        assert call(0.5) == [21, 31, 22, 23, 24, 25, 26, 27, 28, 29, 20, 30]  # a period, no more
        sent.clear()
        for k in range(1, 501):  # 1 s of calls at the slot cadence, a third of them late
            call(0.5 + k * 0.002 + (0.0015 if k % 3 == 0 else 0.0))
        counts = np.bincount([g for call_ in sent for g in call_], minlength=32)[20:]
        assert set(counts.tolist()) <= {49, 50, 51}
        assert max(len(c) for c in sent) <= 4
    finally:
        ad.stop()
