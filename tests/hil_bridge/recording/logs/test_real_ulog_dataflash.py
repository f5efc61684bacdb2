"""The PX4 ULogs and ArduPilot DataFlash logs the real tools wrote (``tests/data/flightlogs``,
README there) read to what the standard tools read from them: pyulog for ULog, pymavlink's
DFReader for DataFlash. The same position samples (count, times), positions within 1e-6° and
1 cm (as the reader returns them, and back from the trajectory's local ENU metres), attitude
within 1e-6 rad, and GPS receivers kept apart."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from hil_bridge.recording.logs import NoPoseError, detect_format, read_log
from hil_bridge.recording.logs.mavlink import read_dataflash
from hil_bridge.recording.logs.track import PoseLog
from hil_bridge.recording.logs.ulog import read_ulog

DATA = Path(__file__).resolve().parents[3] / "data" / "flightlogs"
CUBE = DATA / "px4_cubeorange_vtol.ulg"
SITL = DATA / "px4_sitl_quad_events.ulg"
PLANE = DATA / "ardupilot_plane_pixracer_short.bin"
COPTER = DATA / "ardupilot_copter_v462_short.bin"
DEG, CM, RAD = 1e-6, 0.01, 1e-6
#: NED <-> ENU axes, and FRD <-> FLU: the frames' definitions, not the project's converter
NED_ENU = np.array([[0.0, 1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, -1.0]])
FRD_FLU = np.diag([1.0, -1.0, -1.0])


def _pyulog(path: Path) -> dict[tuple[str, int], dict[str, np.ndarray]]:
    from pyulog import ULog

    return {(d.name, d.multi_id): d.data for d in ULog(str(path)).data_list}


@pytest.fixture(scope="module")
def cube() -> dict[tuple[str, int], dict[str, np.ndarray]]:
    return _pyulog(CUBE)


@pytest.fixture(scope="module")
def sitl() -> dict[tuple[str, int], dict[str, np.ndarray]]:
    return _pyulog(SITL)


def _dfreader(path: Path) -> dict[str, list[Any]]:
    from pymavlink import DFReader

    reader = DFReader.DFReader_binary(str(path), zero_time_base=False)
    out: dict[str, list[Any]] = {"POS": [], "ATT": [], "GPS": [], "GPS2": []}
    try:
        while (m := reader.recv_match(type=list(out))) is not None:
            out[m.get_type()].append(m)
    finally:
        reader.filehandle.close()
    return out


def _rows(msgs: list[Any], fields: tuple[str, ...]) -> np.ndarray:
    return np.array([[float(getattr(m, f)) for f in fields] for m in msgs])


def _enu_flu(r_ned_frd: Rotation) -> Rotation:
    """World-from-body ENU/FLU of a world-from-body NED/FRD rotation, by the axes' definition."""
    return Rotation.from_matrix(NED_ENU @ r_ned_frd.as_matrix() @ FRD_FLU)


def _check_attitude(log: PoseLog, t: np.ndarray, oracle: Rotation) -> None:
    assert log.att_t is not None and log.att_q is not None
    np.testing.assert_allclose(log.att_t, t, rtol=0, atol=1e-9)
    got = Rotation.from_quat(log.att_q[:, [1, 2, 3, 0]])  # [w, x, y, z] -> scipy's [x, y, z, w]
    assert np.max((got.inv() * _enu_flu(oracle)).magnitude()) < RAD


def _check_positions(path: Path, log: PoseLog, t: np.ndarray, geo: np.ndarray,
                     **read: Any) -> None:
    """``log`` (the reader's samples) and the trajectory of ``read_log`` against the tool's
    times ``t`` (s) and ``geo`` (lat deg, lon deg, alt m)."""
    import pymap3d

    assert log.frame == "geodetic" and len(log.t) == len(t)
    np.testing.assert_allclose(log.t, t, rtol=0, atol=1e-9)
    np.testing.assert_allclose(log.position[:, :2], geo[:, :2], rtol=0, atol=DEG)
    np.testing.assert_allclose(log.position[:, 2], geo[:, 2], rtol=0, atol=CM)
    traj, report = read_log(path, **read)
    assert report.samples == len(t) and report.jumps == []
    assert traj.duration == pytest.approx(t[-1] - t[0], abs=1e-9)
    assert report.origin is not None
    lat, lon, alt = pymap3d.enu2geodetic(*traj.xyz.T, *report.origin)
    np.testing.assert_allclose(np.stack([lat, lon], axis=1), geo[:, :2], rtol=0, atol=DEG)
    np.testing.assert_allclose(alt, geo[:, 2], rtol=0, atol=CM)


def test_px4_cubeorange_ulog_without_a_local_estimate_reads_its_gps_as_pyulog(
    cube: dict[tuple[str, int], dict[str, np.ndarray]],
) -> None:
    assert detect_format(CUBE) == "ulog"
    assert ("vehicle_global_position", 0) not in cube
    local = cube[("vehicle_local_position", 0)]
    assert not local["xy_valid"].any() and not local["xy_global"].any()  # README: no estimate
    gps = cube[("vehicle_gps_position", 0)]
    assert [i for n, i in cube if n == "vehicle_gps_position"] == [0]  # one receiver
    fix = gps["fix_type"] >= 3
    geo = np.stack([gps["lat"][fix] * 1e-7, gps["lon"][fix] * 1e-7, gps["alt"][fix] * 1e-3],
                   axis=1)
    log = read_ulog(CUBE)
    assert log.source == "vehicle_gps_position" and len(log.t) == 32
    assert any("vehicle_local_position: xy_valid or z_valid false in all 636" in n
               for n in log.notes)
    assert not any("other instances" in n for n in log.notes)
    _check_positions(CUBE, log, gps["timestamp"][fix] * 1e-6, geo)
    att = cube[("vehicle_attitude", 0)]
    q = np.stack([att[f"q[{i}]"] for i in (1, 2, 3, 0)], axis=1)
    _check_attitude(log, att["timestamp"] * 1e-6, Rotation.from_quat(q))
    with pytest.raises(NoPoseError, match=r"px4_cubeorange_vtol.ulg: vehicle_local_position: "
                                          r"xy_valid or z_valid false in all 636 samples"):
        read_log(CUBE, topic="vehicle_local_position")


def test_px4_sitl_ulog_global_and_gps_positions_read_as_pyulog(
    sitl: dict[tuple[str, int], dict[str, np.ndarray]],
) -> None:
    glob = sitl[("vehicle_global_position", 0)]
    log = read_ulog(SITL)
    assert log.source == "vehicle_global_position" and len(log.t) == 109
    _check_positions(SITL, log, glob["timestamp"] * 1e-6,
                     np.stack([glob["lat"], glob["lon"], glob["alt"]], axis=1))
    att = sitl[("vehicle_attitude", 0)]
    q = np.stack([att[f"q[{i}]"] for i in (1, 2, 3, 0)], axis=1)
    _check_attitude(log, att["timestamp"] * 1e-6, Rotation.from_quat(q))
    for topic in ("vehicle_gps_position", "sensor_gps"):  # PX4 1.14 fields, degrees and m
        assert [i for n, i in sitl if n == topic] == [0]
        g = sitl[(topic, 0)]
        fix = g["fix_type"] >= 3
        geo = np.stack([g["latitude_deg"][fix], g["longitude_deg"][fix],
                        g["altitude_msl_m"][fix]], axis=1)
        got = read_ulog(SITL, topic=topic)
        assert got.source == topic and 0 < len(got.t) < len(g["timestamp"])
        _check_positions(SITL, got, g["timestamp"][fix] * 1e-6, geo, topic=topic)


def test_px4_local_position_with_its_reference_is_placed_where_px4_placed_it(
    sitl: dict[tuple[str, int], dict[str, np.ndarray]],
) -> None:
    """``vehicle_local_position`` about its reference lands on PX4's own
    ``vehicle_global_position`` of the same estimator sample (PX4 computes one from the
    other), so ``--origin`` works for it and it lines up with GPS logs."""
    local = sitl[("vehicle_local_position", 0)]
    glob = sitl[("vehicle_global_position", 0)]
    usable = (local["xy_valid"] & local["z_valid"] & local["xy_global"]
              & local["z_global"]).astype(bool)
    assert 0 < usable.sum() < len(usable)  # the first samples have no estimate yet
    log = read_ulog(SITL, topic="vehicle_local_position")
    assert log.frame == "geodetic" and len(log.t) == usable.sum()
    np.testing.assert_allclose(log.t, local["timestamp"][usable] * 1e-6, rtol=0, atol=1e-9)
    kept = local["timestamp_sample"][usable]
    same, i, j = np.intersect1d(kept, glob["timestamp_sample"], return_indices=True)
    assert len(same) > 100
    np.testing.assert_allclose(log.position[i, :2],
                               np.stack([glob["lat"][j], glob["lon"][j]], axis=1),
                               rtol=0, atol=1e-9)
    np.testing.assert_allclose(log.position[i, 2], glob["alt"][j], rtol=0, atol=1e-3)
    origin = (float(glob["lat"][0]), float(glob["lon"][0]), float(glob["alt"][0]))
    traj, report = read_log(SITL, topic="vehicle_local_position", origin=origin)
    by_gps, _ = read_log(SITL, origin=origin)  # the global track, about the same origin
    assert report.origin == origin
    at = (traj.t >= by_gps.t[0]) & (traj.t <= by_gps.t[-1])
    err = np.abs(traj.xyz[at] - np.stack([np.interp(traj.t[at], by_gps.t, by_gps.xyz[:, k])
                                          for k in range(3)], axis=1))
    assert err.max() < 0.5  # one frame: only the global stream's 5 Hz sampling apart


@pytest.mark.parametrize("path", [PLANE, COPTER], ids=["plane-3.8", "copter-4.6"])
def test_ardupilot_dataflash_reads_as_pymavlink(path: Path) -> None:
    assert detect_format(path) == "dataflash"
    df = _dfreader(path)
    pos = _rows(df["POS"], ("TimeUS", "Lat", "Lng", "Alt"))
    log = read_dataflash(path)
    assert log.source == "POS" and log.att_source == "ATT"
    _check_positions(path, log, pos[:, 0] * 1e-6, pos[:, 1:4])
    att = _rows(df["ATT"], ("TimeUS", "Roll", "Pitch", "Yaw"))
    oracle = Rotation.from_euler("ZYX", att[:, [3, 2, 1]], degrees=True)  # NED/FRD Z-Y-X
    _check_attitude(log, att[:, 0] * 1e-6, oracle)
    # one GPS receiver in each file (README), found, used and named; no second one invented
    instances = {int(getattr(m, "I", 0)) for m in df["GPS"]}
    assert instances == {0} and df["GPS2"] == []
    gps = [m for m in df["GPS"] if m.Status >= 3]
    g = _rows(gps, ("TimeUS", "Lat", "Lng", "Alt"))
    got = read_dataflash(path, topic="GPS[0]")
    assert got.source == ("GPS[0]" if "I" in df["GPS"][0].fmt.colhash else "GPS")
    _check_positions(path, got, g[:, 0] * 1e-6, g[:, 1:4], topic="GPS[0]")
    with pytest.raises(NoPoseError, match=r"GPS\[1\]: no such receiver; position sources in "
                                          r"the log: AHR2 \(\d+\), GPS(\[0\])? \(\d+\), POS"):
        read_log(path, topic="GPS[1]")
