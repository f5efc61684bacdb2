"""SimServer: lockstep stalls, command limits, held commands, registration (mem:// bus)."""

from __future__ import annotations

import itertools
import math
import threading
from typing import Any

import numpy as np
import pytest

from hil_bridge.bus.messages import GliderCmd, GliderNeighbors, GliderState
from hil_bridge.bus.node import Node
from hil_bridge.bus.qos import COMMAND
from hil_bridge.server.sim_server import SimServer
from sim_core.config import ConfigError

SWARM = {"overrides": {"numAgents": 3, "dt": 0.1}, "seed": 4}


def _scene(mode: str, **clock: Any) -> dict[str, Any]:
    return {"swarm": SWARM, "state_rate_hz": 20, "clock": {"mode": mode, **clock}}


def test_lockstep_with_a_silent_autopilot_stalls_then_freewheels() -> None:
    scene = _scene("lockstep", lockstep_timeout_s=0.01, lockstep_start_timeout_s=0.01,
                   lockstep_max_stalls=3)
    srv = SimServer("server", bus="mem://lockstep_silent", scene=scene, autopilots=[1],
                    stop_after_s=1.0)
    srv.start()
    try:
        assert srv.wait_done(timeout=60), "lockstep deadlocked on a silent autopilot"
    finally:
        srv.stop()
    st = srv.stats()
    assert st["control_steps"] == 11  # at t = 0, 0.1, ..., 1.0 s
    assert st["physics_steps"] == 20  # one integration step per tick at 20 Hz
    assert st["stalls"] == 3  # then the silent autopilot is no longer waited for
    assert st["lockstep_released"] == 1
    assert st["freewheeling"] == [1]


def test_commands_apply_with_limits_and_bad_ones_are_counted() -> None:
    """A lockstep autopilot answers each physics step with the next scripted command."""
    script = [
        (0.1, 10.0),            # good
        (math.nan, 10.0),       # rejected: non-finite -> hold (0.1, 10)
        (2.0, 10.0),            # rejected: |bank| >= pi/2
        (0.1, -1.0),            # rejected: airspeed <= 0
        (-0.5, 20.0),           # clipped to (bankMin, forwardSpeedMax)
        (-0.5, 20.0),
    ]
    bus = "mem://commands"
    scene = _scene("lockstep", lockstep_timeout_s=5.0)
    srv = SimServer("server", bus=bus, scene=scene, autopilots=[0], stop_after_s=0.6)
    ap = Node("autopilot", bus=bus)
    cmd_pub = ap.create_publisher(GliderCmd, "/glider/0/cmd", COMMAND)
    banks: dict[int, float] = {}
    neighbour_msgs: list[GliderNeighbors] = []
    sent = {"n": 0}
    lock = threading.Lock()

    def on_state(msg: GliderState) -> None:
        with lock:
            banks[msg.step] = msg.bank
            # answer the first state of each control step (steps count from 1)
            if msg.step == sent["n"] + 1 and sent["n"] < len(script):
                bank, speed = script[sent["n"]]
                sent["n"] += 1
                cmd_pub.publish(GliderCmd(stamp_ns=msg.stamp_ns, bank_cmd=bank,
                                          airspeed_cmd=speed, glider_id=0, step=msg.step))

    ap.create_subscription(GliderState, "/glider/0/state", on_state)
    ap.create_subscription(GliderNeighbors, "/glider/0/neighbors", neighbour_msgs.append)
    other: list[GliderNeighbors] = []
    ap.create_subscription(GliderNeighbors, "/glider/1/neighbors", other.append)
    ap.start()
    srv.start()
    try:
        assert srv.wait_done(timeout=60)
    finally:
        srv.stop()
        ap.stop()
    st = srv.stats()
    assert st["cmd_rejected"] == 3
    assert st["cmd_applied"] == 3
    assert st["cmd_clipped"] == 2
    assert st["stalls"] == 0
    # The period after control step k flies the command answering step k: 0.1 rad through
    # steps 1..4 (held through the three rejected ones), then bankMin. The bank follows its
    # command through the flight model's lag, so it closes on 0.1, then turns towards bankMin.
    law_bank_min = srv.scene.law.bankMin
    errors = [abs(banks[k] - 0.1) for k in (1, 2, 3, 4)]  # each at the end of its period
    assert all(b < a for a, b in itertools.pairwise(errors)), banks
    assert banks[6] < banks[5] < banks[4] and banks[5] > law_bank_min
    assert st["flown"]["0"]["bank_cmd"] == pytest.approx(law_bank_min)
    # neighbour lists only for the glider whose autopilot registered
    assert neighbour_msgs and not other


def test_unknown_autopilot_id_and_bad_params_fail_at_construction() -> None:
    with pytest.raises(ConfigError, match="autopilots: unknown glider id"):
        SimServer("server", bus="mem://bad", scene=_scene("fast"), autopilots=[42])
    with pytest.raises(ConfigError, match="unknown key"):
        SimServer("server", bus="mem://bad", scene=_scene("fast"), colour="red")
    with pytest.raises(ConfigError, match="echo_queue"):
        SimServer("server", bus="mem://bad", scene=_scene("fast"), echo_queue=0)
    with pytest.raises(ConfigError, match="echo_budget_ms"):
        SimServer("server", bus="mem://bad", scene=_scene("fast"), echo_budget_ms=0)


def test_commanded_vehicle_leaves_its_path_and_turns_at_the_coordinated_rate() -> None:
    bus = "mem://vehicle_cmd"
    # from level flight: looped, the path would start in its U-turn back from the far end
    path = {"kind": "points", "points": [[0.0, 0.0, 3.0], [100.0, 0.0, 3.0]], "loop": False}
    scene = {
        "vehicles": [{"id": 100, "path": path, "commanded": True},
                     {"id": 101, "path": path}],
        "state_rate_hz": 20, "clock": {"mode": "realtime", "rate": 4.0},
    }
    srv = SimServer("server", bus=bus, scene=scene, stop_after_s=3.0)
    ap = Node("autopilot", bus=bus)
    pub100 = ap.create_publisher(GliderCmd, "/glider/100/cmd", COMMAND)
    pub101 = ap.create_publisher(GliderCmd, "/glider/101/cmd", COMMAND)
    states: list[GliderState] = []
    ap.create_subscription(GliderState, "/glider/100/state", states.append)
    ap.start()
    srv.start()
    try:
        pub100.publish(GliderCmd(stamp_ns=0, bank_cmd=0.3, airspeed_cmd=4.0))
        pub101.publish(GliderCmd(stamp_ns=0, bank_cmd=0.3, airspeed_cmd=4.0))
        assert srv.wait_done(timeout=30)
    finally:
        srv.stop()
        ap.stop()
    flown = [m for m in states if m.stamp_ns >= 1_000_000_000]
    assert len(flown) > 30
    for a, b in itertools.pairwise(flown):
        assert b.step == a.step + 1
        assert b.z == 3.0  # a commanded vehicle holds its height by default
        mid_bank, mid_speed = (a.bank + b.bank) / 2, (a.airspeed + b.airspeed) / 2
        dh = (b.heading - a.heading + math.pi) % (2 * math.pi) - math.pi
        assert dh * 20 == pytest.approx(9.81 * math.tan(mid_bank) / mid_speed, rel=2e-3)
        assert math.hypot(b.x - a.x, b.y - a.y) * 20 == pytest.approx(mid_speed, rel=1e-3)
    # first-order responses to the command (bank 0.3 rad, 4 m/s from the path's 5 m/s)
    last = flown[-1]
    assert last.bank == pytest.approx(0.3, abs=1e-3)
    assert last.roll == -last.bank and last.pitch == 0.0
    t_on = next(m for m in states if m.airspeed < 5.0).stamp_ns / 1e9 - 0.05
    assert last.airspeed == pytest.approx(4.0 + math.exp(-(last.stamp_ns / 1e9 - t_on) / 5.0),
                                          abs=0.02)
    assert last.yaw_rate == pytest.approx(9.81 * math.tan(last.bank) / last.airspeed
                                          * math.cos(last.bank), rel=1e-9)
    st = srv.stats()
    assert st["cmd_ignored"] == 1  # vehicle 101 follows its path and ignores commands
    assert 100 in st["registered"]


def _final_state(bus: str, seed: int) -> Any:
    scene = {"swarm": {"overrides": {"numAgents": 4, "dt": 0.1}, "seed": seed},
             "state_rate_hz": 20, "clock": {"mode": "fast"}}
    srv = SimServer("server", bus=bus, scene=scene, stop_after_s=3.0)
    srv.start()
    try:
        assert srv.wait_done(timeout=30)
    finally:
        srv.stop()
    return srv.scene.swarm.state


def test_same_seed_same_flight_different_seed_differs() -> None:
    a = _final_state("mem://determinism_a", 3)
    b = _final_state("mem://determinism_b", 3)
    c = _final_state("mem://determinism_c", 4)
    for name in ("x", "y", "z", "heading", "bank", "speed"):
        assert np.array_equal(getattr(a, name), getattr(b, name)), name
    assert not np.array_equal(a.x, c.x)
