"""The demo in lockstep, twice: 0 stalls, and the same states, pings and echoes at every stamp.

`launch/demo.yaml` with `server.scene.clock.mode=lockstep`: the mock autopilots answer each
state step over CAN, the mock sonar head pings on sim time over the pty, the server waits for
both; with every node a thread of the test's process (a mem:// bus), and with every node a
process of its own (a numbered domain's ZeroMQ bus and loopback CAN). Six processes on a
loaded 2-core machine can be descheduled for a second, so that run waits up to 10 s for a step
(`lockstep_timeout_s`; it only bounds a hang, and a stall would still fail the test). Two runs
of different (wall) lengths must agree wherever both have data: every glider state at every
common stamp, every sim-time ping and every echo, bit for bit. Each run ends at a sim time (a
watcher on the bus stops it), so a loaded machine shortens nothing: the sonar vehicle first has
leaves in its beam from the ping at 5.2 s. Every ping the adapter publishes reaches the
server (the launch's proxy is up before any node and every endpoint syncs before it starts).
"""

from __future__ import annotations

import contextlib
import dataclasses
import threading
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from hil_bridge.bus.codec import decode_payload
from hil_bridge.bus.domain import Domain, claim_first_free, current, use
from hil_bridge.bus.messages import Clock
from hil_bridge.bus.node import Node
from hil_bridge.bus.qos import SENSOR
from hil_bridge.launch.runner import RunSummary, load, parse_param_overrides, run
from hil_bridge.recording.bag import read_bag

ROOT = Path(__file__).resolve().parents[2]


@pytest.fixture(params=["threads", pytest.param("processes", marks=pytest.mark.processes)])
def mode(request: pytest.FixtureRequest) -> Iterator[str]:
    """Where the nodes run; processes need a numbered domain (claimed for the test)."""
    with contextlib.ExitStack() as stack:
        if request.param == "processes":
            dom, _ = stack.enter_context(claim_first_free(Domain(60)))
            stack.enter_context(use(dom))
        yield request.param


def _run(tmp_path: Path, name: str, sim_s: float,
         mode: str) -> tuple[RunSummary, dict[str, Any]]:
    """The lockstep demo until ``/clock`` reaches ``sim_s``, recorded; its summary and what
    the recording holds."""
    overrides = ["server.scene.clock.mode=lockstep"]
    if mode == "processes":
        overrides.append("server.scene.clock.lockstep_timeout_s=10")
    spec = load(ROOT / "launch" / "demo.yaml",
                params_overrides=parse_param_overrides(overrides))
    mcap = tmp_path / f"{name}.mcap"
    reached = threading.Event()
    watcher = Node("sim_time_watcher", bus=current().bus_url)
    watcher.create_subscription(
        Clock, "/clock", lambda c: reached.set() if c.stamp_ns >= sim_s * 1e9 else None, SENSOR)
    watcher.start()
    try:
        summary = run(spec, duration=120.0, record=mcap, handle_signals=False,
                      stop_event=reached, domain=current())
    finally:
        watcher.stop()
    assert reached.is_set(), f"the run ended before sim time {sim_s} s"
    states: dict[tuple[str, int], Any] = {}
    pings: dict[int, Any] = {}
    echoes: dict[int, Any] = {}
    for m in read_bag(mcap):
        if m.topic.startswith("/glider/") and m.topic.endswith("/state"):
            msg = decode_payload(m.header.type, m.header.v, m.payload)
            states[(m.topic, msg.stamp_ns)] = msg
        elif m.topic == "/sonar/0/ping":
            msg = decode_payload(m.header.type, m.header.v, m.payload)
            if msg.next_ns >= 0:  # sim-time pings (the head's own-clock ones are not answered)
                pings[msg.ping_seq] = msg
        elif m.topic == "/sonar/0/echo":
            msg = decode_payload(m.header.type, m.header.v, m.payload)
            echoes[msg.ping_seq] = msg
    return summary, {"states": states, "pings": pings, "echoes": echoes}


def _echo_content(msg: Any) -> dict[str, Any]:
    """An echo's fields that the simulation decides (its stamp and compute time are wall-time)."""
    return {f.name: getattr(msg, f.name) for f in dataclasses.fields(msg)
            if f.name not in ("stamp_ns", "compute_ns")}


def test_lockstep_demo_twice_gives_identical_states_pings_and_echoes(tmp_path: Path,
                                                                    mode: str) -> None:
    first, a = _run(tmp_path, "a", 8.4, mode)
    second, b = _run(tmp_path, "b", 7.0, mode)
    for summary in (first, second):
        assert summary.mode == mode
        server = summary.nodes["server"]
        assert server["clock_mode"] == "lockstep" and server["tick_error"] == ""
        lockstep = {k: v for k, v in server.items() if k.startswith(
            ("stall", "lockstep", "freewheel", "sonars_free", "ticks", "sim_time", "ping", "cmd"))}
        assert server["stalls"] == 0, (f"{lockstep} wall {summary.wall_s:.1f} s; head "
                                       f"{summary.nodes['sonar_head_mock']}; adapter "
                                       f"{summary.nodes['sonar_head']}; server topics "
                                       f"{server.get('topics')}")
        assert summary.nodes["sonar_head_mock"]["lockstep_starts"] == 1
        # the bus lost nothing: every ping the adapter published reached the server
        published = summary.nodes["sonar_head"]["topics"]["/sonar/0/ping"]["sent"]
        assert server["pings_received"] == published, (server["pings_received"], published)
        assert summary.exit_status == 0, summary.failures
    common = sorted(set(a["states"]) & set(b["states"]))
    assert len(common) >= 9 * 50
    different = [key for key in common if a["states"][key] != b["states"][key]]
    assert different == [], f"{len(different)} of {len(common)} states differ, first {different[0]}"
    assert {topic for topic, _ in common} == {f"/glider/{g}/state" for g in (*range(8), 100)}
    # the sonar vehicle was flown by its autopilot (commanded), not along the scripted path
    assert first.nodes["server"]["cmd_applied"] > 100

    seqs = sorted(set(a["pings"]) & set(b["pings"]))
    assert len(seqs) >= 5 and seqs == list(range(len(seqs)))
    for seq in seqs:
        pa, pb = a["pings"][seq], b["pings"][seq]
        assert pa == pb
        assert pa.stamp_ns == seq * 200_000_000  # 5 Hz of sim time, from sim time 0
    echoed = sorted(set(a["echoes"]) & set(b["echoes"]))
    assert len(echoed) >= 5
    for seq in echoed:
        ea, eb = _echo_content(a["echoes"][seq]), _echo_content(b["echoes"][seq])
        for key in ("samples", "position", "orientation", "boresight", "boresight_body"):  # arrays
            np.testing.assert_array_equal(ea.pop(key), eb.pop(key))
        assert ea == eb
    assert any(a["echoes"][seq].leaves_in_beam > 0 for seq in echoed)
