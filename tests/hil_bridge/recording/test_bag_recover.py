"""Corrupt and unfinished recordings: a flipped bit loses one chunk, a killed recorder's file is
recovered into one any MCAP reader opens, info/play/export skip what is corrupt and go on."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import textwrap
from pathlib import Path

import numpy as np
import pytest
from mcap.reader import make_reader

from hil_bridge.bus.codec import decode_payload, encode
from hil_bridge.bus.messages import Clock
from hil_bridge.bus.transport import open_transport
from hil_bridge.cli import main as echoloop
from hil_bridge.errors import OutputExistsError
from hil_bridge.recording.bag import bag_info, read_bag
from hil_bridge.recording.bag_writer import recover
from hil_bridge.recording.mcap_scan import BagFileError, ScanReport, scan
from hil_bridge.recording.recorder import Recorder

ROOT = Path(__file__).resolve().parents[3]
N = 3000


@pytest.fixture(scope="module")
def recording(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A finished recording of N /clock messages (stamps 0..N-1) in many small chunks."""
    path = tmp_path_factory.mktemp("rec") / "clean.mcap"
    bus = f"mem://recover?depth={N + 10}"
    rec = Recorder(path, bus=bus, chunk_size=2048, diagnostics_period_s=0)
    rec.start()
    try:
        with open_transport(bus) as raw:
            for i in range(N):
                raw.publish(encode("/clock", Clock(stamp_ns=i), seq=i, pub_ns=i, src="p"))
        assert rec.wait_for(N, 60)
    finally:
        rec.stop()
    return path


def _stamps(path: Path) -> list[int]:
    return [decode_payload(m.header.type, m.header.v, m.payload).stamp_ns  # type: ignore[attr-defined]
            for m in read_bag(path)]


def _chunk_offsets(path: Path) -> list[tuple[int, int]]:
    with open(path, "rb") as f:
        summary = make_reader(f).get_summary()
    assert summary is not None
    return [(ci.chunk_start_offset, ci.chunk_length) for ci in summary.chunk_indexes]


def _flip(src: Path, dst: Path, offset: int, bit: int = 3) -> None:
    data = bytearray(src.read_bytes())
    data[offset] ^= 1 << bit
    dst.write_bytes(bytes(data))


def _read_with_standard_reader(path: Path) -> list[int]:
    with open(path, "rb") as f:
        reader = make_reader(f)
        assert reader.get_summary() is not None
        return [decode_payload("echoloop/Clock", 1, m.data).stamp_ns  # type: ignore[attr-defined]
                for _, _, m in reader.iter_messages(log_time_order=False)]


@pytest.mark.parametrize("where", ["payload", "length"])
def test_a_flipped_bit_in_one_chunk_loses_only_that_chunk(recording: Path, tmp_path: Path,
                                                          where: str) -> None:
    chunks = _chunk_offsets(recording)
    assert len(chunks) > 10
    offset, length = chunks[len(chunks) // 2]
    # the payload's middle, or the record's length field (the framing itself)
    target = offset + length // 2 if where == "payload" else offset + 1 + 2
    broken = tmp_path / "broken.mcap"
    _flip(recording, broken, target)
    report = ScanReport(str(broken))
    stamps = [decode_payload("echoloop/Clock", 1, m.data).stamp_ns  # type: ignore[attr-defined]
              for m in scan(broken, report) if hasattr(m, "sequence")]
    missing = sorted(set(range(N)) - set(stamps))
    assert stamps == sorted(stamps)  # nothing reordered, nothing duplicated
    assert 0 < len(missing) < 300  # one chunk's worth
    assert missing == list(range(missing[0], missing[-1] + 1))  # one contiguous run
    assert report.corrupt_chunks + report.resyncs >= 1
    assert report.lost == len(missing)  # the file's statistics say exactly what is gone
    fixed = tmp_path / "fixed.mcap"
    assert recover(broken, fixed).messages == len(stamps)
    assert _read_with_standard_reader(fixed) == stamps


def test_the_chunk_that_defined_the_channels_can_be_lost(recording: Path,
                                                         tmp_path: Path) -> None:
    offset, length = _chunk_offsets(recording)[0]
    broken = tmp_path / "first.mcap"
    _flip(recording, broken, offset + length // 2)
    stamps = _stamps(broken)
    assert stamps and stamps[0] > 0 and stamps[-1] == N - 1  # later chunks still decode


def test_killed_recording_is_recovered_into_a_standard_mcap(tmp_path: Path) -> None:
    path = tmp_path / "killed.mcap"
    child = textwrap.dedent(f"""
        import threading
        from hil_bridge.recording.recorder import Recorder
        from hil_bridge.bus.messages import Clock
        from hil_bridge.bus.node import Node
        bus = "mem://kill?depth=100000"
        rec = Recorder({str(path)!r}, bus=bus, chunk_size=4096, flush_period_s=0.02,
                       diagnostics_period_s=0)
        rec.start()
        node = Node("src", bus=bus, diagnostics_period_s=0)
        pub = node.create_publisher(Clock, "/clock")
        i = 0
        while True:
            pub.publish(Clock(stamp_ns=i))
            i += 1
            if i == 2000:
                assert rec.wait_for(2000, 30)
                flushes = rec.stats()["flushes"]
            if i > 2000 and rec.stats()["flushes"] > flushes + 1:
                print("flushed", flush=True)
                flushes = 1 << 60
            threading.Event().wait(0.0005)
    """)
    proc = subprocess.Popen([sys.executable, "-c", child], stdout=subprocess.PIPE, text=True,
                            cwd=ROOT)
    try:
        assert proc.stdout is not None and proc.stdout.readline().strip() == "flushed"
    finally:
        os.kill(proc.pid, signal.SIGKILL)
        proc.wait(timeout=30)
    (part,) = tmp_path.glob(".killed.*.part.mcap")
    with open(part, "rb") as f, pytest.raises(Exception):  # noqa: B017 - any reader error
        list(make_reader(f).iter_messages())  # the standard reader needs the summary
    fixed = tmp_path / "fixed.mcap"
    assert echoloop(["bag", "recover", str(part), str(fixed)]) == 0
    stamps = _read_with_standard_reader(fixed)
    assert len(stamps) >= 2000 and stamps == list(range(len(stamps)))
    info = bag_info(fixed)
    assert not info.truncated and info.messages == len(stamps)
    assert info.topics["/clock"].gaps == 0


def test_recover_reports_kept_and_lost(recording: Path, tmp_path: Path,
                                       capsys: pytest.CaptureFixture[str]) -> None:
    offset, length = _chunk_offsets(recording)[3]
    broken = tmp_path / "b.mcap"
    _flip(recording, broken, offset + length // 2)
    fixed = tmp_path / "f.mcap"
    assert echoloop(["bag", "recover", str(broken), str(fixed)]) == 0
    out = capsys.readouterr().out
    kept = len(_read_with_standard_reader(fixed))
    assert f"kept {kept} messages, lost {N - kept}" in out
    assert echoloop(["bag", "recover", str(broken), str(fixed)]) == 1  # exists: refused
    assert "pass --overwrite" in capsys.readouterr().err
    assert echoloop(["bag", "recover", str(broken), str(broken), "--overwrite"]) == 1
    assert "is also an input" in capsys.readouterr().err


@pytest.mark.parametrize("command", ["info", "play", "export"])
def test_info_play_export_skip_a_corrupt_chunk_with_a_warning(
    recording: Path, tmp_path: Path, command: str, capsys: pytest.CaptureFixture[str]
) -> None:
    offset, length = _chunk_offsets(recording)[5]
    broken = tmp_path / "b.mcap"
    _flip(recording, broken, offset + length // 2)
    args = {"info": ["info", str(broken)],
            "play": ["play", str(broken), "--bus", "mem://playcorrupt", "--rate", "0"],
            "export": ["export", str(broken), "--json", str(tmp_path / "j.mcap")]}[command]
    assert echoloop(["bag", *args]) == 0
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "warning" in err and "1 corrupt chunk(s) skipped" in err
    assert str(broken) in err


def test_random_bit_flips_never_crash_a_reader(recording: Path, tmp_path: Path) -> None:
    data = recording.read_bytes()
    rng = np.random.default_rng(11)
    broken = tmp_path / "r.mcap"
    for offset in rng.integers(8, len(data), 40):
        _flip(recording, broken, int(offset), int(rng.integers(0, 8)))
        report = ScanReport(str(broken))
        kept = sum(1 for m in scan(broken, report) if hasattr(m, "sequence"))
        assert kept >= N - 400, (offset, report.describe())


@pytest.mark.parametrize("content", [b"", b"\x89MCAP", b"plain text, not a recording"],
                         ids=["empty", "partial-magic", "text"])
def test_not_a_recording_is_one_clear_error(tmp_path: Path, content: bytes) -> None:
    path = tmp_path / "x.mcap"
    path.write_bytes(content)
    with pytest.raises(BagFileError, match=r"x\.mcap: not an MCAP file"):
        recover(path, tmp_path / "y.mcap")
    assert not (tmp_path / "y.mcap").exists()
    assert sorted(p.name for p in tmp_path.iterdir()) == ["x.mcap"]


def test_export_onto_its_input_is_refused_and_the_input_unchanged(
    recording: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    copy = tmp_path / "same.mcap"
    copy.write_bytes(recording.read_bytes())
    before = copy.read_bytes()
    for overwrite in ([], ["--overwrite"]):
        assert echoloop(["bag", "export", str(copy), "--json", str(copy), *overwrite]) == 1
        assert "is also an input" in capsys.readouterr().err
    assert copy.read_bytes() == before
    out = tmp_path / "out.mcap"
    out.write_bytes(b"keep me")
    with pytest.raises(OutputExistsError):
        recover(copy, out)
    assert out.read_bytes() == b"keep me"


def test_every_bit_of_a_chunks_opcode_and_length_loses_at_most_that_chunk_and_says_so(
        recording: Path, tmp_path: Path) -> None:
    """A flipped opcode can read as a footer (0x06 ^ 0x04 = 0x02) and a flipped length can run
    past the next chunks: neither may end the read early or hide the loss."""
    offset, _ = _chunk_offsets(recording)[5]
    broken = tmp_path / "h.mcap"
    for byte in range(offset, offset + 9):
        for bit in range(8):
            _flip(recording, broken, byte, bit)
            report = ScanReport(str(broken))
            kept = sum(1 for m in scan(broken, report) if hasattr(m, "sequence"))
            assert kept >= N - 100, (byte - offset, bit, report.describe())
            assert kept == N or report.damaged, (byte - offset, bit, report.describe())
