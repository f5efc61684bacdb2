"""Every command that reads a file, fed a corpus of bad files: each one ends in one line on
stderr naming the file and the problem (exit 1), never a traceback, never a silent success.

The table is meant to grow: a new reader is one :class:`Reader` row (the command, and the kind
of file it reads); a new kind of file is one :class:`Kind` (a valid example and, where they
make sense, its own huge-shape and NaN variants). Corruptions that a reader legitimately
survives (a corrupt MCAP chunk is skipped with a warning) are listed in ``Reader.survives``: the
command may then succeed, but must say on stderr, in lines naming the file, what it skipped.
"""

from __future__ import annotations

import io
import logging
import struct
import zipfile
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pytest
import yaml

from hil_bridge.bus.codec import encode
from hil_bridge.bus.messages import Clock
from hil_bridge.bus.transport import open_transport
from hil_bridge.cli import main as echoloop
from hil_bridge.recording.recorder import Recorder

DATA = Path(__file__).resolve().parents[2] / "data"

CORRUPTIONS = ("empty", "truncated", "wrong-type", "flipped-bit", "huge-shape", "nan-rows")


# -- valid examples of every kind of input file ---------------------------------------------------


def _npz(arrays: dict[str, np.ndarray]) -> bytes:
    buf = io.BytesIO()
    np.savez(buf, **arrays)  # type: ignore[arg-type]
    return buf.getvalue()


def _npz_with_huge(arrays: dict[str, np.ndarray], name: str) -> bytes:
    """An .npz whose ``name`` array declares 10^12 rows in its header but holds a few bytes."""
    buf = io.BytesIO()
    with zipfile.ZipFile(buf, "w") as zf:
        for key, arr in arrays.items():
            member = io.BytesIO()
            np.lib.format.write_array(member, arr)
            data = member.getvalue()
            if key == name:
                header = {"descr": arr.dtype.str, "fortran_order": False,
                          "shape": (10**12, *arr.shape[1:])}
                head = io.BytesIO()
                np.lib.format.write_array_header_1_0(head, header)  # type: ignore[arg-type]
                data = head.getvalue() + arr.tobytes()
            zf.writestr(f"{key}.npy", data)
    return buf.getvalue()


def _leaves(nan: bool = False) -> dict[str, np.ndarray]:
    rng = np.random.default_rng(0)
    centers = rng.uniform(-3, 3, (40, 3)) + np.array([0.0, 0.0, 5.0])
    normals = rng.normal(size=(40, 3))
    normals /= np.linalg.norm(normals, axis=1, keepdims=True)
    if nan:
        centers[7] = np.nan
    return {"centers": centers, "normals": normals, "radii": np.full(40, 0.05)}


def _trajectory(nan: bool = False) -> dict[str, np.ndarray]:
    t = np.linspace(0.0, 4.0, 5)
    cols = {"t": t, "x": 3.0 * t, "y": np.zeros(5), "z": np.full(5, 2.0),
            "heading": np.zeros(5), "bank": np.zeros(5), "airspeed": np.full(5, 3.0)}
    if nan:
        cols["x"][2] = np.nan
    return cols


def _csv(cols: dict[str, np.ndarray], header: bool = True) -> bytes:
    rows = np.stack(list(cols.values()), axis=1)
    lines = [",".join(cols)] if header else []
    lines += [",".join(repr(float(v)) for v in row) for row in rows]
    return ("\n".join(lines) + "\n").encode()


def _trace(nan: bool = False) -> dict[str, np.ndarray]:
    s, n = 6, 3
    t = np.arange(s) * 0.5
    if nan:
        t[3] = np.nan
    grid = np.tile(np.arange(n, dtype=float), (s, 1))
    return {"t": t, "x": grid, "y": grid, "z": grid + 100, "heading": grid * 0,
            "bank": grid * 0, "airspeed": grid * 0 + 10, "vz": grid * 0,
            "alive": np.ones((s, n), bool), "cohesion": grid * 0,
            "thermal_x": np.zeros(1), "thermal_y": np.zeros(1),
            "thermal_radius": np.full(1, 100.0), "thermal_strength": np.ones((s, 1))}


def _mcap(tmp: Path) -> bytes:
    path = tmp / "good.mcap"
    bus = f"mem://corpus{id(tmp)}"
    rec = Recorder(path, bus=bus, chunk_size=512, diagnostics_period_s=0)
    rec.start()
    try:
        with open_transport(bus) as raw:
            for i in range(200):
                raw.publish(encode("/clock", Clock(stamp_ns=i), seq=i, pub_ns=i, src="p"))
        assert rec.wait_for(200, 30)
    finally:
        rec.stop()
    data = path.read_bytes()
    path.unlink()
    return data


def _mcap_chunk_middle(data: bytes) -> int:
    """The middle of the recording's middle chunk (a flip there corrupts data, not an index)."""
    from mcap.reader import make_reader

    summary = make_reader(io.BytesIO(data)).get_summary()
    assert summary is not None
    chunk = summary.chunk_indexes[len(summary.chunk_indexes) // 2]
    return chunk.chunk_start_offset + chunk.chunk_length // 2


def _flight_log(suffix: str) -> Callable[[Path], bytes]:
    """A valid flight log written by issue 12's log makers (PX4 ULog, ArduPilot DataFlash,
    MAVLink tlog), as bytes."""
    def make(d: Path) -> bytes:
        from tests.hil_bridge.recording.logs.logmakers import (
            truth,
            write_dataflash,
            write_tlog,
            write_ulog,
        )

        t = np.arange(0.0, 20.0, 0.25)
        path = d / f"flight{suffix}"
        if suffix == ".ulg":
            write_ulog(path, truth(t), truth(t), local=True, glob=False)
        elif suffix == ".bin":
            write_dataflash(path, truth(t), truth(t))
        else:
            write_tlog(path, truth(t), truth(t))
        data = path.read_bytes()
        path.unlink()
        return data
    return make


def _dataflash_two_gps(d: Path) -> bytes:
    """A DataFlash log of two GPS receivers (ArduPilot 4.x records, interleaved), as bytes."""
    from tests.hil_bridge.recording.logs.logmakers import Flight, truth, write_dataflash_gps

    t = np.arange(0.0, 20.0, 0.2)
    first, late = truth(t), truth(t + 0.1)
    second = Flight(late.t, late.enu + 30.0, late.roll, late.pitch, late.yaw)
    path = d / "two_gps.bin"
    write_dataflash_gps(path, [first, second], truth(t), layout="4x")
    data = path.read_bytes()
    path.unlink()
    return data


def _yaml(data: object) -> bytes:
    return yaml.safe_dump(data).encode()


_LAUNCH = {"bus": "mem://corpus_launch", "nodes": [
    {"name": "server", "entry": "hil_bridge.server:SimServer", "params": {"scene": {}}}]}


@dataclass(frozen=True)
class Kind:
    """A kind of input file: a valid example, and its huge-shape / NaN variants (None: the
    corruption means nothing for this kind). Functions take a scratch directory."""

    suffix: str
    good: Callable[[Path], bytes]
    huge: Callable[[Path], bytes] | None = None
    nan: Callable[[Path], bytes] | None = None
    #: where to flip a bit (default: the middle); must make the file invalid, not merely other
    flip_at: Callable[[bytes], int] | None = None
    #: where to cut it (default: the middle, inside a line); a file cut at a line end is a
    #: shorter valid file for formats that list optional keys (a law file)
    cut_at: Callable[[bytes], int] | None = None


def _first(token: bytes) -> Callable[[bytes], int]:
    return lambda data: data.index(token)


KINDS: dict[str, Kind] = {
    "leaves-npz": Kind(".npz", lambda d: _npz(_leaves()),
                       lambda d: _npz_with_huge(_leaves(), "centers"),
                       lambda d: _npz(_leaves(nan=True))),
    "trace-npz": Kind(".npz", lambda d: _npz(_trace()), lambda d: _npz_with_huge(_trace(), "x"),
                      lambda d: _npz(_trace(nan=True))),
    "trajectory-csv": Kind(".csv", lambda d: _csv(_trajectory()), None,
                           lambda d: _csv(_trajectory(nan=True)), _first(b"heading")),
    "trajectory-npz": Kind(".npz", lambda d: _npz(_trajectory()),
                           lambda d: _npz_with_huge(_trajectory(), "x"),
                           lambda d: _npz(_trajectory(nan=True))),
    "waypoints-csv": Kind(".csv", lambda d: b"0,0\n30,0\n30,30\n0,30\n", None,
                          lambda d: b"0,0\nnan,0\n30,30\n", lambda data: 2),
    "table-csv": Kind(".csv", lambda d: b"survivingPercent,numAgents\n50,20\n60,40\n", None,
                      lambda d: b"survivingPercent,numAgents\nnan,20\n60,40\n",
                      _first(b"numAgents")),
    "law-yaml": Kind(".yaml", lambda d: (DATA / "seed002" / "law_40survivors.yaml").read_bytes(),
                     lambda d: b"numAgents: 1000000000000\n", lambda d: b"dt: .nan\n",
                     _first(b"totalTime"),
                     lambda data: data.index(b"\n", len(data) // 2) + 5),  # inside a key
    "grid-yaml": Kind(".yaml", lambda d: b"numAgents: [2, 3]\n",
                      lambda d: b"numAgents: [1000000000000]\n", lambda d: b"cohesion: [.nan]\n",
                      _first(b"numAgents")),
    "launch-yaml": Kind(".yaml", lambda d: _yaml(_LAUNCH),
                        lambda d: _yaml({**_LAUNCH, "nodes": [{**_LAUNCH["nodes"][0],  # type: ignore[dict-item]
                                         "params": {"scene": {"swarm": {"overrides": {
                                             "numAgents": 10**12}}}}}]}),
                        lambda d: _yaml({**_LAUNCH, "duration": float("nan")}),
                        _first(b"entry")),
    "scene-yaml": Kind(".yaml", lambda d: b"seed: 0\n", None, lambda d: b"seed: .nan\n",
                       _first(b"seed")),
    "forest-yaml": Kind(".yaml", lambda d: _yaml({"species": [
                            {"name": "maple", "tree": "maple", "positions": [[0, 0]]}]}),
                        lambda d: _yaml({"domain": [0, 0, 1e9, 1e9], "species": [
                            {"name": "maple", "tree": "maple", "rate": 1.0}]}),
                        lambda d: _yaml({"species": [
                            {"name": "maple", "tree": "maple", "positions": [[0, float("nan")]]}]}),
                        _first(b"species")),
    "mcap": Kind(".mcap", _mcap, lambda d: _mcap(d)[:8] + struct.pack("<BQ", 6, 1 << 60),
                 None, _mcap_chunk_middle),
    "ulog": Kind(".ulg", _flight_log(".ulg")),
    "dataflash": Kind(".bin", _flight_log(".bin")),
    "tlog": Kind(".tlog", _flight_log(".tlog")),
    # written by the real tools (README there): an ArduPilot QuadPlane's telemetry log, PX4's
    # CubeOrange ULog (its local position never valid: read from its GPS), a Plane DataFlash log
    "tlog-ardupilot": Kind(".tlog", lambda d: (
        DATA / "flightlogs" / "ardupilot_quadplane_sitl.tlog").read_bytes()),
    "ulog-px4": Kind(".ulg", lambda d: (
        DATA / "flightlogs" / "px4_cubeorange_vtol.ulg").read_bytes()),
    "dataflash-ardupilot": Kind(".bin", lambda d: (
        DATA / "flightlogs" / "ardupilot_plane_pixracer_short.bin").read_bytes()),
    "dataflash-two-gps": Kind(".bin", _dataflash_two_gps),
    "ros2-mapping-yaml": Kind(".yaml", lambda d: _yaml(_ros2_mapping()), None,
                              lambda d: _yaml([{**_ros2_mapping()[0],
                                                "max_rate_hz": float("nan")}]),
                              _first(b"ros_type")),
    "curve-key": Kind(".key_secret", lambda d: (_keys(d) / "server.key_secret").read_bytes(),
                      None, None, _first(b"curve")),
}


def _ros2_mapping() -> list[dict[str, object]]:
    import dataclasses

    from ros2_bridge.config import DEFAULT_MAPPING

    return [dataclasses.asdict(m) for m in DEFAULT_MAPPING]


def _keys(d: Path) -> Path:
    from hil_bridge.bus.security import generate_keys

    root = d / "keys"
    if not root.exists():
        generate_keys(root, ["sim"])
    return root


# -- the commands that read files -----------------------------------------------------------------


@dataclass(frozen=True)
class Reader:
    """A command reading one file of ``kind``: ``argv(file, scratch dir)``; corruptions it
    survives by design (it must then warn on stderr, naming the file)."""

    id: str
    kind: str
    argv: Callable[[Path, Path], list[str]]
    survives: frozenset[str] = frozenset()
    #: where the bad file must go (default: ``scratch/input<suffix>``)
    place: Callable[[Path], Path] | None = None
    #: a survived corruption is reported on stdout (a read report naming the file) instead of
    #: by warnings on stderr
    reports_on_stdout: bool = False


_MCAP_SURVIVES = frozenset({"truncated", "flipped-bit", "huge-shape"})

READERS: tuple[Reader, ...] = (
    # leaves that are not finite are dropped and counted by the synthesiser (said on stderr)
    Reader("echo-leaves", "leaves-npz", lambda f, d: [
        "echo", "--leaves", str(f), "--position", "0,0,5", "--boresight", "0,90",
        "--beamwidth", "40"], frozenset({"nan-rows"})),
    Reader("forest-scene", "forest-yaml", lambda f, d: [
        "forest", "generate", "--scene", str(f), "--out", str(d / "forest.npz")]),
    Reader("swarm-run-law", "law-yaml", lambda f, d: [
        "swarm", "run", "--law", str(f), "--set", "totalTime=1", "--json"]),
    Reader("swarm-sweep-grid", "grid-yaml", lambda f, d: [
        "swarm", "sweep", "--law", "default", "--set", "totalTime=1", "--grid", str(f),
        "--out", str(d / "table.csv"), "--no-progress"]),
    Reader("swarm-plot-trace", "trace-npz", lambda f, d: [
        "swarm", "plot", "--trace", str(f), "--out", str(d / "p.png")]),
    Reader("swarm-plot-table", "table-csv", lambda f, d: [
        "swarm", "plot", "--table", str(f), "--by", "numAgents", "--out", str(d / "p.png")]),
    Reader("launch", "launch-yaml", lambda f, d: ["launch", str(f), "--duration", "0.3"]),
    Reader("replay-csv", "trajectory-csv", lambda f, d: [
        "replay", str(f), "--fast", "--bus", "mem://corpus_replay", "--duration", "0.3",
        "--sonar", "0"]),
    Reader("replay-npz", "trajectory-npz", lambda f, d: [
        "replay", str(f), "--fast", "--bus", "mem://corpus_replay", "--duration", "0.3",
        "--sonar", "0"]),
    Reader("replay-scene", "scene-yaml", lambda f, d: [
        "replay", str(d / "ok.csv"), "--scene", str(f), "--fast", "--bus", "mem://corpus_rs",
        "--duration", "0.3", "--sonar", "0"]),
    # flight logs (issue 12): a log cut mid-record is read up to the cut, and its report says
    # what was read; ULog and DataFlash carry no checksum (a flipped bit is another value) and
    # MAVLink drops a message failing its CRC, so a flipped bit is read past, not refused
    *(Reader(f"replay-{kind}", kind, lambda f, d: [
        "replay", str(f), "--fast", "--bus", "mem://corpus_log", "--duration", "0.3",
        "--sonar", "0"], frozenset({"truncated", "flipped-bit"}), reports_on_stdout=True)
      for kind in ("ulog", "dataflash", "tlog", "tlog-ardupilot", "ulog-px4",
                   "dataflash-ardupilot")),
    # the second GPS receiver of a log with two, chosen by --topic
    Reader("replay-dataflash-gps1", "dataflash-two-gps", lambda f, d: [
        "replay", str(f), "--topic", "GPS[1]", "--fast", "--bus", "mem://corpus_log",
        "--duration", "0.3", "--sonar", "0"], frozenset({"truncated", "flipped-bit"}),
        reports_on_stdout=True),
    Reader("bag-info", "mcap", lambda f, d: ["bag", "info", str(f)], _MCAP_SURVIVES),
    Reader("bag-play", "mcap", lambda f, d: [
        "bag", "play", str(f), "--bus", "mem://corpus_play", "--rate", "0"], _MCAP_SURVIVES),
    Reader("bag-export", "mcap", lambda f, d: [
        "bag", "export", str(f), "--json", str(d / "j.mcap")], _MCAP_SURVIVES),
    Reader("bag-recover", "mcap", lambda f, d: [
        "bag", "recover", str(f), str(d / "r.mcap")], _MCAP_SURVIVES),
    Reader("topic-echo-replay", "mcap", lambda f, d: [
        "topic", "echo", "/clock", "--bus", f"replay://{f}?rate=0", "--duration", "0.5"],
        _MCAP_SURVIVES),
    Reader("mock-autopilot-waypoints", "waypoints-csv", lambda f, d: [
        "mock", "autopilot", "--channel", f"corpus{id(d)}", "--controller", "path",
        "--waypoints", str(f), "--duration", "0.2", "--every", "0"]),
    Reader("ros2-bridge-mapping", "ros2-mapping-yaml", lambda f, d: [
        "ros2", "bridge", "--mapping", str(f), "--duration", "0.2"]),
    Reader("bus-curve-keys", "curve-key", lambda f, d: [
        "bus", "--pub", "tcp://127.0.0.1:0", "--sub", "tcp://127.0.0.1:0",
        "--curve-keys", str(f.parent)], place=lambda d: _keys(d) / "server.key_secret"),
)


def _bad_bytes(kind: Kind, corruption: str, scratch: Path) -> bytes | None:
    if corruption == "empty":
        return b""
    if corruption == "huge-shape":
        return kind.huge(scratch) if kind.huge else None
    if corruption == "nan-rows":
        return kind.nan(scratch) if kind.nan else None
    if corruption == "wrong-type":  # a valid file of another kind
        other = "mcap" if kind.suffix != ".mcap" else "leaves-npz"
        return KINDS[other].good(scratch)
    good = kind.good(scratch)
    if corruption == "truncated":  # cut inside a line: a text file cut at a line end is
        cut = len(good) // 2        # indistinguishable from a shorter valid file
        if kind.cut_at is not None:
            cut = kind.cut_at(good)
        return good[: cut - 1 if good[cut - 1:cut] == b"\n" else cut]
    at = kind.flip_at(good) if kind.flip_at else len(good) // 2
    flipped = bytearray(good)
    flipped[at] ^= 0x80
    return bytes(flipped)


def _applies(reader: Reader, corruption: str) -> bool:
    """Whether ``corruption`` means something for the reader's kind of file (a YAML key file
    has no shape to make huge; a ULog's NaN rows are valid data)."""
    kind = KINDS[reader.kind]
    return {"huge-shape": kind.huge, "nan-rows": kind.nan}.get(corruption, True) is not None


CASES = [pytest.param(r, c, id=f"{r.id}-{c}")
         for r in READERS for c in CORRUPTIONS if _applies(r, c)]


@pytest.mark.parametrize(("reader", "corruption"), CASES)
def test_every_reader_reports_a_bad_file_in_one_line(
    reader: Reader, corruption: str, tmp_path: Path, capsys: pytest.CaptureFixture[str],
    caplog: pytest.LogCaptureFixture,
) -> None:
    kind = KINDS[reader.kind]
    data = _bad_bytes(kind, corruption, tmp_path)
    assert data is not None
    (tmp_path / "ok.csv").write_bytes(_csv(_trajectory()))
    path = reader.place(tmp_path) if reader.place else tmp_path / f"input{kind.suffix}"
    path.write_bytes(data)
    if path.suffix == ".key_secret":
        path.chmod(0o600)
    caplog.set_level(logging.WARNING)
    code = echoloop(reader.argv(path, tmp_path))
    captured = capsys.readouterr()
    err = captured.err
    # log records reach stderr as one line each in a real run (logging's last-resort handler);
    # a run's announcement ("echoloop replay: running ...") is not about the file
    lines = [line for line in err.strip().splitlines() if ": running " not in line]
    lines += [r.getMessage() for r in caplog.records]
    assert "Traceback" not in err, err
    if code == 0:
        assert corruption in reader.survives, f"accepted a bad file silently: {err!r}"
        if reader.reports_on_stdout:
            lines = [line for line in captured.out.splitlines() if str(path) in line]
        assert lines and all(str(path) in line for line in lines), err
    else:
        assert code == 1, (code, err)
        assert len(lines) == 1, err
        assert lines[0].startswith("echoloop ") and str(path) in lines[0], err


def test_the_table_covers_every_command_that_reads_files() -> None:
    from hil_bridge.cli import COMMANDS

    readers = {r.argv(Path("f"), Path("d"))[0] for r in READERS}
    assert readers == set(COMMANDS) - {"scenario", "run", "ardupilot", "mavlink",
                                        "dronecan"}  # no file read
