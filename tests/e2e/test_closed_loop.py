"""The closed loop of `make demo` (launch/demo.yaml), short and in-process.

Server + serial sonar-head adapter + mock head on a pty + CAN adapter + mock autopilots on a
python-can virtual bus. Asserts that echoes arrive complete at the mock head and that the
autopilots' commands (sent as CAN frames, forwarded as /glider/<id>/cmd) set the gliders' bank.
"""

from __future__ import annotations

import os
import threading
from pathlib import Path

import numpy as np

from hil_bridge.bus.messages import GliderCmd
from hil_bridge.bus.node import Node
from hil_bridge.bus.qos import QoSProfile
from hil_bridge.launch.runner import load, parse_param_overrides, run
from sim_core.soaring import Law

ROOT = Path(__file__).resolve().parents[2]
#: the observer must see every command the server may have flown
KEEP_ALL = QoSProfile("observer", depth=100_000)


def test_closed_loop_echoes_complete_and_commands_fly_the_gliders(tmp_path: Path) -> None:
    bus = f"mem://e2e_loop_{os.getpid()}"
    channel = f"e2e_glider_{os.getpid()}"
    link = tmp_path / "sonar0"
    overrides = parse_param_overrides([
        f"sonar_head_mock.link={link}",
        f"sonar_head.port={link}",
        f"autopilot.channel={channel}",
        f"mock_autopilot_swarm.channel={channel}",
        f"mock_autopilot_sonar.channel={channel}",
    ])
    spec = load(ROOT / "launch" / "demo.yaml", params_overrides=overrides)
    observed: dict[int, list[float]] = {}
    lock = threading.Lock()
    observer = Node("observer", bus=bus)
    for gid in (*range(8), 100):
        def on_cmd(msg: GliderCmd, gid: int = gid) -> None:
            with lock:
                observed.setdefault(gid, []).append(msg.bank_cmd)

        observer.create_subscription(GliderCmd, f"/glider/{gid}/cmd", on_cmd, KEEP_ALL)
    observer.start()
    try:
        summary = run(spec, duration=6.0, bus=bus, handle_signals=False)
    finally:
        observer.stop()

    head = summary.nodes["sonar_head_mock"]
    assert head["echoes_complete"] >= 5
    assert head["echoes_incomplete"] == 0
    assert head["pings_sent"] == (head["echoes_complete"] + head["echoes_incomplete"]
                                  + head["echo_timeouts"] + head["pings_in_flight"]), head
    assert head["crc_errors"] == 0

    server = summary.nodes["server"]
    assert server["tick_error"] == ""
    assert server["echoes_published"] >= head["echoes_complete"]
    assert server["cmd_applied"] > 0 and server["cmd_rejected"] == 0
    assert set(server["registered"]) == {*range(8), 100}
    law_bank = Law().bankMax  # the demo flies the packaged law
    flown = server["flown"]
    assert set(flown) == {str(g) for g in range(8)}
    for gid, row in flown.items():
        # the command held at the last control step is the (clipped) bank an autopilot sent
        # over CAN; the glider's bank follows it through the flight model's lag
        sent = np.clip(np.asarray(observed[int(gid)]), -law_bank, law_bank)
        assert np.any(np.isclose(sent, row["bank_cmd"], atol=1e-12)), (gid, row)
        assert abs(row["bank"]) <= law_bank + 1e-12
    assert server["external_steps"] >= 8 * 5
    # the sonar vehicle is flown by the path follower after the take-over
    assert observed[100]
    can = summary.nodes["autopilot"]
    assert can["cmd_forwarded"] > 0 and can["states_sent"] > 0
