"""``launch/ardupilot_glider.yaml`` in processes, SITL played by the protocol double from this
process (CI has no firmware): the domain's SITL port, lockstep across processes, the sonar on
the 6-DoF glider answered, a clean exit 0 with every count in the summary."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from drivers.mocks.sitl_double import SitlDouble, WingLeveler
from hil_bridge.bus.domain import Domain

pytestmark = pytest.mark.processes

ROOT = Path(__file__).resolve().parents[3]
LAUNCH = ROOT / "launch" / "ardupilot_glider.yaml"
FRAMES = 1500


def test_the_glider_launch_flies_a_double_in_lockstep(domain: Domain) -> None:
    answers, summary = _fly(domain, LAUNCH, frames=FRAMES, bank_deg=15.0)
    stamps = np.array([a["timestamp"] for a in answers])
    np.testing.assert_allclose(np.diff(stamps), 1 / 250, rtol=0, atol=1e-9)
    nodes = summary["nodes"]
    sitl, server, pinger = nodes["sitl"], nodes["server"], nodes["pinger"]
    assert sitl["vehicles"]["7"]["instance"] == domain.number
    assert sitl["frames"] == sitl["replies"] == FRAMES
    assert sitl["packets_bad"] == sitl["replies_stale"] == sitl["states_nonfinite"] == 0
    assert server["surfaces_applied"] == FRAMES - 1 and server["surfaces_rejected"] == 0
    assert server["registered"] == [7]
    assert pinger["echoes_received"] > 0  # the sonar rides the 6-DoF glider
    # gliding: it lost height at about its sink rate (NED down grows), at about 19.5 m/s
    assert answers[-1]["position"][2] > answers[0]["position"][2]
    assert answers[-1]["airspeed"] == pytest.approx(19.5, abs=2.0)


SHORT = {"description": "one 6-DoF glider and the SITL node, lockstep at 250 Hz", "nodes": [
    {"name": "server", "entry": "hil_bridge.server:SimServer", "params": {
        "autopilots": [7], "scene": {
            "clock": {"mode": "lockstep", "lockstep_timeout_s": 5.0,
                      "lockstep_start_timeout_s": 120.0},
            "vehicles": [{"id": 7, "sixdof": {}, "path": {
                "kind": "points", "points": [[0, 0, 400], [700, 0, 400]]}}]}}},
    {"name": "sitl", "entry": "drivers.ardupilot.sitl:ArduPilotSitl",
     "params": {"instances": [{"vehicle_id": 7}]}},
]}


def _fly(domain: Domain, launch: Path, *args: str, frames: int, bank_deg: float = 20.0
         ) -> tuple[list[dict], dict]:
    """Launch ``launch`` (with ``args``) in ``domain``, fly ``frames`` frames of the double
    holding ``bank_deg``: its answers and the launch's JSON summary (exit 0 asserted)."""
    assert domain.number is not None
    proc = subprocess.Popen(
        [sys.executable, "-m", "hil_bridge.cli", "launch", str(launch), "--domain",
         str(domain.number), "--duration", "300", "--json", *args], cwd=ROOT, text=True,
        stdout=subprocess.PIPE, stderr=subprocess.PIPE, env=dict(os.environ, PYTHONUNBUFFERED="1"))
    try:
        assert proc.stderr is not None
        for line in proc.stderr:
            if "echoloop launch: running" in line:
                break
        else:
            pytest.fail("the launch never ran")
        double = SitlDouble(port=9002 + 10 * domain.number, timeout_s=60.0)
        try:
            answers = double.fly(frames, WingLeveler(bank_deg=bank_deg))
        finally:
            double.close()
        proc.send_signal(signal.SIGTERM)
        out, err = proc.communicate(timeout=120)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.communicate()
    assert proc.returncode == 0, err[-3000:]
    return answers, json.loads(out)


def test_composed_at_full_speed_flies_the_bits_of_isolated_processes_paced(
        domain: Domain, tmp_path: Path) -> None:
    """The server and the SITL node composed in one process, unpaced (``--speed max``), and
    each in a process of its own paced at real time (``--isolate --speed 1``): the same
    answers to SITL, bit for bit, frame by frame (one machine, lockstep)."""
    import yaml

    launch = tmp_path / "short.yaml"
    launch.write_text(yaml.safe_dump(SHORT))
    fast, fast_run = _fly(domain, launch, "--speed", "max", frames=250)
    paced, paced_run = _fly(domain, launch, "--isolate", "--speed", "1", frames=250)
    assert fast == paced
    local = fast_run["nodes"]["sitl"]
    assert local["replies"] == 250 and local["replies_stale"] == 0
    assert fast_run["containers"] == {"lockstep": ["server", "sitl"]}
    assert paced_run["containers"] == {}
    assert paced_run["wall_s"] > 250 / 250  # paced: not faster than real time
