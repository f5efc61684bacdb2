"""Composition (hil_bridge.bus.intra): nodes of one process hand messages over without decoding,
inline subscriptions run on the publishing thread, a topic published in the process is heard
from it only, everything else on the bus sees the same frames, and a launch composes a
lockstep server with its firmware nodes. (The node suite runs
over a composed bus too: ``bus_url``'s ``composed`` parameter.)"""

from __future__ import annotations

import dataclasses
import threading
from collections.abc import Iterator

import pytest

from hil_bridge.bus import intra
from hil_bridge.bus.codec import Envelope, decode_header, encode
from hil_bridge.bus.messages import Clock, GliderState
from hil_bridge.bus.node import Node
from hil_bridge.bus.proxy import Proxy
from hil_bridge.bus.qos import LATCHED, SENSOR
from hil_bridge.bus.transport import open_transport
from hil_bridge.launch.spec import LOCKSTEP_CONTAINER, compose_lockstep, load
from tests.hil_bridge.bus.bus_test_util import WAIT, poll_until

N = 50


@pytest.fixture
def composed() -> Iterator[str]:
    with Proxy("tcp://127.0.0.1:0", "tcp://127.0.0.1:0") as proxy:
        intra.compose(proxy.url)
        try:
            yield proxy.url
        finally:
            intra.release(proxy.url)


def _state(i: int) -> GliderState:
    return GliderState(stamp_ns=i, x=float(i), y=0.0, z=100.0, heading=0.0, bank=0.0,
                       airspeed=9.0, vz=0.0, glider_id=1)


def test_handed_over_in_process_and_the_same_frames_for_everyone_else(composed: str) -> None:
    got: list[tuple[Envelope, int]] = []
    queued: list[int] = []
    done = threading.Event()

    def on_state(env: Envelope) -> None:
        got.append((env, threading.get_ident()))
        if len(got) == N:
            done.set()

    with Node("server", bus=composed, diagnostics_period_s=0) as srv, \
            Node("firmware", bus=composed, diagnostics_period_s=0) as fw, \
            Node("logger", bus=composed, diagnostics_period_s=0) as log, \
            open_transport(composed) as outside:
        srv.start()
        fw.start()
        log.start()
        outside.subscribe(b"/glider/1/state\0")
        fw.create_subscription(GliderState, "/glider/1/state", on_state, SENSOR, envelope=True,
                               inline=True)
        log.create_subscription(GliderState, "/glider/1/state",
                                lambda m: queued.append(threading.get_ident()),
                                dataclasses.replace(SENSOR, depth=N))  # keeps all N
        pub = srv.create_publisher(GliderState, "/glider/1/state", exclusive=True)
        assert srv.transport.wait_for_subscriber("/glider/1/state", WAIT)  # the outside's
        for i in range(N):
            pub.publish(_state(i))
        assert done.wait(WAIT)
        frames = [outside.recv(WAIT) for _ in range(N)]
        assert poll_until(lambda: len(queued) == N)
    me = threading.get_ident()
    assert [e.msg for e, _ in got] == [_state(i) for i in range(N)]
    assert {t for _, t in got} == {me}  # each inline callback ran in publish()
    assert me not in set(queued)  # the other one on its node's executor
    # the process outside sees the frames, byte for byte what was handed over
    assert all(f is not None for f in frames)
    assert [f[2] for f in frames if f is not None] == [e.payload for e, _ in got]
    assert [decode_header(f[1]) for f in frames if f is not None] == [e.header for e, _ in got]
    topic = fw.stats()["topics"]["/glider/1/state"]
    assert topic["received"] == topic["local"] == N and topic["decode_errors"] == 0
    # owned here (exclusive): heard from here only (no transport subscription, nothing back)
    assert fw.stats()["loopback"] == log.stats()["loopback"] == 0
    assert fw.transport.stats()["received"] == 0


def test_a_topic_not_owned_here_is_heard_from_everywhere_and_its_copies_skipped(
        composed: str) -> None:
    got: list[GliderState] = []
    with Node("server", bus=composed, diagnostics_period_s=0) as srv, \
            Node("sitl", bus=composed, diagnostics_period_s=0) as sitl, \
            open_transport(composed) as elsewhere:
        srv.start()
        sitl.start()
        srv.create_subscription(GliderState, "/glider/1/state", got.append, SENSOR)
        here = sitl.create_publisher(GliderState, "/glider/1/state")
        assert elsewhere.wait_for_subscriber("/glider/1/state", WAIT)
        here.publish(_state(1))
        elsewhere.publish(encode("/glider/1/state", _state(2), seq=0, pub_ns=0, src="dronecan#1"))
        assert poll_until(lambda: len(got) == 2 and srv.stats()["loopback"] == 1)
    assert sorted(m.x for m in got) == [1.0, 2.0]
    topic = srv.stats()["topics"]["/glider/1/state"]
    assert topic["local"] == 1 and topic["received"] == 2


def test_a_late_subscription_gets_the_latched_message_in_process(composed: str) -> None:
    got: list[Clock] = []
    with Node("server", bus=composed, diagnostics_period_s=0) as srv, \
            Node("late", bus=composed, diagnostics_period_s=0) as late:
        srv.start()
        late.start()
        pub = srv.create_publisher(Clock, "/clock", LATCHED)
        pub.publish(Clock(stamp_ns=7))
        late.create_subscription(Clock, "/clock", got.append, LATCHED)
        assert poll_until(lambda: got == [Clock(stamp_ns=7)])
        assert late.stats()["topics"]["/clock"]["local"] == 1


def test_a_node_not_composed_keeps_the_transport(composed: str) -> None:
    intra.release(composed)
    with Node("plain", bus=composed, diagnostics_period_s=0) as node:
        assert node.intra is None and "#" in node.src
    assert not intra.composed(composed)


def _launch(compose: bool, clock: str) -> dict[str, object]:
    return {"compose_lockstep": compose, "nodes": [
        {"name": "server", "entry": "hil_bridge.server:SimServer", "params": {
            "autopilots": [7], "scene": {"clock": {"mode": clock}, "vehicles": [
                {"id": 7, "sixdof": {}, "path": {"kind": "points",
                                                 "points": [[0, 0, 400], [700, 0, 400]]}}]}}},
        {"name": "sitl", "entry": "drivers.ardupilot.sitl:ArduPilotSitl",
         "params": {"instances": [{"vehicle_id": 7}]}},
        {"name": "pinger", "entry": "hil_bridge.replay:Pinger"},
    ]}


def test_a_lockstep_launch_composes_its_server_and_firmware_nodes() -> None:
    spec = compose_lockstep(load(_launch(True, "lockstep")))
    assert [n.container for n in spec.nodes] == [LOCKSTEP_CONTAINER, LOCKSTEP_CONTAINER, ""]
    for off in (load(_launch(False, "lockstep")), load(_launch(True, "realtime"))):
        assert [n.container for n in compose_lockstep(off).nodes] == ["", "", ""]
