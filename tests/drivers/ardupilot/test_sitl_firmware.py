"""The SITL node runs the firmware itself when given a ``binary``
(:mod:`drivers.ardupilot.firmware`): the command SITL needs for the node's instance, a working
directory of the domain's, SIGINT to stop (SITL ignores SIGTERM once its JSON peer went quiet),
a firmware that quits fails the run, and none outlives a launcher killed with -9. The firmware
here is a stand-in script that behaves as ArduPlane does on those points."""

from __future__ import annotations

import json
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from drivers.ardupilot.sitl import ArduPilotSitl
from hil_bridge.bus.domain import Domain, use
from sim_core.config import ConfigError

ROOT = Path(__file__).resolve().parents[3]
PARM = ROOT / "launch" / "data" / "ardupilot" / "echoloop-sgs126.parm"

FAKE = """#!{python}
import json, os, pathlib, signal, sys, time
seen = pathlib.Path(os.environ["FAKE_SITL_SEEN"])
signal.signal(signal.SIGTERM, signal.SIG_IGN)  # as SITL, waiting for its JSON peer
pathlib.Path("eeprom.bin").write_bytes(b"\\0")
print("Waiting for connection ....", flush=True)
if os.environ.get("FAKE_SITL_EXIT"):
    print("bind failed on port 5760 - Address already in use", flush=True)
    sys.exit(3)
def stopped(*_):
    seen.with_suffix(".stopped").write_text("SIGINT")
    sys.exit(0)
signal.signal(signal.SIGINT, stopped)
seen.write_text(json.dumps({{"argv": sys.argv[1:], "cwd": os.getcwd(), "pid": os.getpid()}}))
while True:
    time.sleep(0.05)
"""


@pytest.fixture
def fake(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> Path:
    script = tmp_path / "arduplane"
    script.write_text(FAKE.format(python=sys.executable))
    script.chmod(0o755)
    monkeypatch.setenv("FAKE_SITL_SEEN", str(tmp_path / "seen.json"))
    return script


def _node(fake: Path, **params: object) -> ArduPilotSitl:
    return ArduPilotSitl("sitl", bus="mem://sitl_firmware", binary=str(fake), instances=[
        {"vehicle_id": 7, "firmware": {"home": [47.0, 8.0, 0.0, 90.0],
                                       "defaults": [str(PARM)]}}], **params)


def _wait_for(path: Path, timeout_s: float = 30.0) -> None:
    deadline = time.monotonic() + timeout_s
    while not path.exists():
        assert time.monotonic() < deadline, f"{path} never appeared"
        time.sleep(0.02)


def test_the_node_runs_its_firmware_for_its_instance_and_stops_it_with_sigint(
    fake: Path, domain: Domain,
) -> None:
    n = domain.number
    assert n is not None
    seen = fake.parent / "seen.json"
    with use(domain):
        node = _node(fake)
        node.start()
        try:
            _wait_for(seen)
            got = json.loads(seen.read_text())
            workdir = domain.path(f"sitl{n}")
            assert got["argv"] == ["--model", "JSON:127.0.0.1", "-I", str(n), "-w", "--home",
                                   "47,8,0,90", "--defaults", str(PARM)]
            assert Path(got["cwd"]) == workdir and (workdir / "eeprom.bin").exists()
            assert node.ports == {7: 9002 + 10 * n}  # where that instance sends
            assert node.failure() is None
            assert node.stats()["vehicles"]["7"]["firmware"]["pid"] == got["pid"]
        finally:
            node.stop()
    assert seen.with_suffix(".stopped").read_text() == "SIGINT"
    assert not workdir.exists()  # the domain's directory goes with the run
    node.stop()  # idempotent


def test_a_firmware_that_quits_fails_the_node_with_its_last_words(
    fake: Path, domain: Domain, monkeypatch: pytest.MonkeyPatch, tmp_path: Path,
) -> None:
    monkeypatch.setenv("FAKE_SITL_EXIT", "1")
    kept = tmp_path / "sitl-runs" / f"sitl{domain.number}"
    with use(domain):
        node = _node(fake, firmware_dir=str(kept.parent))
        node.start()
        try:
            deadline = time.monotonic() + 30
            while (why := node.failure()) is None:
                assert time.monotonic() < deadline, "the firmware's exit was never noticed"
                time.sleep(0.02)
        finally:
            node.stop()
    assert why.startswith("sitl.params.instances[0]: firmware arduplane (pid ")
    assert why.endswith("exited with code 3; its last output: Waiting for connection .... | "
                        "bind failed on port 5760 - Address already in use")
    assert (kept / "eeprom.bin").exists()  # a firmware_dir is the user's: kept, with the log
    assert "bind failed" in (kept / "firmware.log").read_text()


@pytest.mark.parametrize(("params", "said"), [
    ({"binary": "/nonexistent/arduplane"},
     "sitl.params.binary: '/nonexistent/arduplane' is no executable file"),
    ({"firmware": {"home": [47, 8, 0, 90], "defaults": ["nope.parm"]}},
     "sitl.params.instances[0].firmware.defaults: 'nope.parm': no such file"),
    ({"firmware": {}}, "sitl.params.instances[0].firmware.home: expected [lat, lon, alt, "
                       "heading]"),
    ({"port": 9100}, "sitl.params.instances[0].port: 9100 is not instance "),
])
def test_a_bad_firmware_setting_fails_at_construction_naming_the_key(
    fake: Path, domain: Domain, params: dict[str, object], said: str,
) -> None:
    instance: dict[str, object] = {"vehicle_id": 7, "firmware": {"home": [47, 8, 0, 90]}}
    instance.update({k: v for k, v in params.items() if k != "binary"})
    with use(domain), pytest.raises(ConfigError) as err:
        ArduPilotSitl("sitl", bus="mem://x", binary=str(params.get("binary", fake)),
                      instances=[instance])
    assert said in str(err.value)


def test_no_firmware_outlives_a_launcher_killed_with_sigkill(
    fake: Path, domain: Domain, tmp_path: Path,
) -> None:
    launch = tmp_path / "sitl.yaml"
    launch.write_text(
        "nodes:\n  - name: sitl\n    entry: drivers.ardupilot.sitl:ArduPilotSitl\n    params:\n"
        f"      binary: {fake}\n      instances:\n        - vehicle_id: 7\n"
        "          firmware: {home: [47.0, 8.0, 0.0, 90.0]}\n")
    seen = fake.parent / "seen.json"
    proc = subprocess.Popen(
        [sys.executable, "-m", "hil_bridge.cli", "launch", str(launch), "--domain",
         str(domain.number), "--duration", "60"], cwd=ROOT, stdout=subprocess.DEVNULL,
        stderr=subprocess.DEVNULL)
    try:
        _wait_for(seen, timeout_s=60)
        pid = json.loads(seen.read_text())["pid"]
    finally:
        proc.send_signal(signal.SIGKILL)
        proc.wait()
    workdir = domain.path(f"sitl{domain.number}")
    deadline = time.monotonic() + 10  # the host's parent-death signal, then the firmware's
    while _alive(pid) or workdir.exists():
        assert time.monotonic() < deadline, (
            f"the firmware (pid {pid}) or its directory outlived the launch")
        time.sleep(0.05)


def _alive(pid: int) -> bool:
    try:
        with open(f"/proc/{pid}/stat") as f:
            return f.read().split(")")[-1].split()[0] != "Z"
    except OSError:
        return False
