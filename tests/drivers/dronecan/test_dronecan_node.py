"""The DroneCAN node against an independent peer (the dronecan package's own node and
allocator, in a process of its own) over CAN over UDP multicast: node-ID allocation,
NodeStatus and GetNodeInfo, Measurements equal to the echo's range within the float16 step,
ArrayCommand flying the glider's surfaces, bad transfers dropped and counted, the peer
restarting; and launch/dronecan_glider.yaml in processes."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from drivers.dronecan.messages import FLOAT16_STEP
from drivers.dronecan.node import DroneCanNode
from hil_bridge.bus.domain import Domain
from hil_bridge.bus.messages import SonarEcho, SurfaceCmd
from hil_bridge.bus.node import Node
from sim_core.config import ConfigError
from sim_core.sensors import echo_ranges
from tests.drivers.mavlink.test_ranges import leaf_echo

pytestmark = pytest.mark.processes

ROOT = Path(__file__).resolve().parents[3]


def peer(bus: int, *args: str) -> subprocess.Popen[str]:
    return subprocess.Popen([sys.executable, "-m", "drivers.mocks.dronecan_peer", "--bus",
                             str(bus), *args], stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                            text=True)


def report(proc: subprocess.Popen[str]) -> dict[str, Any]:
    out, err = proc.communicate(timeout=60)
    assert proc.returncode == 0, err[-2000:]
    data: dict[str, Any] = json.loads(out.splitlines()[-1])
    return data


def test_a_flight_controller_allocates_hears_and_drives_the_node(domain: Domain) -> None:
    assert domain.number is not None
    bus = f"mem://dronecan_{domain.number}"
    node = DroneCanNode("dronecan", bus=bus, vehicle_id=7, interface=f"mcast:{domain.number}",
                        ranges=[{"sonar_id": 0, "sensor_id": 5}])
    sim = Node("sim", bus=bus)
    echoes = sim.create_publisher(SonarEcho, "/sonar/0/echo")
    surfaces: list[SurfaceCmd] = []
    sim.create_subscription(SurfaceCmd, "/glider/7/surfaces", surfaces.append)
    sim.start()
    node.start()
    try:
        fc = peer(domain.number, "--seconds", "6", "--servo-hz", "20", "--aileron", "0.4",
                  "--garbage")
        deadline = time.monotonic() + 20
        while node.node_id is None and time.monotonic() < deadline:
            time.sleep(0.05)
        assert node.node_id is not None, "no node ID was allocated"
        sent = []
        for k in range(8):
            echo = leaf_echo(2.0 + 0.37 * k)
            sent.append(echo_ranges(echo.samples, echo.fs).range_m)
            echoes.publish(echo)
            time.sleep(0.3)
        seen = report(fc)
        # a restarted flight controller hears the node again, under the same ID
        fc2 = peer(domain.number, "--seconds", "2.5")
        time.sleep(1.0)
        echoes.publish(leaf_echo(4.0))
        again = report(fc2)
    finally:
        node.stop()
        sim.stop()
    me = str(node.node_id)
    assert seen["allocations"] and seen["allocations"][0]["node_id"] == node.node_id
    assert seen["allocations"][0]["unique_id"] == node.unique_id.hex()
    assert seen["node_status"][me] >= 3
    assert seen["node_info"][me]["name"] == "org.echoloop.sim"
    ours = [m for m in seen["measurements"] if m["src"] == node.node_id]
    assert {m["sensor_id"] for m in ours} == {5, 6}  # one per ear
    got = np.array([m["range"] for m in ours]).reshape(-1, 2)
    want = np.array(sent)[-len(got):]
    assert len(got) >= 6
    for g, w in zip(got.ravel(), want.ravel(), strict=True):
        assert abs(g - w) <= FLOAT16_STEP(w) / 2  # float16 rounding, no more
    assert all(m["reading"] == 1 for m in ours)  # VALID_RANGE
    assert again["node_status"][me] >= 1
    assert [m["range"] for m in again["measurements"] if m["src"] == node.node_id]
    st = node.stats()
    assert st["transfers_bad_by"] == {"crc mismatch": 1, "toggle bit": 1,
                                      "unrecognised message": 1}
    assert st["array_commands"] >= 80 and surfaces
    assert surfaces[-1].aileron == pytest.approx(0.4, abs=1e-3)  # float16 of 0.4
    assert surfaces[-1].throttle == 0.0 and surfaces[-1].elevator == 0.0
    assert node.failure(final=True) is None


def test_a_point_mass_profile_turns_servo_commands_into_bank_and_airspeed(
        domain: Domain) -> None:
    from hil_bridge.bus.messages import GliderCmd

    assert domain.number is not None
    bus = f"mem://dronecan_pm_{domain.number}"
    node = DroneCanNode("dronecan", bus=bus, vehicle_id=3, interface=f"mcast:{domain.number}",
                        node_id=42, profile="pointmass",
                        pointmass={"bank_max_rad": 0.6, "airspeed_mps": [9.0, 16.0]})
    sim = Node("sim", bus=bus)
    cmds: list[GliderCmd] = []
    sim.create_subscription(GliderCmd, "/glider/3/cmd", cmds.append)
    sim.start()
    node.start()
    try:
        report(peer(domain.number, "--seconds", "3", "--servo-hz", "20", "--aileron", "-0.5"))
    finally:
        node.stop()
        sim.stop()
    assert node.stats()["cmds_published"] > 0 and cmds
    # aileron -0.5 rolls left; the bus's bank is positive in a left turn (docs/bus.md)
    assert cmds[-1].bank_cmd == pytest.approx(0.5 * 0.6)
    assert cmds[-1].airspeed_cmd == pytest.approx(12.5)  # elevator neutral: mid-range
    assert cmds[-1].glider_id == 3


def test_bad_params_fail_at_load() -> None:
    with pytest.raises(ConfigError, match="node_id"):
        DroneCanNode("dronecan", bus="mem://x", vehicle_id=7, interface="mcast:0", node_id=200)
    with pytest.raises(ConfigError, match="profile"):
        DroneCanNode("dronecan", bus="mem://x", vehicle_id=7, interface="mcast:0",
                     profile="pointmass", gnss=True)


def test_the_dronecan_launch_feeds_a_flight_controller(domain: Domain) -> None:
    assert domain.number is not None
    cmd = [sys.executable, "-m", "hil_bridge.cli", "launch",
           str(ROOT / "launch" / "dronecan_glider.yaml"), "--domain", str(domain.number),
           "--duration", "120", "--json"]
    launch = subprocess.Popen(cmd, cwd=ROOT, text=True, stdout=subprocess.PIPE,
                              stderr=subprocess.PIPE, env=dict(os.environ, PYTHONUNBUFFERED="1"))
    try:
        assert launch.stderr is not None
        for line in launch.stderr:
            if "echoloop launch: running" in line:
                break
        else:
            pytest.fail("the launch never ran")
        seen = report(peer(domain.number, "--seconds", "6", "--servo-hz", "50"))
        launch.send_signal(signal.SIGTERM)
        out, err = launch.communicate(timeout=120)
    finally:
        if launch.poll() is None:
            launch.kill()
            launch.communicate()
    assert launch.returncode == 0, err[-3000:]
    nodes = json.loads(out)["nodes"]
    dc, server = nodes["dronecan"], nodes["server"]
    assert dc["node_id"] and seen["node_info"][str(dc["node_id"])]["name"] == "org.echoloop.sim"
    assert {m["sensor_id"] for m in seen["measurements"]} == {1, 2}
    assert dc["air_data_sent"] > 0 and dc["gnss_sent"] > 0
    assert dc["surfaces_published"] > 0 and server["surfaces_applied"] > 0
    assert dc["transfers_bad"] == 0


def test_echoloop_dronecan_node_runs_alone_beside_a_flight_controller(domain: Domain) -> None:
    assert domain.number is not None
    fc = peer(domain.number, "--seconds", "8")
    cmd = [sys.executable, "-m", "hil_bridge.cli", "dronecan", "node", "--domain",
           str(domain.number), "--param", "vehicle_id=7", "--duration", "6", "--json",
           "--expect", "dronecan.allocation_requests >= 1"]
    run = subprocess.run(cmd, cwd=ROOT, capture_output=True, text=True, timeout=120)
    seen = report(fc)
    assert run.returncode == 0, run.stderr[-2000:]
    me = json.loads(run.stdout)["nodes"]["dronecan"]["node_id"]
    assert me and seen["node_status"][str(me)] >= 2
    assert seen["node_info"][str(me)]["name"] == "org.echoloop.sim"
    bad = subprocess.run([*cmd[:-2], "--param", "node_id=300"], cwd=ROOT, capture_output=True,
                         text=True, timeout=120)
    lines = bad.stderr.strip().splitlines()
    assert bad.returncode == 1 and len(lines) == 1 and "node_id" in lines[0] and "300" in lines[0]


def test_a_bus_of_noise_is_dropped_and_counted_and_the_node_carries_on(domain: Domain) -> None:
    """Seeded noise on the node's bus: frames of every id and length (single- and multi-frame
    tails, services, anonymous, standard ids), datagrams that are not frames; the node
    neither fails nor stops, and then still takes a servo command."""
    import socket

    from drivers.dronecan.mcast import MCAST_PORT, McastDriver

    assert domain.number is not None
    n = domain.number
    bus = f"mem://dronecan_noise_{n}"
    node = DroneCanNode("dronecan", bus=bus, vehicle_id=7, interface=f"mcast:{n}", node_id=42)
    sim = Node("sim", bus=bus)
    surfaces: list[SurfaceCmd] = []
    sim.create_subscription(SurfaceCmd, "/glider/7/surfaces", surfaces.append)
    sim.start()
    node.start()
    noise = McastDriver(n)
    raw = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    raw.setsockopt(socket.IPPROTO_IP, socket.IP_MULTICAST_TTL, 0)
    rng = np.random.default_rng(42)
    try:
        for k in range(3000):
            if k % 10 == 9:
                raw.sendto(rng.bytes(int(rng.integers(0, 40))), (f"239.65.82.{n}", MCAST_PORT))
                continue
            data = bytearray(rng.bytes(int(rng.integers(0, 9))))
            if data and rng.random() < 0.5:  # a plausible tail byte: start/end/toggle/id
                data[-1] = (data[-1] & 0x1F) | int(rng.choice([0xC0, 0x80, 0x40, 0x00, 0x20]))
            extended = bool(rng.random() < 0.9)
            fid = int(rng.integers(0, 1 << 29 if extended else 1 << 11))
            noise.send(fid, bytes(data), extended=extended)
            if k % 100 == 0:
                time.sleep(0.005)  # let the node keep up: a bus, not a flood
        fc = peer(n, "--seconds", "2", "--servo-hz", "20", "--aileron", "0.25")
        report(fc)
        time.sleep(0.2)
    finally:
        raw.close()
        noise.close()
        node.stop()
        sim.stop()
    st = node.stats()
    assert node.failure(final=True) is None
    assert st["frames_in"] >= 2000 and st["driver"]["bad_datagrams"] >= 250
    assert {"unrecognised message", "unrecognised service", "toggle bit"} <= set(
        st["transfers_bad_by"])
    assert st["array_commands"] > 0 and surfaces[-1].aileron == pytest.approx(0.25, abs=1e-3)
