"""The ROS 2 bridge live: ``launch/ros2_demo.yaml`` (server, pinger, bridge: each a process) and a
plain rclpy node (``rclpy_client.py``, a process of its own, on a private ``ROS_DOMAIN_ID``).

What the client receives is checked against the launch's own recording of the bus: Odometry
positions and attitudes equal the states, its ``use_sim_time`` clock follows ``/clock``, an
echo's samples and emission stamp equal the bus echo's, and its commands bank a glider the
swarm law was flying. A subscriber asking for a QoS the bridge does not offer is warned about;
a bridge killed with SIGKILL ends the run with exit 1 naming it, and it never mapped Fast DDS
shared memory (so a kill leaves no ``/dev/shm/fastdds_*``).
"""

from __future__ import annotations

import importlib.util
import json
import os
import re
import signal
import subprocess
import sys
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from hil_bridge.bus.domain import Domain, claim_first_free
from hil_bridge.bus.messages import Clock, GliderCmd, GliderState, SonarEcho
from hil_bridge.recording.export.common import ExportCounts, decoded

pytestmark = [
    pytest.mark.processes,
    pytest.mark.skipif(importlib.util.find_spec("rclpy") is None,
                       reason="the 'ros2' extra (rclpy) is not installed"),
]

ROOT = Path(__file__).resolve().parents[2]
CLIENT = Path(__file__).with_name("rclpy_client.py")
LAUNCH = ROOT / "launch" / "ros2_demo.yaml"
BANK = 0.2  # rad, inside the swarm law's ±15 degrees
AIRSPEED = 10.0  # m/s, inside the law's 8..13


@pytest.fixture
def domain() -> Iterator[Domain]:
    with claim_first_free(Domain(int.from_bytes(os.urandom(1)) % 60 + 20)) as (dom, _):
        yield dom


def _env(domain: Domain, ros_domain: int) -> dict[str, str]:
    """The environment of the launch and the client: the client is a user's node on UDP (so
    that a test killed by a timeout leaves no Fast DDS shared memory either)."""
    env = dict(os.environ, ECHOLOOP_DOMAIN=str(domain.number), ROS_DOMAIN_ID=str(ros_domain),
               FASTDDS_BUILTIN_TRANSPORTS="UDPv4", PYTHONUNBUFFERED="1")
    for name in ("ROS_AUTOMATIC_DISCOVERY_RANGE", "FASTDDS_DEFAULT_PROFILES_FILE"):
        env.pop(name, None)
    return env


def _ros_domain() -> int:
    """A ROS 2 domain no echoloop domain maps to (those are 0..99)."""
    return 120 + int.from_bytes(os.urandom(1)) % 100


def _launch(domain: Domain, ros_domain: int, *extra: str) -> subprocess.Popen[str]:
    cmd = [sys.executable, "-m", "hil_bridge.cli", "launch", str(LAUNCH),
           "--domain", str(domain.number), *extra]
    return subprocess.Popen(cmd, cwd=ROOT, env=_env(domain, ros_domain), text=True,
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE)


def _wait_for(proc: subprocess.Popen[str], pattern: str, seen: list[str],
              timeout: float = 120.0) -> re.Match[str]:
    """The first line of ``proc``'s stderr (those in ``seen`` first: the runner's own lines and
    the nodes' relayed ones come in no fixed order) that matches ``pattern``."""
    for line in seen:
        if hit := re.search(pattern, line):
            return hit
    assert proc.stderr is not None
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        line = proc.stderr.readline()
        if not line:
            break
        seen.append(line)
        hit = re.search(pattern, line)
        if hit:
            return hit
    proc.kill()
    pytest.fail(f"no line matching {pattern!r}:\n{''.join(seen)[-3000:]}")


def _recorded(path: Path) -> dict[str, list[Any]]:
    out: dict[str, list[Any]] = {}
    for d in decoded(path, ExportCounts()):
        out.setdefault(d.topic, []).append(d.msg)
    return out


def test_a_plain_rclpy_node_sees_the_simulation_and_flies_a_glider(
        domain: Domain, tmp_path: Path) -> None:
    ros_domain = _ros_domain()
    rec, got = tmp_path / "run.mcap", tmp_path / "client.npz"
    launch = _launch(domain, ros_domain, "--duration", "120", "--record", str(rec), "--json")
    seen: list[str] = []
    try:
        _wait_for(launch, r"echoloop launch: running", seen)
        client = subprocess.run(
            [sys.executable, str(CLIENT), str(got), "--duration", "8", "--glider", "2",
             "--bank", str(BANK), "--airspeed", str(AIRSPEED), "--mismatched-qos"],
            env=_env(domain, ros_domain), capture_output=True, text=True, timeout=120)
        assert client.returncode == 0, client.stderr[-3000:]
    finally:
        launch.send_signal(signal.SIGTERM)
        out, err = launch.communicate(timeout=120)
    err = "".join(seen) + err
    assert launch.returncode == 0, err[-3000:]
    summary = json.loads(out)
    bridge, server = summary["nodes"]["ros2"], summary["nodes"]["server"]
    bus = _recorded(rec)
    data = np.load(got)

    # Odometry: the bus states, bit for bit (stamps, positions, attitudes)
    states = {s.stamp_ns: s for s in bus["/glider/0/state"] if isinstance(s, GliderState)}
    assert len(data["odom_stamps"]) > 100
    for stamp, row in zip(data["odom_stamps"], data["odom"], strict=True):
        st = states[int(stamp)]
        assert tuple(row[1:]) == (st.x, st.y, st.z, st.qw, st.qx, st.qy, st.qz)

    # use_sim_time follows /clock: the node's time is a /clock stamp, never the wall clock
    clocks = {c.stamp_ns for c in bus["/clock"] if isinstance(c, Clock)}
    assert len(data["clock"]) > 100 and set(data["clock"].tolist()) <= clocks
    now = data["sim_now"][:, 1]
    assert set(now.tolist()) <= clocks | {0}
    # (rclpy's time source has a /clock subscription of its own: one tick apart at most)
    assert now[-1] > 0 and abs(int(now[-1]) - int(data["clock"][-1])) <= 20_000_000

    # an echo: samples and emission stamp as the bus carried them
    echoes = {e.emit_ns: e for e in bus["/sonar/0/echo"] if isinstance(e, SonarEcho)}
    assert len(data["echo_stamps"]) >= 3
    for i, stamp in enumerate(data["echo_stamps"]):
        echo = echoes[int(stamp)]
        np.testing.assert_array_equal(data[f"echo_{i}"], np.atleast_2d(echo.samples))
    # a lazy topic loses nothing once subscribed: every echo between the first and the last
    got = data["all_echo_stamps"].tolist()
    assert sorted(got) == sorted(s for s in echoes if got[0] <= s <= got[-1])

    # commands: glider 2 flies the client's bank (its roll follows with a lag)
    assert bridge["cmd_forwarded"] > 50 and bridge["cmd_bad"] == 0
    assert server["cmd_applied"] >= bridge["cmd_forwarded"]
    flown = [(s.stamp_ns, s.bank, s.alive) for s in bus["/glider/2/state"]
             if isinstance(s, GliderState)]
    sent = sorted(c.stamp_ns for c in bus["/glider/2/cmd"] if isinstance(c, GliderCmd))
    # from 1.5 s after the first command (the roll follows with a lag) to the last one
    t0, t1 = sent[0] + 1_500_000_000, sent[-1]
    assert t1 - t0 >= 2_000_000_000, (sent[0], sent[-1], len(sent))
    window = [b for t, b, _ in flown if t0 <= t <= t1]
    assert abs(np.median(window) - BANK) < 0.02, (
        [f for f in flown if t0 <= f[0] <= t1][-20:], len(sent),
        {k: v for k, v in server.items() if "cmd" in k})

    # the bridge's own account of a state's time: the bus's part, then its part on top
    bus_ms, out_ms = bridge["state_bus_ms"], bridge["state_out_ms"]
    assert bus_ms["n"] >= out_ms["n"] > 100  # every state received, each Odometry written
    assert 0 < bus_ms["p50"] <= out_ms["p50"]

    # the mismatched subscriber: a warning naming the topic and the policy, and a count
    assert bridge["qos_incompatible"] >= 1
    assert re.search(r"ROS 2 subscription of /glider_0/odom asks for an incompatible QoS "
                     r"\(DURABILITY", err), err[-3000:]


def test_a_killed_bridge_ends_the_run_naming_it(domain: Domain) -> None:
    launch = _launch(domain, _ros_domain(), "--duration", "120")
    seen: list[str] = []
    try:
        _wait_for(launch, r"echoloop launch: running", seen)
        pid = int(_wait_for(launch, r"ros2 \(pid (\d+)\): ROS 2 domain", seen).group(1))
        maps = Path(f"/proc/{pid}/maps").read_text()
        assert "/dev/shm/fastdds" not in maps  # UDP only: a kill leaves no shared memory
        os.kill(pid, signal.SIGKILL)
        out, err = launch.communicate(timeout=120)
    finally:
        if launch.poll() is None:
            launch.kill()
            launch.communicate()
    assert launch.returncode == 1, err[-3000:]
    assert re.search(r"ros2.*killed by SIGKILL", out + err), (out + err)[-3000:]
