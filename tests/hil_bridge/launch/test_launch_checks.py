"""`echoloop launch --expect`, exit codes (a link that never connected: 3), `--duration` checks."""

from __future__ import annotations

import json
import math
from pathlib import Path
from typing import Any

import pytest
import yaml

from hil_bridge.cli import main as echoloop
from hil_bridge.launch.expect import Expectation, parse_expectations
from hil_bridge.launch.runner import EXIT_DISCONNECTED, EXIT_EXPECT, Failure, RunSummary, run

SERVER = {"name": "server", "entry": "hil_bridge.server:SimServer",
          "params": {"scene": {"swarm": {"overrides": {"numAgents": 2, "dt": 0.1}},
                               "state_rate_hz": 20, "clock": {"mode": "fast"}},
                     "stop_after_s": 2.0}}


def _write(tmp_path: Path, nodes: list[dict[str, Any]], name: str = "launch.yaml") -> str:
    path = tmp_path / name
    path.write_text(yaml.safe_dump({"nodes": nodes}), encoding="utf-8")
    return str(path)


@pytest.mark.parametrize(
    ("text", "parsed"),
    [
        ("server.stalls == 0", ("server", "stalls", "==", "0")),
        ("server.stalls==0", ("server", "stalls", "==", "0")),
        ("  head.echoes_complete>=10 ", ("head", "echoes_complete", ">=", "10")),
        ("server.ping_echo_ms.p99 < 2.5e2", ("server", "ping_echo_ms.p99", "<", "2.5e2")),
        ("autopilot.cmd_state:3 != 3", ("autopilot", "cmd_state:3", "!=", "3")),
        ("server.clock_mode == lockstep", ("server", "clock_mode", "==", "lockstep")),
        ("a.b<=-1", ("a", "b", "<=", "-1")), ("a.b>1", ("a", "b", ">", "1")),
    ],
    ids=["spaces", "no-spaces", "padded", "nested", "colon-key", "word", "le", "gt"],
)
def test_expectations_parse_with_or_without_spaces(text: str, parsed: tuple[str, ...]) -> None:
    e = Expectation.parse(text)
    assert (e.node, e.key, e.op, e.value) == parsed


@pytest.mark.parametrize("bad", ["server.stalls = 0", "stalls == 0", "server.stalls ==",
                                 "server.stalls > many", "server.stalls => 1", ""])
def test_bad_expectations_fail_with_the_expected_form(bad: str) -> None:
    with pytest.raises(ValueError, match=r"--expect"):
        Expectation.parse(bad)


def test_expectations_check_numbers_words_nan_and_missing_counters() -> None:
    nodes = {"server": {"stalls": 0, "ticks": 40, "mode": "lockstep", "ok": True,
                        "lat": {"p99": math.nan, "n": 3}}}

    def holds(text: str) -> bool:
        return Expectation.parse(text).check(nodes) is None

    assert holds("server.stalls == 0") and holds("server.ticks > 39") and holds("server.ticks<=40")
    assert not holds("server.ticks < 40") and not holds("server.stalls != 0")
    assert holds("server.mode == lockstep") and holds("server.mode != realtime")
    assert holds("server.ok == 1") and holds("server.ok == true")
    assert holds("server.lat.n >= 3") and not holds("server.lat.p99 < 100")
    assert holds("server.lat.p99 != 100")
    missing = Expectation.parse("server.nope > 0").check(nodes)
    assert missing is not None and "no counter 'nope'" in missing and "stalls" in missing
    assert "not a number" in str(Expectation.parse("server.lat > 1").check(nodes))
    with pytest.raises(ValueError, match=r"unknown node\(s\) \['sever'\]"):
        parse_expectations(["sever.ticks > 0"], nodes=["server"])


def test_exit_status_is_the_lowest_failure_code() -> None:
    summary = RunSummary(wall_s=1.0, stopped_by="duration", nodes={})
    assert summary.exit_status == 0
    summary.failures = [Failure(EXIT_EXPECT, "expect", "x"), Failure(EXIT_DISCONNECTED, "a", "y")]
    assert summary.exit_status == EXIT_DISCONNECTED
    assert summary.to_dict()["exit_status"] == EXIT_DISCONNECTED


def test_expect_true_exits_0_and_false_exits_4_naming_the_failed_check(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    path = _write(tmp_path, [SERVER])
    code = echoloop(["launch", path, "--duration", "3", "--expect", "server.physics_steps>=20",
                     "--expect", "server.stalls == 0", "--json"])
    captured = capsys.readouterr()
    assert code == 0, captured.err
    assert json.loads(captured.out)["failures"] == []
    code = echoloop(["launch", path, "--duration", "3", "--expect", "server.physics_steps>=20",
                     "--expect", "server.ticks < 5", "--expect", "server.nothing == 1"])
    err = capsys.readouterr().err.splitlines()
    assert code == EXIT_EXPECT
    failed = [line for line in err if "expectation" in line]
    assert len(failed) == 2
    assert "server.ticks < 5 failed: server.ticks = " in failed[0]
    assert "no counter 'nothing'" in failed[1]


def test_expect_on_an_unknown_node_fails_before_running(tmp_path: Path) -> None:
    with pytest.raises(ValueError, match=r"unknown node\(s\) \['sever'\]"):
        run(_write(tmp_path, [SERVER]), duration=1.0, expect=["sever.ticks > 0"],
            handle_signals=False)


def test_a_serial_port_that_never_opens_exits_3(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    adapter = {"name": "sonar_head", "entry": "drivers.serial.adapter:SonarHeadAdapter",
               "params": {"port": str(tmp_path / "ttyNOPE"), "ping_rate_hz": 1,
                          "encoding": "iq16"}}
    path = _write(tmp_path, [SERVER, adapter])
    code = echoloop(["launch", path, "--duration", "1"])
    out, err = capsys.readouterr()
    assert code == EXIT_DISCONNECTED
    lines = [line for line in err.splitlines() if "never connected" in line]
    assert len(lines) == 1
    assert f"sonar_head.serial: serial link {tmp_path / 'ttyNOPE'} never connected" in lines[0]
    assert f"link sonar_head.serial: serial {tmp_path / 'ttyNOPE'}: NEVER CONNECTED" in out
    assert echoloop(["launch", path, "--duration", "1", "--allow-disconnected"]) == 0
    assert "NEVER CONNECTED" in capsys.readouterr().out


def test_a_can_bus_that_never_opens_exits_3(tmp_path: Path) -> None:
    adapter = {"name": "autopilot", "entry": "drivers.can.adapter:AutopilotAdapter",
               "params": {"interface": "socketcan", "channel": "echoloopnope0", "gliders": [0]}}
    summary = run(_write(tmp_path, [SERVER, adapter]), duration=1.0, handle_signals=False)
    assert summary.exit_status == EXIT_DISCONNECTED
    assert summary.links["autopilot.can"]["connected"] is False
    assert [f.source for f in summary.failures] == ["autopilot.can"]


def test_links_that_connected_are_shown_and_pass(tmp_path: Path) -> None:
    nodes = [SERVER, {"name": "autopilot", "entry": "drivers.can.adapter:AutopilotAdapter",
                      "params": {"gliders": [0]}}]
    summary = run(_write(tmp_path, nodes), duration=0.5, handle_signals=False)
    link = summary.links["autopilot.can"]
    assert link["connected"] is True and link["state"] == "up"
    assert summary.exit_status == 0


@pytest.mark.parametrize("bad", ["nan", "0", "-1", "inf", "soon"])
def test_duration_rejects_nan_zero_negative(
    bad: str, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    with pytest.raises(SystemExit) as exc:
        echoloop(["launch", _write(tmp_path, [SERVER]), "--duration", bad])
    assert exc.value.code == 2
    assert "argument --duration: expected a finite number of seconds > 0" in (
        capsys.readouterr().err)
    with pytest.raises(ValueError, match="duration"):
        run(_write(tmp_path, [SERVER]), duration=float(bad) if bad != "soon" else math.nan,
            handle_signals=False)
