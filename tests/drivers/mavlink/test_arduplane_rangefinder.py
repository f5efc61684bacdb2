"""Real firmware: ArduPlane SITL takes echoloop's sonar as its range finder over MAVLink and logs
what it was sent.

Runs only where ``ECHOLOOP_ARDUPILOT_SITL`` names an ``arduplane`` binary (built by the user from
ArduPilot, outside this repository). ``launch/ardupilot_glider.yaml``, its sonar on a vehicle
flown 15 m over a dense maple forest, runs while ArduPlane boots with
``echoloop-sgs126.parm`` and ``echoloop-rangefinder.parm`` (``RNGFND1_TYPE`` 10, orientation
down, ``LOG_DISARMED`` 1); the launch's rangefinder node sends every echo as a
``DISTANCE_SENSOR`` per ear to SITL's SERIAL1. The run is recorded: the echoes in the recording,
put through the node's own rule, are what was sent; ArduPlane's DataFlash log (read with
pymavlink) must hold them as ``RFND`` records, each logged distance one that was sent (to the
centimetre of ``DISTANCE_SENSOR``, stored as a float), good ones among them.
"""

from __future__ import annotations

import subprocess
import sys
import time
from pathlib import Path

import pytest
import yaml

from hil_bridge.bus.domain import Domain
from tests.drivers.firmware import SITL, needs_sitl, stop

pytestmark = [
    pytest.mark.processes,
    needs_sitl,
]

ROOT = Path(__file__).resolve().parents[3]
LAUNCH = ROOT / "launch" / "ardupilot_glider.yaml"
PARMS = [ROOT / "launch" / "data" / "ardupilot" / f"echoloop-{n}.parm"
         for n in ("sgs126", "rangefinder")]
FLY_S = 45.0


def _low_over_the_forest(path: Path) -> dict:
    """The ArduPilot launch with its sonar on a second vehicle, flown 15 m over a dense maple
    forest along a path (canopy tops at 10-20 m: echoes with returns), while the firmware
    flies its glider high above: what is under test is the wire and the log, and a glider
    gliding down into the trees would give the firmware seconds, not minutes, of returns."""
    spec = yaml.safe_load(LAUNCH.read_text())
    scene = spec["nodes"][0]["params"]["scene"]
    scene["vehicles"].append({"id": 8, "path": {
        "kind": "points", "points": [[0.0, 0.0, 15.0], [1000.0, 0.0, 15.0]], "speed_mps": 8.0}})
    scene["sonars"][0]["mount"] = 8
    scene["forest"]["spec"]["species"] = [{"name": "maple", "tree": "maple", "rate": 0.01,
                                           "count": 1500}]
    path.write_text(yaml.safe_dump(spec, sort_keys=False))
    return spec


def test_arduplane_logs_the_echo_ranges_it_was_sent(domain: Domain, tmp_path: Path) -> None:
    from pymavlink import mavutil

    from drivers.mavlink.ranges import EchoRanger, RangeFinderSpec
    from hil_bridge.bus.codec import decode_payload
    from hil_bridge.recording.bag import read_bag
    from sim_core.config import from_dict

    n = domain.number
    assert n is not None
    launch_file = tmp_path / "low.yaml"
    spec = _low_over_the_forest(launch_file)
    bag = tmp_path / "run.mcap"
    launch = subprocess.Popen(
        [sys.executable, "-m", "hil_bridge.cli", "launch", str(launch_file), "--domain", str(n),
         "--duration", "600", "--record", str(bag)], cwd=ROOT, text=True,
        stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    firmware = subprocess.Popen(
        [SITL, "--model", "JSON:127.0.0.1", "-I", str(n), "-w", "--home", "47.0,8.0,0,90",
         "--defaults", ",".join(str(p) for p in PARMS)], cwd=tmp_path, text=True,
        stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    try:
        mav = mavutil.mavlink_connection(f"tcp:127.0.0.1:{5760 + 10 * n}", retries=120)
        assert mav.wait_heartbeat(timeout=120) is not None, "no heartbeat from SITL"
        deadline = time.monotonic() + FLY_S
        while time.monotonic() < deadline:  # SITL starts once its SERIAL0 has a peer: read it
            mav.recv_match(blocking=True, timeout=1)
    finally:
        stop(firmware)
        stop(launch)
    rule = from_dict(RangeFinderSpec, spec["nodes"][-1]["params"]["ranges"])
    ranger = EchoRanger(rule)
    sent: set[int] = set()
    for m in read_bag(bag, ["/sonar/0/echo"]):
        echo = decode_payload(m.header.type, m.header.v, m.payload)
        sent |= {d.current_distance for d in ranger.messages(echo)}
    assert ranger.counters["returns"] > 0, "no echo had a return: the sonar flew too high"
    logs = sorted((tmp_path / "logs").glob("*.BIN"))
    assert logs, "ArduPlane wrote no DataFlash log"
    log = mavutil.mavlink_connection(str(logs[-1]))
    records = []
    while (r := log.recv_match(type="RFND")) is not None:
        records.append(r)
    measured = [r for r in records if r.Stat >= 2]  # not NotConnected (0) or NoData (1)
    assert len(measured) > 50, f"only {len(measured)} RFND records with data"
    assert {r.Orient for r in measured} == {25}
    for r in measured:  # each logged distance is one that was sent, to the float's rounding
        assert round(r.Dist * 100) in sent and abs(r.Dist * 100 - round(r.Dist * 100)) < 0.01
    good = [r for r in measured if r.Stat == 4]
    assert good and all(0.2 <= r.Dist <= 10.0 for r in good)
    assert any(r.Stat == 3 and r.Dist > 10.0 for r in measured)  # no return: out of range
