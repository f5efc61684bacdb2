"""Every command that writes a file refuses an existing one unless ``--overwrite`` (before doing
any work, leaving it untouched), and writes through a temporary file renamed at the end.

One row per output option; issue 12's new exports add rows here."""

from __future__ import annotations

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


def _leaves(d: Path) -> Path:
    path = d / "leaves.npz"
    rng = np.random.default_rng(1)
    normals = rng.normal(size=(30, 3))
    np.savez(path, centers=rng.uniform(-2, 2, (30, 3)) + np.array([0.0, 0.0, 5.0]),
             normals=normals / np.linalg.norm(normals, axis=1, keepdims=True),
             radii=np.full(30, 0.05))
    return path


def _bag(d: Path) -> Path:
    path = d / "in.mcap"
    bus = f"mem://outputs{id(d)}"
    rec = Recorder(path, bus=bus, diagnostics_period_s=0)
    rec.start()
    try:
        with open_transport(bus) as raw:
            for i in range(10):
                raw.publish(encode("/clock", Clock(stamp_ns=i), seq=i, pub_ns=i, src="p"))
        assert rec.wait_for(10, 30)
    finally:
        rec.stop()
    return path


def _launch(d: Path) -> Path:
    path = d / "l.yaml"
    scene = {"swarm": {"overrides": {"numAgents": 2, "dt": 0.1}}, "state_rate_hz": 20}
    path.write_text(yaml.safe_dump({"bus": f"mem://outputs_launch{id(d)}", "nodes": [
        {"name": "server", "entry": "hil_bridge.server:SimServer", "params": {"scene": scene}}]}),
        encoding="utf-8")
    return path


@dataclass(frozen=True)
class Writer:
    """A command writing ``out`` (``argv(out, scratch)``); ``name`` is the output's file name."""

    id: str
    name: str
    argv: Callable[[Path, Path], list[str]]


WRITERS: tuple[Writer, ...] = (
    Writer("echo-out", "e.npz", lambda o, d: [
        "echo", "--leaves", str(_leaves(d)), "--position", "0,0,5", "--boresight", "0,90",
        "--beamwidth", "40", "--out", str(o)]),
    Writer("echo-plot", "e.png", lambda o, d: [
        "echo", "--leaves", str(_leaves(d)), "--position", "0,0,5", "--boresight", "0,90",
        "--beamwidth", "40", "--plot", str(o)]),
    Writer("forest-out", "f.npz", lambda o, d: [
        "forest", "generate", "--preset", "seed000-fig5d", "--out", str(o)]),
    Writer("swarm-run-trace", "t.npz", lambda o, d: [
        "swarm", "run", "--law", "default", "--set", "totalTime=1", "--set", "numAgents=2",
        "--trace", str(o)]),
    Writer("swarm-plot", "p.png", lambda o, d: [
        "swarm", "plot", "--table", str(_table(d)), "--by", "numAgents", "--out", str(o)]),
    Writer("scenario", "fig6.png", lambda o, d: ["scenario", "fig6", "--out", str(o.parent)]),
    Writer("launch-record", "r.mcap", lambda o, d: [
        "launch", str(_launch(d)), "--duration", "0.2", "--record", str(o)]),
    Writer("launch-plot", "r.png", lambda o, d: [
        "launch", str(_launch(d)), "--duration", "0.5", "--record", str(d / "x.mcap"),
        "--plot", str(o)]),
    Writer("bag-record", "b.mcap", lambda o, d: [
        "bag", "record", str(o), "--bus", "mem://outputs_rec", "--duration", "0.2"]),
    Writer("bag-export", "j.mcap", lambda o, d: [
        "bag", "export", str(_bag(d)), "--json", str(o)]),
    Writer("bag-recover", "rec.mcap", lambda o, d: ["bag", "recover", str(_bag(d)), str(o)]),
    Writer("bus-keygen", "server.key", lambda o, d: ["bus", "--keygen", str(o.parent)]),
    Writer("mock-can-log", "can.log", lambda o, d: [
        "mock", "autopilot", "--channel", f"outputs{id(d)}", "--can-log", str(o),
        "--duration", "0.1", "--every", "0"]),
)


def _table(d: Path) -> Path:
    path = d / "table.csv"
    path.write_text("survivingPercent,numAgents\n50,20\n60,40\n", encoding="utf-8")
    return path


@pytest.mark.parametrize("writer", WRITERS, ids=[w.id for w in WRITERS])
def test_an_existing_output_is_refused_unless_overwrite(
    writer: Writer, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    out = tmp_path / "outputs" / writer.name
    out.parent.mkdir()
    out.write_bytes(b"precious")
    argv = writer.argv(out, tmp_path)
    assert echoloop(argv) == 1
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and f"{out}: exists; pass --overwrite" in err[0], err
    assert out.read_bytes() == b"precious"
    assert not [p for p in out.parent.iterdir() if ".part" in p.name]
    assert echoloop([*argv, "--overwrite"]) == 0, capsys.readouterr().err
    assert out.read_bytes() != b"precious"
    assert not [p for p in out.parent.iterdir() if ".part" in p.name]


def test_serial_capture_is_refused_at_load_unless_overwrite(tmp_path: Path) -> None:
    from drivers.serial.adapter import SonarHeadAdapter
    from hil_bridge.errors import OutputExistsError

    prefix = tmp_path / "head"
    (tmp_path / "head.tx.bin").write_bytes(b"precious")
    with pytest.raises(OutputExistsError, match=r"head\.tx\.bin: exists"):
        SonarHeadAdapter("sonar_head", bus="mem://capture", port="loop://",
                         capture=str(prefix))
    assert (tmp_path / "head.tx.bin").read_bytes() == b"precious"
    adapter = SonarHeadAdapter("sonar_head", bus="mem://capture", port="loop://",
                               capture=str(prefix), overwrite=True)
    adapter.start()
    adapter.stop()
    assert (tmp_path / "head.tx.bin").read_bytes() != b"precious"
    assert sorted(p.name for p in tmp_path.iterdir()) == [
        "head.index.tsv", "head.rx.bin", "head.tx.bin"]
