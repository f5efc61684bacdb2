"""The bridge's frames from bus messages (drivers/can/bridge_frames.py), command supervision
(drivers/can/supervision.py) and the CAN endpoint's loops (drivers/can/endpoint.py)."""

from __future__ import annotations

import math
import threading
from collections import Counter

import numpy as np
import pytest

from drivers.can.bridge_frames import (
    BRIDGE_MODES,
    MAX_NEIGHBOURS,
    attitude_frames,
    bridge_mode,
    motion_frame,
    neighbour_frames,
    pos_frame,
)
from drivers.can.bus import CanBusConfig
from drivers.can.codec import GliderCanCodec
from drivers.can.endpoint import CanEndpoint
from drivers.can.supervision import CMD_STATES, next_cmd_state
from hil_bridge.bus.faults import Faults
from hil_bridge.bus.messages import GliderNeighbors, GliderState
from tests.drivers.can._util import unique, wait_until

CODEC = GliderCanCodec()


def _state(**kw: float) -> GliderState:
    return GliderState(stamp_ns=0, x=100.0, y=-50.0, z=1200.0, heading=0.3, bank=0.1,
                       airspeed=10.0, vz=-0.5, **kw)


def _neighbours(k: int) -> GliderNeighbors:
    i = np.arange(k, dtype=np.float64)
    return GliderNeighbors(stamp_ns=0, glider_id=0, ids=np.arange(k, dtype=np.int32),
                           x=110.0 + i, y=-50.0 - 2 * i, z=1190.0 + 0 * i, heading=0.1 * i,
                           bank=0 * i, airspeed=9.0 + 0 * i, vz=-0.4 + 0 * i)


def test_a_sample_without_attitude_is_pos_and_motion_only() -> None:
    st = _state()
    assert attitude_frames(st, 5) == []
    assert pos_frame(st) == ("GLIDER_STATE_POS", {"x_m": 100.0, "y_m": -50.0, "z_m": 1200.0})
    assert pos_frame(st, lockstep=True)[1]["lockstep"] == 1
    name, values = motion_frame(st, 5)
    assert name == "GLIDER_STATE_MOTION" and values["state_counter"] == 5


def test_the_quaternion_goes_out_with_qw_non_negative() -> None:
    half = math.sqrt(0.5)
    st = _state(qw=-half, qx=0.0, qy=0.0, qz=-half, roll_rate=0.0, pitch_rate=0.0,
                yaw_rate=0.2)
    (quat, q), (rates, r) = attitude_frames(st, 3)
    assert (quat, rates) == ("GLIDER_STATE_QUAT", "GLIDER_STATE_RATES")
    assert (q["qw"], q["qz"]) == (half, half) and q["state_counter"] == r["state_counter"] == 3
    for name, values in attitude_frames(st, 3):
        CODEC.encode(name, 0, values)  # within the DBC's ranges


@pytest.mark.parametrize("k", [0, 1, MAX_NEIGHBOURS, MAX_NEIGHBOURS + 4])
def test_neighbour_list_positions_are_relative_and_at_most_15(k: int) -> None:
    own = _state()
    frames = neighbour_frames(own, _neighbours(k), nb_set=7)
    sent = min(k, MAX_NEIGHBOURS)
    if sent == 0:
        assert frames == [("NEIGHBOR_MOTION", {"nb_slot": 0, "nb_count": 0, "nb_heading_rad": 0.0,
                                               "nb_airspeed_mps": 0.0, "nb_vz_mps": 0.0,
                                               "nb_set": 7})]
        return
    assert [n for n, _ in frames] == ["NEIGHBOR_POS", "NEIGHBOR_MOTION"] * sent
    for i in range(sent):
        pos, motion = frames[2 * i][1], frames[2 * i + 1][1]
        assert (pos["nb_slot"], pos["nb_dx_m"], pos["nb_dy_m"], pos["nb_dz_m"]) == (
            i, 10.0 + i, -2.0 * i, -10.0)
        assert (motion["nb_slot"], motion["nb_count"], motion["nb_set"]) == (i, sent, 7)


@pytest.mark.parametrize(("has_state", "link", "mode"), [
    (False, "up", "INIT"), (True, "up", "RUN"), (True, "bus_off", "BUS_OFF"),
    (True, "degraded", "DEGRADED"), (True, "down", "DEGRADED"),
])
def test_bridge_mode(has_state: bool, link: str, mode: str) -> None:
    assert bridge_mode(has_state, link) == BRIDGE_MODES[mode]


@pytest.mark.parametrize(("has_cmd", "age_s", "ap_fault", "state"), [
    (False, 0.5, False, "WAITING"), (False, 3.5, False, "FAILSAFE"),
    (True, 0.5, False, "FRESH"), (True, 1.0, False, "FRESH"), (True, 1.5, False, "HOLD"),
    (True, 3.0, False, "HOLD"), (True, 3.5, False, "FAILSAFE"), (True, 0.1, True, "FAILSAFE"),
])
def test_command_supervision_states(has_cmd: bool, age_s: float, ap_fault: bool,
                                    state: str) -> None:
    assert next_cmd_state(has_cmd=has_cmd, age_s=age_s, ap_fault=ap_fault, cmd_timeout_s=1.0,
                          failsafe_after_s=3.0) == CMD_STATES[state]


def test_endpoint_counts_and_reports_errors_and_its_loops_go_on() -> None:
    """A task or handler that raises is counted and reported; the loops keep running."""
    counts: Counter[str] = Counter()
    lock = threading.Lock()

    def count(key: str) -> None:
        with lock:
            counts[key] += 1

    channel = unique("endpoint-")
    faults = Faults("ep")
    ep = CanEndpoint("ep", CanBusConfig.from_params(interface="virtual", channel=channel),
                     faults=faults, count=count)
    peer = CanEndpoint("peer", CanBusConfig.from_params(interface="virtual", channel=channel),
                       faults=Faults("peer"), count=count)
    ticks: list[float] = []
    frames: list[str] = []

    def task(now: float) -> None:
        ticks.append(now)
        if len(ticks) == 2:
            raise RuntimeError("task bug")

    def handle(frame: object) -> None:
        frames.append(str(frame))
        if len(frames) == 1:
            raise KeyError("handler bug")

    assert ep.open() and not ep.open()
    assert peer.open()
    try:
        ep.run(handle, [(0.01, task)], rx_place="handling CAN frame", tx_place="cycle")
        values = {"ap_counter": 1, "ap_mode": 1, "ap_controller": 0, "ap_state_age_ms": 0.0,
                  "ap_rx_errors": 0}
        assert wait_until(lambda: len(ticks) >= 5)
        for _ in range(3):
            assert peer.send("AUTOPILOT_HEARTBEAT", 0, values)
        assert wait_until(lambda: len(frames) == 3)
        with lock:
            assert counts["loop_errors"] == 2
        assert faults.counts() == {"cycle": 1, "handling CAN frame AUTOPILOT_HEARTBEAT": 1}
        assert all(t.is_alive() for t in ep.threads)
        assert ep.stats()["can_state"] == "up"
    finally:
        ep.stop()
        peer.stop()
    assert not ep.threads and not ep.open()
