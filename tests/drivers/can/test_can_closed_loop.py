"""The CAN half of the closed loop: SimServer ⇄ AutopilotAdapter ⇄ faulty CAN ⇄ MockAutopilot."""

from __future__ import annotations

import threading

from drivers.can.adapter import AutopilotAdapter
from drivers.faults.can_bus import FaultInjectingBus
from drivers.mocks.autopilot import MockAutopilot
from hil_bridge.bus.messages import GliderCmd, GliderState
from hil_bridge.bus.node import Node
from hil_bridge.server.sim_server import SimServer
from tests.drivers.can._util import unique, wait_until


def test_swarm_flies_on_can_commands_through_faults() -> None:
    bus, channel = f"mem://{unique('loop-')}", unique("loop-")
    scene = {"seed": 4, "state_rate_hz": 50, "clock": {"mode": "realtime", "rate": 4.0},
             "swarm": {"law": "default", "overrides": {"numAgents": 4}}}
    faults = {"seed": 9, "error_frame_rate": 0.02, "truncate_rate": 0.02, "foreign_rate": 0.02,
              "enobufs_rate": 0.02, "enobufs_burst": 2}
    server = SimServer("server", bus=bus, scene=scene)
    adapter = AutopilotAdapter("autopilot", bus=bus, channel=channel, gliders=[0, 1, 2, 3],
                               faults=faults)
    mock = MockAutopilot("mock", channel=channel, gliders=[0, 1, 2, 3], rate_hz=8.0)
    probe = Node("probe", bus=bus, diagnostics_period_s=0)
    lock = threading.Lock()
    banks: list[float] = []
    cmds: list[float] = []

    def on_state(msg: GliderState) -> None:
        with lock:
            banks.append(msg.bank)

    def on_cmd(msg: GliderCmd) -> None:
        with lock:
            cmds.append(msg.bank_cmd)

    probe.create_subscription(GliderState, "/glider/0/state", on_state)
    probe.create_subscription(GliderCmd, "/glider/0/cmd", on_cmd)
    nodes = [probe, server, adapter, mock]
    try:
        for node in nodes:
            node.start()
        assert wait_until(lambda: server.stats()["cmd_applied"] >= 40, timeout=20.0)
        link = adapter.can.link
        assert link is not None and isinstance(link.bus, FaultInjectingBus)
        link.bus.inject_bus_off(30.0)
        assert wait_until(lambda: adapter.stats().get("can_bus_off_recoveries", 0) >= 1)
        applied = server.stats()["cmd_applied"]
        assert wait_until(lambda: server.stats()["cmd_applied"] >= applied + 40, timeout=20.0)
        with lock:
            commanded = {round(max(-0.261799, min(0.261799, b)), 6) for b in cmds}
            flown = [round(b, 6) for b in banks]
        assert sum(b in commanded for b in flown) >= 10
        assert len(set(flown)) >= 2  # the bank changes with the commands
        stats = adapter.stats()
        assert stats["can_error_frames"] > 0 and stats["rx_decode_errors"] > 0
        assert stats["cmd_state:0"] == 1 and all(t.is_alive() for t in adapter.can.threads)
        assert server.stats()["gliders_alive"] == 4 and server.stats()["cmd_rejected"] == 0
    finally:
        for node in reversed(nodes):
            node.stop()
