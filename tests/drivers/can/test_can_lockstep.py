"""Lockstep over CAN: the mock answers each lockstep sample once; the adapter sends each new
state step once (neighbours inside the sample), maps answers back to steps, ages in sim time."""

from __future__ import annotations

import math
import threading
from collections.abc import Iterator

import can
import numpy as np
import pytest

from drivers.can.adapter import AutopilotAdapter
from drivers.can.codec import DecodedFrame, GliderCanCodec
from drivers.can.supervision import CMD_STATES
from drivers.mocks.autopilot import MockAutopilot
from hil_bridge.bus.messages import Clock, GliderCmd, GliderNeighbors, GliderState
from hil_bridge.bus.node import Node
from sim_core.soaring.boids import GliderObs, controller_command
from sim_core.soaring.law import Law
from tests.drivers.can._util import unique, wait_until

CODEC = GliderCanCodec()


class Bridge:
    """A hand-driven bridge end on a raw virtual bus."""

    def __init__(self, channel: str) -> None:
        self.bus = can.Bus(interface="virtual", channel=channel)
        self.frames: list[DecodedFrame] = []

    def send(self, name: str, node: int, **signals: float) -> None:
        self.bus.send(CODEC.encode(name, node, signals))

    def sample(self, node: int, counter: int, *, lockstep: int, x: float = 5.0,
               neighbours: list[float] | None = None) -> None:
        """POS, optionally a one-neighbour list (dx), then MOTION."""
        self.send("GLIDER_STATE_POS", node, x_m=x, y_m=0.0, z_m=400.0, lockstep=lockstep)
        for slot, dx in enumerate(neighbours or []):
            self.send("NEIGHBOR_POS", node, nb_slot=slot, nb_dx_m=dx, nb_dy_m=20.0, nb_dz_m=0.0)
            self.send("NEIGHBOR_MOTION", node, nb_slot=slot, nb_count=len(neighbours or []),
                      nb_heading_rad=1.0, nb_airspeed_mps=10.0, nb_vz_mps=0.5, nb_set=counter)
        self.send("GLIDER_STATE_MOTION", node, heading_rad=0.3, bank_rad=0.0, airspeed_mps=10.0,
                  vz_mps=0.0, alive=1, state_counter=counter)

    def commands(self) -> list[DecodedFrame]:
        while (msg := self.bus.recv(0.0)) is not None:
            self.frames.append(CODEC.decode(msg))
        return [f for f in self.frames if f.name == "AUTOPILOT_CMD"]


@pytest.fixture
def bridge_mock() -> Iterator[tuple[Bridge, MockAutopilot]]:
    channel = unique("lockstep-")
    bridge = Bridge(channel)
    mock = MockAutopilot("mock", channel=channel, gliders=[3], controller="unified",
                         rate_hz=0.5, heartbeat_hz=50.0)
    mock.start()
    yield bridge, mock
    mock.stop()
    bridge.bus.shutdown()


def test_mock_answers_every_lockstep_sample_once_with_its_neighbours(
    bridge_mock: tuple[Bridge, MockAutopilot]
) -> None:
    bridge, mock = bridge_mock
    # the first sample cannot be bound to a counter yet (no previous one): dropped, unanswered
    bridge.sample(3, 15, lockstep=1)
    assert wait_until(lambda: mock.stats().get("rx_samples_unverified") == 1)
    for counter in range(6):
        bridge.sample(3, counter, lockstep=1, x=5.0 + counter, neighbours=[30.0, -15.0])
        assert wait_until(lambda n=counter: len(bridge.commands()) == n + 1)
    answers = bridge.commands()
    assert [int(f.signals["answer"]) for f in answers] == [1] * 6
    assert [int(f.signals["answer_counter"]) for f in answers] == list(range(6))
    # the command is seed 002's Boids on this sample and the list sent inside it
    own = GliderObs(x=10.0, y=0.0, z=400.0, heading=0.3, speed=10.0, vz=0.0)
    nbs = np.array([[40.0, 20.0, 400.0, 1.0, 10.0, 0.5], [-5.0, 20.0, 400.0, 1.0, 10.0, 0.5]])
    law = Law()
    bank, speed = controller_command(own, nbs, law, controller="unified")
    last = answers[-1].signals
    assert last["bank_cmd_rad"] == pytest.approx(min(max(bank, law.bankMin), law.bankMax),
                                                 abs=1e-4)
    assert last["airspeed_cmd_mps"] == pytest.approx(
        min(max(speed, law.forwardSpeedMin), law.forwardSpeedMax), abs=0.01)
    assert mock.stats()["lockstep_answers"] == 6


def test_mock_leaves_lockstep_nodes_to_the_samples(
    bridge_mock: tuple[Bridge, MockAutopilot]
) -> None:
    """At a 50 Hz control rate the timer would command; a lockstep node is commanded only when
    a sample asks, a node back on the periodic stream by the timer again."""
    channel = unique("lockstep-fast-")
    bridge = Bridge(channel)
    mock = MockAutopilot("mock", channel=channel, gliders=[1], controller="path", rate_hz=50.0)
    mock.start()
    try:
        bridge.sample(1, 15, lockstep=1)  # binds the counter, unanswered (see above)
        bridge.sample(1, 0, lockstep=1)
        assert wait_until(lambda: len(bridge.commands()) == 1)
        threading.Event().wait(0.3)
        assert len(bridge.commands()) == 1
        bridge.sample(1, 1, lockstep=0)
        assert wait_until(lambda: len(bridge.commands()) >= 5)
        assert all(f.signals["answer"] == 0 for f in bridge.commands()[1:])
    finally:
        mock.stop()
        bridge.bus.shutdown()


@pytest.fixture
def adapter_rig() -> Iterator[tuple[Node, Bridge, AutopilotAdapter, list[GliderCmd]]]:
    bus, channel = f"mem://{unique('ls-')}", unique("lsch-")
    sim = Node("sim", bus=bus, diagnostics_period_s=0)
    bridge = Bridge(channel)
    adapter = AutopilotAdapter("autopilot", bus=bus, channel=channel, gliders={7: 2, 100: 5},
                               heartbeat_hz=50.0, cmd_timeout_s=0.05, failsafe_after_s=0.1)
    cmds: list[GliderCmd] = []
    lock = threading.Lock()

    def on_cmd(msg: GliderCmd) -> None:
        with lock:
            cmds.append(msg)

    sim.create_subscription(GliderCmd, "/glider/7/cmd", on_cmd)
    adapter.start()
    sim.start()
    yield sim, bridge, adapter, cmds
    sim.stop()
    adapter.stop()
    bridge.bus.shutdown()


def _state(step: int, stamp: int) -> GliderState:
    return GliderState(stamp_ns=stamp, x=1.0 + step, y=2.0, z=300.0, heading=0.1, bank=0.0,
                       airspeed=10.0, vz=0.0, alive=True, glider_id=7, step=step)


def test_adapter_sends_each_step_once_and_maps_answers_to_steps(
    adapter_rig: tuple[Node, Bridge, AutopilotAdapter, list[GliderCmd]]
) -> None:
    sim, bridge, adapter, cmds = adapter_rig
    clock = sim.create_publisher(Clock, "/clock")
    states = sim.create_publisher(GliderState, "/glider/7/state")
    nbs = sim.create_publisher(GliderNeighbors, "/glider/7/neighbors")
    assert states.wait_for_subscribers(5.0) and clock.wait_for_subscribers(5.0)

    def frames(name: str) -> list[DecodedFrame]:
        bridge.commands()
        return [f for f in bridge.frames if f.name == name and f.node_id == 2]

    clock.publish(Clock(stamp_ns=0, lockstep=True))
    nbs.publish(GliderNeighbors(stamp_ns=0, glider_id=7, ids=[8], x=[11.0], y=[2.0], z=[300.0],
                                heading=[0.0], bank=[0.0], airspeed=[9.0], vz=[0.0], step=0))
    for stamp in (0, 20, 40):  # one step, held over three ticks: one sample
        clock.publish(Clock(stamp_ns=stamp, lockstep=True))
        states.publish(_state(0, stamp))
    assert wait_until(lambda: len(frames("GLIDER_STATE_MOTION")) == 1)
    threading.Event().wait(0.2)
    assert len(frames("GLIDER_STATE_MOTION")) == 1  # and no periodic stream in lockstep
    order = [f.name for f in bridge.frames if f.node_id == 2 and f.name.startswith(("GLIDER",
                                                                                   "NEIGHBOR"))]
    assert order == ["GLIDER_STATE_POS", "NEIGHBOR_POS", "NEIGHBOR_MOTION", "GLIDER_STATE_MOTION"]
    pos = frames("GLIDER_STATE_POS")[0]
    assert pos.signals["lockstep"] == 1
    counter = int(frames("GLIDER_STATE_MOTION")[0].signals["state_counter"])
    # the server re-sends the same tick (same stamp): the unanswered sample goes again
    states.publish(_state(0, 40))
    assert wait_until(lambda: len(frames("GLIDER_STATE_MOTION")) == 2)
    # the autopilot answers the first sample: published with that sample's step and stamp
    bridge.send("AUTOPILOT_CMD", 2, bank_cmd_rad=0.2, airspeed_cmd_mps=11.0, cmd_counter=1,
                answer=1, answer_counter=counter)
    assert wait_until(lambda: len(cmds) == 1)
    assert (cmds[0].step, cmds[0].stamp_ns, cmds[0].bank_cmd) == (0, 0, pytest.approx(0.2))
    states.publish(_state(0, 40))  # answered now: a repeat is not sent again
    clock.publish(Clock(stamp_ns=60, lockstep=True))
    states.publish(_state(1, 60))
    assert wait_until(lambda: len(frames("GLIDER_STATE_MOTION")) == 3)
    # sim time stands still (the server waits for someone else): commands never age into HOLD
    threading.Event().wait(0.3)
    assert adapter.cmd_state(7) == "FRESH"
    assert all(c.step == 0 for c in cmds) and adapter.stats()["lockstep_answers"] == 1
    # sim time moves on without an answer: HOLD, then FAILSAFE, in sim seconds; both carry
    # the step of the last command, so a lockstep server does not take them as answers
    clock.publish(Clock(stamp_ns=60 + 200_000_000, lockstep=True))
    assert wait_until(lambda: adapter.cmd_state(7) == "FAILSAFE")
    assert wait_until(lambda: len(cmds) > 1)  # the failsafe command crosses the bus after
    assert all(c.step == 0 for c in cmds)
    assert CMD_STATES["FAILSAFE"] == 3 and math.isfinite(cmds[-1].airspeed_cmd)
