"""Real firmware: ArduPlane SITL flies ``launch/ardupilot_glider.yaml``'s glider into the thermal.

Runs only where ``ECHOLOOP_ARDUPILOT_SITL`` names an ``arduplane`` binary (built by the user from
ArduPilot, outside this repository). The launch serves SITL instance N (the claimed domain);
``arduplane -I N --model JSON:127.0.0.1`` flies with ``launch/data/ardupilot/echoloop-sgs126.parm``
in CRUISE towards the 3 m/s thermal 700 m ahead; the firmware's soaring code must switch to mode
THERMAL and the glider must climb in it.
"""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from collections.abc import Iterator
from pathlib import Path

import pytest

from hil_bridge.bus.domain import Domain, claim_first_free

SITL = os.environ.get("ECHOLOOP_ARDUPILOT_SITL", "")
pytestmark = [
    pytest.mark.processes,
    pytest.mark.skipif(not (SITL and os.access(SITL, os.X_OK)),
                       reason="ECHOLOOP_ARDUPILOT_SITL does not name an arduplane binary"),
]

ROOT = Path(__file__).resolve().parents[3]
LAUNCH = ROOT / "launch" / "ardupilot_glider.yaml"
PARM = ROOT / "launch" / "data" / "ardupilot" / "echoloop-sgs126.parm"
CRUISE, THERMAL = 7, 24  # ArduPlane's mode numbers
CLIMB_M = 30.0


@pytest.fixture
def domain() -> Iterator[Domain]:
    with claim_first_free(Domain(int.from_bytes(os.urandom(1)) % 40 + 20)) as (dom, _):
        yield dom


def _stop(proc: subprocess.Popen[str]) -> None:
    if proc.poll() is None:
        proc.send_signal(signal.SIGTERM)
        try:
            proc.wait(timeout=60)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait()


def test_arduplane_enters_thermal_and_climbs(domain: Domain, tmp_path: Path) -> None:
    from pymavlink import mavutil

    n = domain.number
    assert n is not None
    launch = subprocess.Popen(
        [sys.executable, "-m", "hil_bridge.cli", "launch", str(LAUNCH), "--domain", str(n),
         "--duration", "1800"], cwd=ROOT, text=True, stdout=subprocess.DEVNULL,
        stderr=subprocess.DEVNULL)
    firmware = subprocess.Popen(
        [SITL, "--model", "JSON:127.0.0.1", "-I", str(n), "-w", "--home", "47.0,8.0,0,90",
         "--defaults", str(PARM)], cwd=tmp_path, text=True, stdout=subprocess.DEVNULL,
        stderr=subprocess.DEVNULL)
    try:
        mav = mavutil.mavlink_connection(f"tcp:127.0.0.1:{5760 + 10 * n}", retries=60)
        assert mav.wait_heartbeat(timeout=120) is not None, "no heartbeat from SITL"
        mav.mav.param_set_send(mav.target_system, mav.target_component, b"ARMING_CHECK", 0,
                               mavutil.mavlink.MAV_PARAM_TYPE_REAL32)
        mav.set_mode(CRUISE)
        mav.mav.command_long_send(mav.target_system, mav.target_component,
                                  mavutil.mavlink.MAV_CMD_COMPONENT_ARM_DISARM, 0, 1, 21196,
                                  0, 0, 0, 0, 0)
        thermal_alt: float | None = None
        best = -1e9
        deadline = time.monotonic() + 900
        while time.monotonic() < deadline:
            msg = mav.recv_match(type=["HEARTBEAT", "GLOBAL_POSITION_INT"], blocking=True,
                                 timeout=5)
            if msg is None:
                continue
            if msg.get_type() == "HEARTBEAT" and msg.custom_mode == THERMAL and (
                    thermal_alt is None):
                thermal_alt = best
            elif msg.get_type() == "GLOBAL_POSITION_INT":
                best = msg.relative_alt / 1000.0 if thermal_alt is None else max(
                    best, msg.relative_alt / 1000.0)
                if thermal_alt is not None and best - thermal_alt >= CLIMB_M:
                    break
        assert thermal_alt is not None, "ArduPlane never switched to THERMAL"
        assert best - thermal_alt >= CLIMB_M, (
            f"in THERMAL from {thermal_alt:.0f} m the glider reached only {best:.0f} m")
    finally:
        _stop(firmware)
        _stop(launch)
