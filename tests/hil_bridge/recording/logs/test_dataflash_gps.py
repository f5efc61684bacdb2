"""DataFlash logs of two GPS receivers, their records interleaved as ArduPilot's logger writes
them: the track is one receiver's, never a zigzag between the two (hil_bridge.recording.logs)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from hil_bridge.recording.logs import NoPoseError, read_log
from tests.hil_bridge.recording.logs.logmakers import Flight, truth, write_dataflash_gps

GPS_T = np.arange(0.0, 4.0001, 0.2)  # 5 Hz, as ArduPilot logs GPS
ATT_T = np.arange(0.0, 4.0001, 0.04)
#: where the second antenna is, about the first (m ENU): a receiver far off, as a bad one is
OFFSET = np.array([30.0, -20.0, 5.0])
LAYOUTS = ["4x", "4x-no-fmtu", "3x"]


def _receivers() -> tuple[Flight, Flight]:
    """The first receiver on the known flight; the second 0.1 s later and :data:`OFFSET` off."""
    first = truth(GPS_T)
    late = truth(GPS_T + 0.1)
    second = Flight(late.t, late.enu + OFFSET, late.roll, late.pitch, late.yaw)
    return first, second


def _write(tmp_path: Path, layout: str, no_fix: tuple[int, ...] = (0, 3)) -> Path:
    path = tmp_path / f"gps_{layout}.bin"
    write_dataflash_gps(path, list(_receivers()), truth(ATT_T), layout=layout, no_fix=no_fix)
    return path


@pytest.mark.parametrize("layout", LAYOUTS)
def test_two_receivers_give_the_first_ones_track_not_both(tmp_path: Path, layout: str) -> None:
    path = _write(tmp_path, layout)
    traj, report = read_log(path)
    first, _ = _receivers()
    assert len(traj) == len(GPS_T)  # one receiver's samples, not both receivers' 41
    np.testing.assert_allclose(traj.t - traj.t[0], GPS_T, atol=1e-9)
    np.testing.assert_allclose(traj.xyz, first.enu, atol=0.012)  # 1e-7 deg, cm altitude
    assert report.jumps == [] and report.backward == []
    names = ("GPS", "GPS2") if layout == "3x" else ("GPS[0]", "GPS[1]")
    assert report.source == names[0]
    assert f"GPS receivers in the log: {names[0]}, {names[1]}; {names[0]} used" in "\n".join(
        report.lines())


def test_pymavlink_sees_the_4x_receivers_as_instances(tmp_path: Path) -> None:
    """The 4.x log is what pymavlink takes for ArduPilot's: FMTU declares ``I`` the instance
    field (its unit ``#``), so pymavlink itself files the records as GPS[0] and GPS[1]."""
    from pymavlink import DFReader

    for layout, field in (("4x", "I"), ("4x-no-fmtu", None)):
        reader = DFReader.DFReader_binary(str(_write(tmp_path, layout)), zero_time_base=False)
        try:
            m = reader.recv_match(type="GPS")
            assert m.fmt.instance_field == field
            while reader.recv_match(type="GPS") is not None:
                pass
            instances = {k for k in reader.messages if k.startswith("GPS[")}
            assert instances == ({"GPS[0]", "GPS[1]"} if field else set())
        finally:
            reader.filehandle.close()


@pytest.mark.parametrize("layout", LAYOUTS)
def test_topic_chooses_the_other_receiver(tmp_path: Path, layout: str) -> None:
    path = _write(tmp_path, layout)
    _, second = _receivers()
    for topic in ("GPS[1]", "GPS2", " GPS2 "):
        traj, report = read_log(path, topic=topic)
        assert len(traj) == len(GPS_T) - 3  # its samples without a fix are dropped
        np.testing.assert_allclose(traj.t - traj.t[0], GPS_T[3:] - GPS_T[3], atol=1e-9)
        np.testing.assert_allclose(traj.xyz, second.enu[3:] - second.enu[3], atol=0.012)
        assert report.source == ("GPS2" if layout == "3x" else "GPS[1]")
    traj, _ = read_log(path, topic="GPS")
    np.testing.assert_allclose(traj.xyz, _receivers()[0].enu, atol=0.012)


def test_a_first_receiver_without_fix_yields_to_the_next(tmp_path: Path) -> None:
    """No 3D fix on receiver 0 at all: the next receiver with one is used, and said."""
    path = _write(tmp_path, "4x", no_fix=(len(GPS_T), 0))
    traj, report = read_log(path)
    _, second = _receivers()
    assert report.source == "GPS[1]"
    np.testing.assert_allclose(traj.xyz, second.enu - second.enu[0], atol=0.012)
    assert "GPS receivers in the log: GPS[0], GPS[1]; GPS[1] used" in "\n".join(report.lines())


@pytest.mark.parametrize(("topic", "says"), [
    ("GPS[7]", r"GPS\[7\]: no such receiver; position sources in the log: GPS\[0\] \(21\), "
               r"GPS\[1\] \(21\)"),
    ("POS", r"no POS messages; position sources in the log: GPS\[0\] \(21\), GPS\[1\] \(21\)"),
    ("GPS[x]", r"topic 'GPS\[x\]': expected a DataFlash position message, POS, AHR2, GPS"),
    ("POS[1]", r"topic 'POS\[1\]': expected a DataFlash position message"),
    ("/odom", r"topic '/odom': expected a DataFlash position message"),
])
def test_a_bad_topic_fails_in_one_line_naming_file_and_value(
    tmp_path: Path, topic: str, says: str,
) -> None:
    path = _write(tmp_path, "4x", no_fix=())
    with pytest.raises(ValueError, match=says) as info:
        read_log(path, topic=topic)
    assert str(info.value).startswith(f"{path}: ") and "\n" not in str(info.value)


def test_a_receiver_that_never_had_a_fix_is_named(tmp_path: Path) -> None:
    path = _write(tmp_path, "3x", no_fix=(0, len(GPS_T)))
    with pytest.raises(NoPoseError, match=r"gps_3x.bin: GPS2: 21 sample\(s\), none with a 3D "
                                          r"fix; position sources in the log: GPS \(21\), "
                                          r"GPS2 \(21\)"):
        read_log(path, topic="GPS2")
