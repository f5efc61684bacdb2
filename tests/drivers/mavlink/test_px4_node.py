"""The PX4 HIL node against the PX4 protocol double (its own process) and a lockstep server
(mem:// bus): lockstep order and period, GNSS rate, sensors held to closed forms of the truth,
the aileron rolling the glider, a restarted PX4, bad messages, and HITL over a pty."""

from __future__ import annotations

import itertools
import json
import math
import subprocess
import sys
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from drivers.mavlink.px4 import Px4Hil
from hil_bridge.server.sim_server import SimServer
from sim_core.config import ConfigError
from sim_core.pose import quat_rotate
from sim_core.sensors import field_enu, isa

pytestmark = pytest.mark.processes

_n = itertools.count()
G0 = 9.80665


def _scene(clock: str = "lockstep") -> dict[str, Any]:
    return {
        "state_rate_hz": 250,
        "clock": {"mode": clock, "lockstep_timeout_s": 5.0, "lockstep_start_timeout_s": 60.0},
        "vehicles": [{"id": 7, "sixdof": {"origin": [47.0, 8.0, 0.0]},
                      "path": {"kind": "points", "points": [[0, 0, 500], [100, 0, 500]]}}],
    }


def loop(clock: str = "lockstep", **node_params: Any) -> tuple[SimServer, Px4Hil]:
    bus = f"mem://px4_{next(_n)}"
    srv = SimServer("server", bus=bus, scene=_scene(clock), autopilots=[7])
    params = {"vehicle_id": 7, "sensors": {"noise": False}, **node_params}
    if "link" not in params:
        params["port"] = 0
    node = Px4Hil("px4", bus=bus, **params)
    node.start()
    srv.start()
    return srv, node


@pytest.fixture
def lockstep() -> Iterator[tuple[SimServer, Px4Hil]]:
    srv, node = loop()
    try:
        yield srv, node
    finally:
        srv.stop()
        node.stop()
        assert node.failure(final=True) is None and srv.failure(final=True) is None


def double(url: str, *args: str, timeout: float = 120.0) -> dict[str, Any]:
    """Run the double as PX4 would run: its own process; its report."""
    out = subprocess.run([sys.executable, "-m", "drivers.mocks.px4_double", "--url", url,
                          "--timeout", "20", *args], capture_output=True, text=True,
                         timeout=timeout)
    report: dict[str, Any] = json.loads(out.stdout.splitlines()[-1])
    assert out.returncode == 0, (report.get("error"), out.stderr[-2000:])
    return report


def test_lockstep_sensors_gps_and_closed_forms(lockstep: tuple[SimServer, Px4Hil]) -> None:
    srv, node = lockstep
    rep = double(f"tcp://127.0.0.1:{node.port}", "--steps", "1500")
    t = np.array(rep["sensor_times"])
    # the double checked one HIL_SENSOR per controls and steps of exactly 4000 µs once they
    # flowed; before (PX4 booting) the node ran the clock on in real time, also at 4000 µs
    assert np.all(np.diff(t) == 4000)
    gps = np.diff(rep["gps_times"])
    assert len(rep["gps_times"]) == 60 and np.all(gps == 100_000)  # 6 s of sim time at 10 Hz
    st = node.stats()
    assert st["lockstep"] is False  # the double has gone: the node paces the clock again
    assert st["sensors_sent"] >= 1500 and st["states_nonfinite"] == 0
    assert st["surfaces_paced"] >= 25 and st["messages_bad"] == 0
    assert st["added_latency_us"]["n"] >= 1400
    assert srv.stats()["surfaces_applied"] >= 1499
    pairs = rep["pairs"]
    # HIL_STATE_QUATERNION at 50 Hz (the first step's, then sim times on 20 ms), each with its
    # step's sensors; the truth of the last step the double reads, if one, comes after it
    # stopped reading
    times = rep["sensor_times"]
    truths = {times[0], *(s for s in times if s % 20_000 == 0)}
    assert len(pairs) == len(truths) - (times[-1] in truths) >= 299
    ref = field_enu(np.array([47.0]), np.array([8.0]), np.array([500.0]), 2026.0)[0]
    acc_ned, v_ned, t_s = [], [], []
    for pair in pairs:
        s, g = pair["sensor"], pair["truth"]
        alt = g["alt"] / 1e3
        p, temp, rho = (float(v[0]) for v in isa(np.array([alt])))
        assert s["abs_pressure"] * 100 == pytest.approx(p, abs=0.02)  # ISA at the height
        assert s["temperature"] == pytest.approx(temp - 273.15, abs=1e-4)
        tas = g["true_airspeed"] / 100
        assert s["diff_pressure"] * 100 == pytest.approx(0.5 * rho * tas * tas, abs=0.15)
        assert g["ind_airspeed"] / 100 == pytest.approx(tas * math.sqrt(rho / 1.225), abs=0.02)
        q = np.array(g["attitude_quaternion"])  # NED from FRD
        acc_ned.append(quat_rotate(q, np.array([s["xacc"], s["yacc"], s["zacc"]])))
        v_ned.append([g["vx"] / 100, g["vy"] / 100, g["vz"] / 100])
        t_s.append(g["time_usec"] / 1e6)
        mag_ned = quat_rotate(q, np.array([s["xmag"], s["ymag"], s["zmag"]]))
        np.testing.assert_allclose(mag_ned, [ref[1], ref[0], -ref[2]], atol=2e-4)
        assert np.linalg.norm(mag_ned) == pytest.approx(np.linalg.norm(ref), rel=1e-4)
        assert s["pressure_alt"] == pytest.approx(alt, abs=1.0)
    assert abs(math.degrees(rep["roll"])) < 2.0  # wings held level
    # the accelerometer reads the kinematic acceleration minus gravity: over each second,
    # its mean against the truth's change of velocity (cm/s steps: 0.01 m/s² over 1 s)
    acc, v, ts = np.array(acc_ned), np.array(v_ned), np.array(t_s)
    for k in range(0, len(ts) - 50, 50):
        kinematic = (v[k + 50] - v[k]) / (ts[k + 50] - ts[k])
        mean = (acc[k:k + 51].sum(axis=0) - (acc[k] + acc[k + 50]) / 2) / 50  # trapezoid
        np.testing.assert_allclose(mean, kinematic - [0.0, 0.0, G0], atol=0.05)


def test_aileron_rolls_and_a_restarted_px4_is_served_again(
        lockstep: tuple[SimServer, Px4Hil]) -> None:
    _, node = lockstep
    rep = double(f"tcp://127.0.0.1:{node.port}", "--steps", "2000", "--reconnect-after", "300",
                 "--bank-deg", "20")
    # the clock went on across the restart: the new PX4 starts on the newest state, which the
    # old one may have seen last (the double checked each connection's time rising)
    dt = np.diff(np.array(rep["sensor_times"]))
    assert np.all(dt >= 0) and np.count_nonzero(dt == 0) <= 1
    # the double's aileron banked the glider right (PX4: roll + rolls right)
    assert math.degrees(rep["roll"]) == pytest.approx(20.0, abs=8.0)
    st = node.stats()
    assert st["px4_connects"] == 2 and st["px4_disconnects"] >= 1
    assert st["link"]["connects"] == 2


def test_bad_messages_are_dropped_and_counted(lockstep: tuple[SimServer, Px4Hil]) -> None:
    _, node = lockstep
    double(f"tcp://127.0.0.1:{node.port}", "--steps", "200", "--garbage")
    st = node.stats()
    assert st["link"]["bad"] >= 2  # garbage and a frame whose checksum fails
    assert st["link"]["unknown"] >= 1  # a message id the dialect has not
    assert st["messages_bad"] == 1  # NaN controls, never flown
    assert st["states_nonfinite"] == 0 and st["sensors_sent"] >= 200


def test_hitl_over_a_pty_is_paced_by_the_wall_clock(tmp_path: Path) -> None:
    """HITL: PX4 on a USB serial port, no lockstep; the node answers every state at its time
    on the wall clock, never before, so the sensors arrive at 250 Hz of real time at most."""
    link = tmp_path / "px4-usb"
    proc = subprocess.Popen([sys.executable, "-m", "drivers.mocks.px4_double", "--url",
                             f"pty://{link}", "--hitl", "--steps", "750", "--timeout", "20"],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        assert proc.stdout is not None
        assert "pty" in json.loads(proc.stdout.readline())
        srv, node = loop(link=f"serial://{link}?baud=921600")
        try:
            out, err = proc.communicate(timeout=60)
        finally:
            srv.stop()
            node.stop()
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.communicate()
    rep = json.loads(out.splitlines()[-1])
    assert proc.returncode == 0, (rep.get("error"), err[-2000:])
    st = node.stats()
    assert st["lockstep"] is False and st["surfaces_paced"] >= 700
    assert st["ground_truth_sent"] == 0  # HITL: PX4 would take it for its own state
    t_sim = (np.array(rep["sensor_times"]) - rep["sensor_times"][0]) / 1e6
    t_wall = np.array(rep["wall_times"]) - rep["wall_times"][0]
    assert t_sim[-1] == pytest.approx(2.996, abs=0.01)
    # paced, never ahead of the wall clock (a loaded machine may only make it later: the node
    # counts that in pace_late, and BENCHMARKS.md measures the pace it holds)
    assert np.all(t_sim - t_wall <= 0.01)
    assert node.failure(final=True) is None


def test_bad_params_fail_at_load_with_the_key() -> None:
    with pytest.raises(ConfigError, match="lockstep"):
        Px4Hil("px4", bus="mem://x", vehicle_id=7, lockstep="maybe")
    with pytest.raises(ConfigError, match=r"actuators\.roll"):
        Px4Hil("px4", bus="mem://x", vehicle_id=7, actuators={"roll": [[16, 1.0]]})
    with pytest.raises(ConfigError, match="bogus"):
        Px4Hil("px4", bus="mem://x", vehicle_id=7, bogus=1)
    with pytest.raises(ConfigError, match="port"):
        Px4Hil("px4", bus="mem://x", vehicle_id=7, port=4560, link="tcpin://127.0.0.1:4561")
