"""``launch/px4_glider.yaml`` in processes, PX4 played by the protocol double (its own
process; CI has no firmware): the domain's SITL port, lockstep across processes, the sonar's
echoes as DISTANCE_SENSOR per ear pointing down, a clean exit 0 with every count in the
summary."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from hil_bridge.bus.domain import Domain

pytestmark = pytest.mark.processes

ROOT = Path(__file__).resolve().parents[3]
LAUNCH = ROOT / "launch" / "px4_glider.yaml"
STEPS = 1500


def test_the_px4_launch_flies_a_double_in_lockstep_with_echo_ranges(domain: Domain) -> None:
    assert domain.number is not None
    cmd = [sys.executable, "-m", "hil_bridge.cli", "launch", str(LAUNCH), "--domain",
           str(domain.number), "--duration", "300", "--json", "--speed", "max"]
    launch = subprocess.Popen(cmd, cwd=ROOT, text=True, stdout=subprocess.PIPE,
                              stderr=subprocess.PIPE, env=dict(os.environ, PYTHONUNBUFFERED="1"))
    try:
        assert launch.stderr is not None
        for line in launch.stderr:
            if "echoloop launch: running" in line:
                break
        else:
            pytest.fail("the launch never ran")
        px4 = subprocess.run(
            [sys.executable, "-m", "drivers.mocks.px4_double", "--url",
             f"tcp://127.0.0.1:{4560 + domain.number}", "--steps", str(STEPS), "--timeout",
             "60"], capture_output=True, text=True, timeout=240)
        launch.send_signal(signal.SIGTERM)
        out, err = launch.communicate(timeout=120)
    finally:
        if launch.poll() is None:
            launch.kill()
            launch.communicate()
    report = json.loads(px4.stdout.splitlines()[-1])
    assert px4.returncode == 0, report.get("error")
    assert launch.returncode == 0, err[-3000:]
    assert np.all(np.diff(report["sensor_times"]) == 4000)
    nodes = json.loads(out)["nodes"]
    node, server, pinger = nodes["px4"], nodes["server"], nodes["pinger"]
    assert node["port"] == 4560 + domain.number and node["px4_connects"] == 1
    assert node["states_nonfinite"] == 0 and node["messages_bad"] == 0
    assert server["registered"] == [7] and server["surfaces_rejected"] == 0
    assert server["surfaces_applied"] >= STEPS - 1
    assert pinger["echoes_received"] > 0
    ranges = report["distances"]
    assert ranges and {d["id"] for d in ranges} == {0, 1}  # one per ear
    assert {d["orientation"] for d in ranges} == {25}  # the sonar looks down
    assert all(d["min_distance"] == 20 and d["max_distance"] == 1000 for d in ranges)
    assert node["ranges"]["distance_messages"] >= len(ranges)
