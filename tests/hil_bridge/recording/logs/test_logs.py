"""Every log kind replays to the poses it was written from (hil_bridge.recording.logs)."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

from hil_bridge.recording.logs import NoPoseError, detect_format, read_log
from sim_core.trajectory import Trajectory
from tests.hil_bridge.recording.logs.logmakers import (
    ORIGIN,
    Flight,
    truth,
    write_dataflash,
    write_ros2_bag,
    write_tlog,
    write_ulog,
)

POS_T = np.arange(0.0, 4.0001, 0.1)  # 10 Hz positions
ATT_T = np.arange(0.0, 4.0001, 0.04)  # 25 Hz attitude


def _same_rotation(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Angle (rad) between unit quaternions (..., 4), sign-insensitive."""
    return 2 * np.arccos(np.clip(np.abs(np.sum(a * b, axis=-1)), 0.0, 1.0))


def _check(traj: Trajectory, flight: Flight, *, pos_tol: float, att_tol: float = 1e-5) -> None:
    np.testing.assert_allclose(traj.t - traj.t[0], flight.t - flight.t[0], atol=1e-6)
    np.testing.assert_allclose(traj.xyz, flight.enu, atol=pos_tol)
    assert traj.quat is not None
    assert np.max(_same_rotation(traj.quat, flight.quat)) < att_tol
    heading_err = (traj.heading - flight.yaw + math.pi) % (2 * math.pi) - math.pi
    assert np.max(np.abs(heading_err)) < att_tol
    np.testing.assert_allclose(traj.bank, -flight.roll, atol=att_tol)


@pytest.mark.parametrize("local", [True, False], ids=["local-ned", "global"])
def test_ulog_replays_to_the_written_poses(tmp_path: Path, local: bool) -> None:
    path = tmp_path / "flight.ulg"
    write_ulog(path, truth(POS_T), truth(ATT_T), local=local, glob=not local)
    assert detect_format(path) == "ulog"
    traj, report = read_log(path)
    # float32 NED metres (local) / float32 altitude (global) bound the position error
    _check(traj, truth(POS_T), pos_tol=1e-4)
    assert report.source == ("vehicle_local_position" if local else "vehicle_global_position")
    assert report.att_source == "vehicle_attitude"
    assert (report.origin is None) == local
    if not local:
        assert report.origin == pytest.approx(ORIGIN)
    np.testing.assert_allclose(traj.airspeed[1:-1], 12.0 * np.hypot(1, 1 / 12), rtol=2e-3)


def test_ulog_without_position_lists_what_it_holds(tmp_path: Path) -> None:
    path = tmp_path / "nopose.ulg"
    write_ulog(path, truth(POS_T), truth(ATT_T), local=False, glob=False)
    with pytest.raises(NoPoseError, match=r"nopose.ulg: PX4 ULog without a usable pose.*"
                                          r"battery_status \(41\), vehicle_attitude \(101\)"):
        read_log(path)


def test_dataflash_replays_to_the_written_poses(tmp_path: Path) -> None:
    path = tmp_path / "00000042.BIN"
    write_dataflash(path, truth(POS_T), truth(ATT_T))
    assert detect_format(path) == "dataflash"
    traj, report = read_log(path)
    # 1e-7 deg integers: 1.1 cm north, 0.75 cm east at this latitude
    _check(traj, truth(POS_T), pos_tol=0.012, att_tol=1e-5)
    assert (report.source, report.att_source) == ("POS", "ATT")
    np.testing.assert_allclose(traj.t - traj.t[0], POS_T, atol=1e-9)


def test_dataflash_without_position_lists_what_it_holds(tmp_path: Path) -> None:
    path = tmp_path / "att_only.bin"
    write_dataflash(path, truth(POS_T), truth(ATT_T), with_pos=False)
    with pytest.raises(NoPoseError, match=r"att_only.bin: DataFlash .* ATT \(101\), BAT \(41\)"):
        read_log(path)


def test_tlog_replays_to_the_written_poses(tmp_path: Path) -> None:
    path = tmp_path / "flight.tlog"
    write_tlog(path, truth(POS_T), truth(ATT_T))
    assert detect_format(path) == "tlog"
    traj, report = read_log(path)
    _check(traj, truth(POS_T), pos_tol=0.012)  # 1e-7 deg and mm integers
    assert (report.source, report.att_source) == ("GLOBAL_POSITION_INT", "ATTITUDE_QUATERNION")
    assert report.vehicle_id == 1


def test_tlog_with_two_vehicles_needs_an_id_and_local_ned_works(tmp_path: Path) -> None:
    path = tmp_path / "two.tlog"
    write_tlog(path, truth(POS_T), truth(ATT_T), sysids=(1, 7), local=True)
    with pytest.raises(ValueError, match=r"system ids\) \[1, 7\]; choose one"):
        read_log(path)
    traj, report = read_log(path, vehicle_id=7)
    _check(traj, truth(POS_T), pos_tol=1e-4)
    assert report.source == "LOCAL_POSITION_NED" and report.origin is None
    with pytest.raises(ValueError, match="--origin needs geodetic positions"):
        read_log(path, vehicle_id=7, origin=ORIGIN)


@pytest.mark.parametrize("storage", ["mcap", "sqlite3"])
def test_ros2_bag_replays_to_the_written_poses(tmp_path: Path, storage: str) -> None:
    bag = tmp_path / f"bag_{storage}"
    write_ros2_bag(bag, truth(POS_T), storage=storage, extra_topic=True)
    with pytest.raises(ValueError, match=r"pose topics \['/odom', '/pose'\]; choose one"):
        read_log(bag)
    for target in (bag, next(bag.glob("*.mcap" if storage == "mcap" else "*.db3"))):
        assert detect_format(target) == "ros2"
        traj, report = read_log(target, topic="/odom")
        flight = truth(POS_T)
        np.testing.assert_allclose(traj.t, flight.t + 5.0, atol=1e-9)  # header stamps
        np.testing.assert_allclose(traj.xyz, flight.enu, atol=1e-9)
        assert np.max(_same_rotation(traj.quat, flight.quat)) < 1e-7
        assert report.source == "/odom [nav_msgs/msg/Odometry]"
    traj, _ = read_log(bag, topic="/pose")
    np.testing.assert_allclose(traj.xyz, truth(POS_T).enu, atol=1e-9)


def test_ros2_bag_without_pose_lists_its_topics(tmp_path: Path) -> None:
    bag = tmp_path / "status_only"
    write_ros2_bag(bag, truth(POS_T), storage="mcap", with_pose=False)
    with pytest.raises(NoPoseError, match=r"without a pose topic.*/status \[std_msgs/msg/String\] "
                                          r"\(41\)"):
        read_log(bag)
    bag2 = tmp_path / "with_pose"
    write_ros2_bag(bag2, truth(POS_T), storage="mcap")
    with pytest.raises(NoPoseError, match=r"topic '/status' holds no pose"):
        read_log(bag2, topic="/status")


def test_geodetic_csv_about_first_fix_and_given_origin(tmp_path: Path) -> None:
    flight = truth(POS_T)
    g = flight.geodetic
    path = tmp_path / "gps.csv"
    rows = ["t,lat,lon,alt"] + [",".join(repr(float(v)) for v in (t, *llh)) for t, llh in zip(
        flight.t, g, strict=True)]
    path.write_text("\n".join(rows) + "\n", encoding="utf-8")
    traj, report = read_log(path)  # the first fix is the origin (the flight starts there)
    np.testing.assert_allclose(traj.xyz, flight.enu, atol=1e-6)
    assert report.origin == pytest.approx(ORIGIN)
    assert "(no attitude: heading and bank from the track)" in report.lines()[0]
    # hand-computed: an origin 0.001 deg of longitude east of the first fix moves x by
    # -(N + h) cos(lat) sin(dlon) (WGS-84: N the prime vertical radius at the latitude)
    lat0 = math.radians(ORIGIN[0])
    n = 6378137.0 / math.sqrt(1 - 6.69437999014e-3 * math.sin(lat0) ** 2)
    shifted = (ORIGIN[0], ORIGIN[1] + 0.001, ORIGIN[2])
    moved, _ = read_log(path, origin=shifted)
    east = -(n + ORIGIN[2]) * math.cos(lat0) * math.sin(math.radians(0.001))
    assert moved.xyz[0, 0] == pytest.approx(east, abs=1e-4)
    assert moved.xyz[0, 1] == pytest.approx(0.0, abs=0.01)
    # no attitude in the file: heading from the track, bank of the coordinated turn
    heading_err = (traj.heading - flight.yaw + math.pi) % (2 * math.pi) - math.pi
    assert np.max(np.abs(heading_err[1:-1])) < 0.01
    np.testing.assert_allclose(traj.bank[2:-2], -flight.roll[2:-2], atol=0.01)


def test_gaps_and_time_jumps_are_reported_not_hidden(tmp_path: Path) -> None:
    t = [0.0, 0.1, 0.2, 0.3, 2.8, 2.9, 2.5, 3.0, 3.0, 3.1]
    path = tmp_path / "jumpy.csv"
    rows = ["t,x,y,z"] + [f"{v},{10 * v},0,5" for v in t]
    path.write_text("\n".join(rows) + "\n", encoding="utf-8")
    traj, report = read_log(path, max_gap_s=1.0)
    assert report.gaps == [(0.3, 2.8)]
    assert report.backward == [(2.9, 2.5), (3.0, 3.0)]
    assert len(traj) == 8
    text = "\n".join(report.lines())
    assert "time gaps: 1, interpolated linearly across (0.300-2.800 s)" in text
    assert "time jumps back: 2 sample(s) dropped (2.900 -> 2.500 s, 3.000 -> 3.000 s)" in text


def test_unknown_content_names_the_file(tmp_path: Path) -> None:
    path = tmp_path / "mystery.dat"
    path.write_bytes(b"\x00\x01\x02 not a log")
    with pytest.raises(ValueError, match=r"mystery.dat: unknown log format"):
        read_log(path)
    renamed = tmp_path / "really_a_ulog.csv"
    write_ulog(renamed, truth(POS_T), truth(ATT_T), local=True, glob=False)
    assert detect_format(renamed) == "ulog"  # content first, extension second


def test_echoloop_recording_replays_the_chosen_glider(tmp_path: Path) -> None:
    from mcap.well_known import MessageEncoding

    from hil_bridge.bus.codec import Header, encode_payload
    from hil_bridge.bus.messages import GliderState
    from hil_bridge.recording.bag_writer import BagWriter

    path = tmp_path / "run.mcap"
    with open(path, "wb") as f:
        bag = BagWriter(f, chunk_size=4096, compression="zstd",
                         message_encoding=MessageEncoding.MessagePack, as_json=False)
        for k in range(20):
            for gid in (3, 4):
                st = GliderState(stamp_ns=k * 50_000_000, x=2.0 * k + gid, y=-k, z=100.0,
                                 heading=0.1 * k, bank=0.2, airspeed=11.0, vz=0.0,
                                 glider_id=gid, alive=not (gid == 4 and k > 10))
                hdr = Header(GliderState.TYPE, GliderState.VERSION, k, st.stamp_ns, 0, "", "s")
                bag.add(f"/glider/{gid}/state", hdr, encode_payload(st), k)
        bag.writer.finish()
    assert detect_format(path) == "echoloop"
    with pytest.raises(ValueError, match=r"holds vehicles \[3, 4\]; choose one"):
        read_log(path)
    traj, report = read_log(path, vehicle_id=4)
    assert len(traj) == 11  # dead states dropped
    np.testing.assert_allclose(traj.xyz[:, 0], 2.0 * np.arange(11) + 4)
    np.testing.assert_allclose(traj.heading, 0.1 * np.arange(11))
    assert report.format == "echoloop recording" and report.source == "/glider/4/state"


def test_replay_cli_flies_a_tlog_and_reports_what_it_read(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    import json

    from hil_bridge.cli.replay import main

    log = tmp_path / "flight.tlog"
    write_tlog(log, truth(POS_T), truth(ATT_T))
    scene = tmp_path / "empty.yaml"
    scene.write_text("{}\n", encoding="utf-8")
    assert main([str(log), "--fast", "--scene", str(scene), "--sonar", "0", "--json",
                 "--bus", "mem://replay_tlog", "--duration", "1.0"]) == 0
    out = capsys.readouterr()
    assert "MAVLink tlog, GLOBAL_POSITION_INT + ATTITUDE_QUATERNION: 41 poses" in out.err
    summary = json.loads(out.out)
    assert summary["log"]["origin"] == pytest.approx(list(ORIGIN))
    assert summary["nodes"]["server"]["sim_time_s"] == pytest.approx(4.0)
    assert summary["nodes"]["server"]["states_published"] >= 200  # 50 Hz over 4 s of sim time


def _bad_files(d: Path) -> dict[str, Path]:
    write_ulog(d / "good.ulg", truth(POS_T), truth(ATT_T), local=True, glob=False)
    write_dataflash(d / "good.bin", truth(POS_T), truth(ATT_T))
    ulg, df = (d / "good.ulg").read_bytes(), (d / "good.bin").read_bytes()
    rng = np.random.default_rng(4)
    files = {
        "ulog cut in its header": ulg[:20],
        "random bytes named .ulg": bytes(rng.integers(0, 256, 300, dtype=np.uint8)),
        "dataflash magic then garbage": b"\xa3\x95" + bytes(rng.integers(0, 256, 500,
                                                                         dtype=np.uint8)),
        "empty tlog": b"",
        "sqlite magic then garbage": b"SQLite format 3\x00" + rng.bytes(200),
        "mcap magic then garbage": b"\x89MCAP0\r\n" + rng.bytes(200),
        "empty csv": b"",
        "csv header only": b"t,x,y,z\n",
    }
    names = ["a.ulg", "b.ulg", "c.bin", "d.tlog", "e.db3", "f.mcap", "g.csv", "h.csv"]
    out = {}
    for (label, data), name in zip(files.items(), names, strict=True):
        (d / name).write_bytes(data)
        out[label] = d / name
    (d / "cut.ulg").write_bytes(ulg[: len(ulg) // 2 + 3])
    (d / "cut.bin").write_bytes(df[: len(df) // 2 + 5])
    return out


def test_any_garbage_after_a_bag_s_magic_fails_with_one_line_naming_the_file(
        tmp_path: Path) -> None:
    """Seeded garbage behind MCAP's and SQLite's magic: rosbags raises TypeError,
    OverflowError or MemoryError on some of it (about 1 in 100), besides its own errors; each
    file fails with one ValueError naming it."""
    rng = np.random.default_rng(0)
    for k in range(1500):
        magic, ext = ((b"\x89MCAP0\r\n", "mcap"), (b"SQLite format 3\x00", "db3"))[k % 2]
        path = tmp_path / f"g{k}.{ext}"
        path.write_bytes(magic + rng.bytes(int(rng.integers(0, 400))))
        with pytest.raises(ValueError) as info:
            read_log(path)
        msg = str(info.value)
        assert msg.startswith(f"{path}: ") and "\n" not in msg, msg
        path.unlink()


def test_bad_files_fail_with_one_line_naming_the_file_and_parsers_stay_quiet(
    tmp_path: Path, capfd: pytest.CaptureFixture[str]
) -> None:
    for label, path in _bad_files(tmp_path).items():
        with pytest.raises(ValueError) as info:
            read_log(path)
        msg = str(info.value)
        assert msg.startswith(f"{path}: ") and "\n" not in msg, (label, msg)
    for cut in ("cut.ulg", "cut.bin"):  # cut mid-record: every complete record is read
        traj, _ = read_log(tmp_path / cut)
        assert 15 <= len(traj) < len(POS_T)
        np.testing.assert_allclose(traj.xyz, truth(POS_T).enu[: len(traj)], atol=0.012)
    out = capfd.readouterr()
    assert out.out == "" and out.err == ""  # pyulog's and pymavlink's prints became notes
