"""A flight log written by the real tools (``tests/data/flightlogs``, README there) reads to what
pymavlink itself reads from it: an ArduPilot QuadPlane's telemetry log, recorded by its ground
station, checked against the vehicle's own numbers read straight with pymavlink."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

from hil_bridge.recording.logs import detect_format, read_log

TLOG = Path(__file__).resolve().parents[3] / "data" / "flightlogs" / "ardupilot_quadplane_sitl.tlog"
#: ``time_boot_ms`` of the vehicle's "Land complete" (disarm), after which its EKF origin, and
#: so LOCAL_POSITION_NED, moves (README)
DISARM_MS = 784_882


@pytest.fixture(scope="module")
def mav() -> dict[str, np.ndarray]:
    """The log as pymavlink reads it: GLOBAL_POSITION_INT (``time_boot_ms, lat, lon, alt, vx,
    vy, vz, hdg``) as received, LOCAL_POSITION_NED (``time_boot_ms, x, y, z``), ATTITUDE
    (``time_boot_ms, roll, pitch, yaw``)."""
    from pymavlink import mavutil

    fields = {"GLOBAL_POSITION_INT": ("time_boot_ms", "lat", "lon", "alt", "vx", "vy", "vz",
                                      "hdg"),
              "LOCAL_POSITION_NED": ("time_boot_ms", "x", "y", "z"),
              "ATTITUDE": ("time_boot_ms", "roll", "pitch", "yaw")}
    rows: dict[str, list[list[float]]] = {k: [] for k in fields}
    conn = mavutil.mavlogfile(str(TLOG), robust_parsing=True)
    try:
        while (m := conn.recv_msg()) is not None:
            if m.get_type() in fields:
                rows[m.get_type()].append([float(getattr(m, f)) for f in fields[m.get_type()]])
    finally:
        conn.close()
    return {k: np.array(v) for k, v in rows.items()}


def _in_time_order(g: np.ndarray) -> np.ndarray:
    """Rows later than every earlier one (the reader drops the others and says so)."""
    keep, latest = [], -math.inf
    for row in g:
        if row[0] > latest:
            keep.append(row)
            latest = row[0]
    return np.array(keep)


def test_ardupilot_tlog_reads_to_the_fixes_pymavlink_reads(mav: dict[str, np.ndarray]) -> None:
    assert detect_format(TLOG) == "tlog"
    traj, report = read_log(TLOG)
    raw = mav["GLOBAL_POSITION_INT"]
    g = _in_time_order(raw)
    assert (len(raw), len(g)) == (807, 804)
    assert report.samples == len(traj) == len(g) and len(report.backward) == len(raw) - len(g)
    assert (report.source, report.att_source, report.vehicle_id) == (
        "GLOBAL_POSITION_INT", "ATTITUDE", 1)
    np.testing.assert_allclose(traj.t, g[:, 0] / 1e3, rtol=0, atol=1e-9)
    assert traj.duration == pytest.approx((816_994 - 608_582) / 1e3)
    assert report.origin == pytest.approx((g[0, 1] * 1e-7, g[0, 2] * 1e-7, g[0, 3] / 1e3))
    # local ENU by hand from WGS-84's radii of curvature at the first fix (second-order terms
    # stay under 5 mm within the flight's 300 m): east from longitude, north from latitude,
    # up from altitude -- z grows as the vehicle climbs
    a, e2 = 6378137.0, 6.69437999014e-3
    lat0, h0 = math.radians(g[0, 1] * 1e-7), g[0, 3] / 1e3
    n = a / math.sqrt(1 - e2 * math.sin(lat0) ** 2)
    m = a * (1 - e2) / (1 - e2 * math.sin(lat0) ** 2) ** 1.5
    east = (n + h0) * math.cos(lat0) * np.radians((g[:, 2] - g[0, 2]) * 1e-7)
    north = (m + h0) * np.radians((g[:, 1] - g[0, 1]) * 1e-7)
    up = (g[:, 3] - g[0, 3]) / 1e3
    np.testing.assert_allclose(traj.xyz, np.stack([east, north, up], axis=1), atol=0.01)
    assert traj.xyz[:, 2].max() == pytest.approx(56.6, abs=0.01)  # the circuits, 56.6 m up
    np.testing.assert_allclose(traj.xyz[-1], [8.25, 225.03, -1.21], atol=0.01)  # landed
    # speed: the norm of the logged NED velocity (cm/s)
    np.testing.assert_allclose(traj.airspeed, np.linalg.norm(g[:, 4:7], axis=1) / 100,
                               atol=1e-9)


def test_ardupilot_tlog_axes_agree_with_the_vehicles_local_ned_and_heading(
    mav: dict[str, np.ndarray],
) -> None:
    traj, _ = read_log(TLOG)
    g = _in_time_order(mav["GLOBAL_POSITION_INT"])
    # LOCAL_POSITION_NED (x north, y east, z down, sent with each fix) moved from the first
    # sample, until the disarm: ArduPilot's spherical-Earth offsets differ from WGS-84 by
    # 0.3 % of the distance (0.8 m at 290 m north)
    local = {row[0]: row[1:] for row in mav["LOCAL_POSITION_NED"]}
    flying = g[:, 0] < DISARM_MS
    ned = np.array([local[t] for t in g[flying, 0]])
    enu = np.stack([ned[:, 1], ned[:, 0], -ned[:, 2]], axis=1)
    moved = enu - enu[0]
    err = np.linalg.norm(traj.xyz[flying] - moved, axis=1)
    assert np.all(err <= 0.005 * np.linalg.norm(moved[:, :2], axis=1) + 0.05)
    assert np.ptp(moved[:, 0]) > 150 and np.ptp(moved[:, 1]) > 400  # both axes were flown
    # heading: ENU yaw = 90 deg - the vehicle's compass heading (hdg, cdeg from north)
    err_deg = (np.degrees(traj.heading) - (90.0 - g[:, 7] / 100) + 180) % 360 - 180
    assert np.median(np.abs(err_deg)) < 0.1 and np.max(np.abs(err_deg)) < 3.0
    # bank = -roll (ATTITUDE's roll, rad, right wing down positive)
    att = mav["ATTITUDE"]
    roll = np.interp(g[:, 0], att[:, 0], att[:, 1])
    np.testing.assert_allclose(traj.bank, -roll, atol=0.01)
    assert np.ptp(roll) > 0.5  # it banked


def test_ardupilot_tlog_cut_or_damaged_is_read_up_to_the_damage_and_says_so(
    tmp_path: Path,
) -> None:
    data = TLOG.read_bytes()
    cut = tmp_path / "cut.tlog"
    cut.write_bytes(data[: len(data) // 2 + 7])  # inside a packet
    traj, report = read_log(cut)
    whole, _ = read_log(TLOG)
    assert 300 < len(traj) < len(whole)
    np.testing.assert_array_equal(traj.xyz, whole.xyz[: len(traj)])
    flipped = bytearray(data)
    rng = np.random.default_rng(7)
    for i in rng.integers(1000, len(data) - 1000, 20):
        flipped[i] ^= 0x80
    bad = tmp_path / "flipped.tlog"
    bad.write_bytes(bytes(flipped))
    _, report = read_log(bad)
    said = [n for n in report.notes if "could not decode" in n]
    assert len(said) == 1 and int(said[0].split()[0]) >= 10, report.notes
