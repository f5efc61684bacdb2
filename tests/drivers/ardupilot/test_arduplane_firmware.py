"""Real firmware: ArduPlane SITL flies ``launch/ardupilot_glider.yaml``'s glider into the thermal.

Runs only where ``ECHOLOOP_ARDUPILOT_SITL`` names an ``arduplane`` binary (built by the user from
ArduPilot, outside this repository). The launch serves SITL instance N (the claimed domain) and
runs the firmware itself (``--param sitl.binary=...``: ``arduplane -I N --model JSON:127.0.0.1``
with the launch's parameter files, in the domain's directory), which boots while the glider
glides; once its EKF uses GPS, the test sets home to the scene's origin,
uploads ``launch/data/ardupilot/echoloop-thermal.waypoints`` (a mission east through the 4 m/s
thermal) and flies it in AUTO: the firmware's soaring code must switch to THERMAL and the glider
must climb 30 m above where it entered the thermal.
"""

from __future__ import annotations

import subprocess
import sys
import time
from pathlib import Path
from typing import Any

import pytest

from hil_bridge.bus.domain import Domain
from tests.drivers.firmware import SITL, needs_sitl, stop

pytestmark = [
    pytest.mark.processes,
    needs_sitl,
]

ROOT = Path(__file__).resolve().parents[3]
LAUNCH = ROOT / "launch" / "ardupilot_glider.yaml"
MISSION = ROOT / "launch" / "data" / "ardupilot" / "echoloop-thermal.waypoints"
AUTO, THERMAL = 10, 24  # ArduPlane's mode numbers
CLIMB_M = 30.0
ORIGIN = (47.0, 8.0, 0.0)  # the launch's sixdof origin: its firmware's --home, the mission's home


def _upload_mission(mav: Any, mavutil: Any) -> None:
    """The waypoint file (QGC WPL 110, as MAVProxy's ``wp load`` reads it) to the vehicle."""
    rows = [line.split("\t") for line in MISSION.read_text().splitlines()[1:] if line.strip()]
    mav.waypoint_count_send(len(rows))
    for _ in rows:
        req = mav.recv_match(type=["MISSION_REQUEST", "MISSION_REQUEST_INT"], blocking=True,
                             timeout=30)
        assert req is not None, "SITL asked for no mission item"
        r = rows[req.seq]
        mav.mav.mission_item_int_send(
            mav.target_system, mav.target_component, req.seq, int(r[2]), int(r[3]), 0, 1,
            *(float(v) for v in r[4:8]), round(float(r[8]) * 1e7), round(float(r[9]) * 1e7),
            float(r[10]))
    ack = mav.recv_match(type="MISSION_ACK", blocking=True, timeout=30)
    assert ack is not None and ack.type == 0, f"mission refused: {ack}"


def test_arduplane_enters_thermal_and_climbs(domain: Domain, tmp_path: Path) -> None:
    from pymavlink import mavutil

    n = domain.number
    assert n is not None
    log_file = (tmp_path / "launch.log").open("w")
    launch = subprocess.Popen(  # the launch runs the firmware (its sitl node's firmware block)
        [sys.executable, "-m", "hil_bridge.cli", "launch", str(LAUNCH), "--domain", str(n),
         "--duration", "1800", "--param", f"sitl.binary={SITL}"], cwd=ROOT, text=True,
        stdout=subprocess.DEVNULL, stderr=log_file)
    try:
        mav = mavutil.mavlink_connection(f"tcp:127.0.0.1:{5760 + 10 * n}", retries=120)
        assert mav.wait_heartbeat(timeout=120) is not None, "no heartbeat from SITL"
        deadline = time.monotonic() + 300
        while time.monotonic() < deadline:  # the EKF aligns while the glider glides
            txt = mav.recv_match(type="STATUSTEXT", blocking=True, timeout=10)
            if txt is not None and "is using GPS" in txt.text:
                break
        else:
            pytest.fail("SITL's EKF never used GPS")
        mav.mav.command_long_send(mav.target_system, mav.target_component,
                                  mavutil.mavlink.MAV_CMD_DO_SET_HOME, 0, 0, 0, 0, 0, *ORIGIN)
        _upload_mission(mav, mavutil)
        mav.waypoint_set_current_send(1)
        mav.set_mode(AUTO)
        mav.mav.command_long_send(mav.target_system, mav.target_component,
                                  mavutil.mavlink.MAV_CMD_COMPONENT_ARM_DISARM, 0, 1, 21196,
                                  0, 0, 0, 0, 0)
        armed_s: float | None = None  # the boot clock of the first position after arming
        entered: float | None = None  # height above the origin when THERMAL began
        entered_s = 0.0
        best = height = -1e9
        boot_s = 0.0
        deadline = time.monotonic() + 900
        while time.monotonic() < deadline and not (entered is not None
                                                   and best - entered >= CLIMB_M):
            msg = mav.recv_match(type=["HEARTBEAT", "GLOBAL_POSITION_INT"], blocking=True,
                                 timeout=10)
            if msg is None:
                continue
            if msg.get_type() == "GLOBAL_POSITION_INT":
                height = msg.relative_alt / 1000.0
                best = max(best, height)
                boot_s = msg.time_boot_ms / 1e3
                armed_s = boot_s if armed_s is None else armed_s
            elif msg.custom_mode == THERMAL and entered is None and height > -1e9:
                entered, best, entered_s = height, height, boot_s
        assert entered is not None, "ArduPlane never switched to THERMAL"
        print(f"THERMAL entered {entered_s:.0f} s after boot"
              + ("" if armed_s is None else f", {entered_s - armed_s:.0f} s after arming "
                 f"(armed {armed_s:.0f} s after boot)")
              + f", at {entered:.0f} m; reached {best:.0f} m")
        assert best - entered >= CLIMB_M, (
            f"in THERMAL from {entered:.0f} m the glider reached only {best:.0f} m")
    finally:
        stop(launch)
        log_file.close()
    assert launch.returncode == 0, (tmp_path / "launch.log").read_text()
    assert not domain.path(f"sitl{n}").exists()  # the firmware's directory went with it
