"""``topic`` names the position source in every reader (a wrong name fails in one line listing
the file's names; tables refuse it), and position jumps are found, reported with their time and
size, and never flown: the log is split there and one segment flown."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from hil_bridge.recording.logs import NoPoseError, read_log

DATA = Path(__file__).resolve().parents[3] / "data" / "flightlogs"
TLOG = DATA / "ardupilot_quadplane_sitl.tlog"
SITL = DATA / "px4_sitl_quad_events.ulg"
COPTER = DATA / "ardupilot_copter_v462_short.bin"


@pytest.mark.parametrize(("path", "topic", "listed"), [
    (TLOG, "GPS_RAW_INT", r"not a position message of system 1 in this tlog; it has "
                          r"GLOBAL_POSITION_INT \(807\), LOCAL_POSITION_NED \(807\)$"),
    (SITL, "vehicle_gps", r"not a position topic of this ULog; it has sensor_gps \(31\), "
                          r"vehicle_global_position \(109\), vehicle_gps_position \(583\), "
                          r"vehicle_local_position \(313\)"),
    (SITL, "vehicle_gps_position[1]", r"not a position topic of this ULog; it has sensor_gps"),
    (COPTER, "XKF1", r"expected a DataFlash position message, .*; the log has AHR2 \(4\), "
                     r"GPS\[0\] \(2\), POS \(4\)$"),
], ids=["tlog", "ulog", "ulog-instance", "dataflash"])
def test_a_wrong_topic_fails_in_one_line_listing_the_files_names(
    path: Path, topic: str, listed: str,
) -> None:
    with pytest.raises(ValueError, match=rf"^{path}: topic {topic!r}: ".replace("[", r"\[")
                       .replace("]", r"\]") + listed) as err:
        read_log(path, topic=topic)
    assert "\n" not in str(err.value)


def test_topic_chooses_a_tlogs_position_message() -> None:
    """(The ULog's topics: test_real_ulog_dataflash.py.)"""
    default, report = read_log(TLOG)
    named, named_report = read_log(TLOG, topic="GLOBAL_POSITION_INT")
    np.testing.assert_array_equal(named.xyz, default.xyz)
    assert named_report.source == report.source == "GLOBAL_POSITION_INT"
    _, local = read_log(TLOG, topic="LOCAL_POSITION_NED")
    assert local.source == "LOCAL_POSITION_NED" and local.origin is None


@pytest.mark.parametrize("suffix", [".csv", ".npz"])
def test_a_table_refuses_a_topic(tmp_path: Path, suffix: str) -> None:
    path = tmp_path / f"track{suffix}"
    t = np.arange(5.0)
    if suffix == ".csv":
        path.write_text("t,x,y,z\n" + "".join(f"{v},{v},0,10\n" for v in t), encoding="utf-8")
    else:
        np.savez(path, t=t, x=t, y=0 * t, z=0 * t + 10)
    read_log(path)
    with pytest.raises(ValueError, match=rf"track{suffix}: topic '/odom': a "
                                         rf"{suffix[1:].upper()} table has no topics"):
        read_log(path, topic="/odom")


def test_a_recordings_topic_names_its_glider(tmp_path: Path) -> None:
    from mcap.well_known import MessageEncoding

    from hil_bridge.bus.codec import Header, encode_payload
    from hil_bridge.bus.messages import GliderState
    from hil_bridge.recording.bag_writer import BagWriter

    path = tmp_path / "run.mcap"
    with open(path, "wb") as f:
        bag = BagWriter(f, chunk_size=4096, compression="zstd",
                        message_encoding=MessageEncoding.MessagePack, as_json=False)
        for k in range(5):
            for gid in (3, 4):
                st = GliderState(stamp_ns=k * 10**8, x=float(gid * k), y=0.0, z=9.0,
                                 heading=0.0, bank=0.0, airspeed=10.0, vz=0.0, glider_id=gid)
                hdr = Header(GliderState.TYPE, GliderState.VERSION, k, st.stamp_ns, 0, "", "s")
                bag.add(f"/glider/{gid}/state", hdr, encode_payload(st), k)
        bag.writer.finish()
    traj, report = read_log(path, topic="/glider/4/state")
    assert report.source == "/glider/4/state" and report.vehicle_id == 4
    np.testing.assert_allclose(traj.xyz[:, 0], 4.0 * np.arange(5))
    with pytest.raises(ValueError, match=r"topic '/glider/5/state': not a state topic of this "
                                         r"recording; it has /glider/3/state \(5\), "
                                         r"/glider/4/state \(5\)$"):
        read_log(path, topic="/glider/5/state")


def test_the_real_tlogs_origin_reset_at_disarm_is_found_and_not_flown() -> None:
    """LOCAL_POSITION_NED jumps 544 m south, 42 m east, 8 m down once after the disarm
    (``Land complete`` at time_boot_ms 784,882; the README): one jump, two segments, the
    longer one (the flight) flown, no step of it faster than the threshold."""
    traj, report = read_log(TLOG, topic="LOCAL_POSITION_NED")
    assert len(report.jumps) == 1
    at, size, speed = report.jumps[0]
    assert at == pytest.approx(785.526) and size == pytest.approx(np.hypot(544, 42), abs=3.0)
    assert speed == pytest.approx(size / (785.526 - 785.284), rel=1e-9)
    assert [(a, b) for a, b, _ in report.segments] == [pytest.approx((608.582, 785.284)),
                                                       pytest.approx((785.526, 816.994))]
    assert [n for _, _, n in report.segments] == [680, 124] and report.segment == 0
    assert traj.t[0] == pytest.approx(608.582) and traj.t[-1] == pytest.approx(785.284)
    steps = np.linalg.norm(np.diff(traj.xyz, axis=0), axis=1) / np.diff(traj.t)
    assert steps.max() < 40.0  # the flight's own speeds, nothing near the jump's
    assert any("position jumps (faster than 150 m/s): 1, never flown (785.526 s: 545." in line
               for line in report.lines())
    after, after_report = read_log(TLOG, topic="LOCAL_POSITION_NED", segment=1)
    assert after_report.segment == 1 and after.t[0] == pytest.approx(785.526)
    assert len(after) == 124
    with pytest.raises(ValueError, match=r"segment 2: LOCAL_POSITION_NED has 2 segment\(s\) "
                                         r"between its position jumps \(0: 608.582-785.284 s "
                                         r"\(680 poses\), 1: 785.526-816.994 s \(124 poses\)\)"):
        read_log(TLOG, topic="LOCAL_POSITION_NED", segment=2)


def _glitch(tmp_path: Path, size_m: float) -> Path:
    """10 m/s east for 10 s at 10 Hz; at t = 4.0 s one sample ``size_m`` north (a glitch)."""
    t = np.round(np.arange(0.0, 10.0001, 0.1), 3)
    y = np.where(t == 4.0, size_m, 0.0)
    path = tmp_path / "glitch.csv"
    path.write_text("t,x,y,z\n" + "".join(f"{a},{10 * a},{b},20\n" for a, b in
                                          zip(t, y, strict=True)), encoding="utf-8")
    return path


def test_a_gps_glitch_splits_the_log_and_the_longest_segment_is_flown(tmp_path: Path) -> None:
    path = _glitch(tmp_path, 50.0)  # 50 m in 0.1 s: 500 m/s, out and back
    traj, report = read_log(path)
    assert [(a, round(m, 6)) for a, m, _ in report.jumps] == [
        (pytest.approx(4.0), round(float(np.hypot(1.0, 50.0)), 6)),
        (pytest.approx(4.1), round(float(np.hypot(1.0, 50.0)), 6))]
    assert [n for _, _, n in report.segments] == [40, 1, 60]
    assert report.segment == 2  # 4.1-10.0 s is longer than 0.0-3.9 s
    np.testing.assert_allclose(traj.t, np.round(np.arange(4.1, 10.0001, 0.1), 3))
    assert np.all(traj.xyz[:, 1] == 0.0)  # nothing of the glitch
    first, _ = read_log(path, segment=0)
    assert first.t[-1] == pytest.approx(3.9) and np.all(first.xyz[:, 1] == 0.0)
    with pytest.raises(NoPoseError, match=r"glitch.csv: columns t, x, y, z: segment 1 has a "
                                          r"single pose"):
        read_log(path, segment=1)
    # the threshold is the caller's: at 1000 m/s the same step is no jump
    flown, lenient = read_log(path, max_speed_mps=1000.0)
    assert lenient.jumps == [] and len(lenient.segments) == 1 and len(flown) == 101


def test_replay_cli_reports_the_jump_and_flies_one_segment(
    tmp_path: Path, capsys: pytest.CaptureFixture[str],
) -> None:
    from hil_bridge.cli.replay import main

    scene = tmp_path / "empty.yaml"
    scene.write_text("{}\n", encoding="utf-8")
    path = _glitch(tmp_path, 50.0)
    assert main([str(path), "--fast", "--scene", str(scene), "--sonar", "0", "--json",
                 "--bus", "mem://replay_jump", "--state-rate", "10", "--segment", "0",
                 "--max-speed", "200"]) == 0
    out = capsys.readouterr()
    assert "position jumps (faster than 200 m/s): 2, never flown" in out.err
    assert "segment 0 flown" in out.err
    summary = json.loads(out.out)
    assert summary["log"]["segment"] == 0 and len(summary["log"]["segments"]) == 3
    assert summary["stopped_by"] == "finished"
    assert summary["nodes"]["server"]["sim_time_s"] == pytest.approx(3.9)
