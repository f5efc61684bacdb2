"""The echoloop pytest plugin, used as a user would: from test files outside this repository.

The example of docs/testing.md (my_pilot.py, loop.yaml, test_my_pilot.py) is extracted from the
document and run with pytest in a fresh directory, so the page cannot drift from what works.
The fixture's failure modes and its privacy (two runs at once in one process) are checked there
and here.
"""

from __future__ import annotations

import os
import re
import subprocess
import sys
import threading
from pathlib import Path
from typing import Any

import pytest

from hil_bridge.launch.pytest_plugin import RunFailed, node_overrides
from hil_bridge.launch.runner import EXIT_EXPECT

ROOT = Path(__file__).resolve().parents[1]
_BLOCK = re.compile(r"```(?:python|yaml)\n# (?P<name>[\w.]+)\n(?P<body>.*?)```", re.S)

FAILURES = '''
import pytest

from hil_bridge.launch.pytest_plugin import RunFailed

SERVER = {"name": "server", "entry": "hil_bridge.server:SimServer",
          "params": {"scene": {"swarm": {"overrides": {"numAgents": 2, "dt": 0.1}},
                               "clock": {"mode": "fast"}}, "stop_after_s": 1.0}}


def test_a_failed_expectation_raises_naming_it(echoloop_launch):
    with pytest.raises(RunFailed, match=r"expectation server.ticks < 1 failed") as exc:
        echoloop_launch({"nodes": [SERVER]}, duration=0.5, expect=["server.ticks < 1"])
    assert exc.value.summary.exit_status == 4


def test_a_node_that_fails_to_construct_fails_the_run_naming_it(echoloop_launch):
    bad = {"name": "sonar_head", "entry": "drivers.serial.adapter:SonarHeadAdapter",
           "params": {"port": "nope://x"}}
    with pytest.raises(RunFailed, match="sonar_head failed: constructor raised ValueError: "
                                        "serial URL scheme 'nope' unknown") as exc:
        echoloop_launch({"nodes": [SERVER, bad]}, duration=0.5)
    assert exc.value.summary.exit_status == 1
    assert exc.value.summary.stopped_by == "failure"


def test_a_node_that_refuses_its_params_raises_the_config_error(echoloop_launch):
    bad = {"name": "sonar_head", "entry": "drivers.serial.adapter:SonarHeadAdapter",
           "params": {"colour": "red"}}
    with pytest.raises(ValueError, match="colour"):
        echoloop_launch({"nodes": [SERVER, bad]}, duration=0.5)


def test_params_reach_the_nodes(echoloop_launch):
    summary = echoloop_launch({"nodes": [SERVER]}, duration=0.5,
                              params={"server.scene.swarm.overrides.numAgents": 3})
    assert summary.nodes["server"]["gliders_alive"] == 3
'''


def _docs_example() -> dict[str, str]:
    text = (ROOT / "docs" / "testing.md").read_text(encoding="utf-8")
    files = {m["name"]: f"# {m['name']}\n{m['body']}" for m in _BLOCK.finditer(text)}
    assert set(files) == {"my_pilot.py", "loop.yaml", "test_my_pilot.py"}
    return files


def test_the_fixture_works_from_a_test_file_outside_the_repository(tmp_path: Path) -> None:
    user = tmp_path / "user_project" / "tests"
    user.mkdir(parents=True)
    for name, body in _docs_example().items():
        (user / name).write_text(body, encoding="utf-8")
    (user / "test_failures.py").write_text(FAILURES, encoding="utf-8")
    env = {k: v for k, v in os.environ.items() if k not in ("PYTHONPATH", "ECHOLOOP_DOMAIN")}
    proc = subprocess.run(
        [sys.executable, "-m", "pytest", "-q", "-p", "no:cacheprovider", str(user)],
        cwd=tmp_path / "user_project", env=env, capture_output=True, text=True, timeout=300,
    )
    assert proc.returncode == 0, proc.stdout[-3000:] + proc.stderr[-2000:]
    assert "5 passed" in proc.stdout


def test_node_overrides_forms() -> None:
    assert node_overrides({"server.scene.seed": 3, "pilot": {"radius_m": 2.0}}) == {
        "server": {"scene.seed": 3}, "pilot": {"radius_m": 2.0}}
    with pytest.raises(ValueError, match=r"expected 'NODE\.KEY'"):
        node_overrides({"server": 3})


def test_two_runs_at_once_in_one_process_share_nothing(echoloop_launch: Any) -> None:
    """Two demos in two threads: each gets its own bus, CAN channel and pty link."""
    results: dict[int, Any] = {}

    def one(k: int) -> None:
        try:
            results[k] = echoloop_launch(ROOT / "launch" / "demo.yaml", duration=3.0)
        except Exception as exc:  # reported below, with the other run's outcome
            results[k] = exc

    threads = [threading.Thread(target=one, args=(k,)) for k in range(2)]
    for t in threads:
        t.start()
    for t in threads:
        t.join(120)
    assert all(not isinstance(r, Exception) for r in results.values()), results
    a, b = results[0], results[1]
    assert a.bus != b.bus and a.bus.startswith("mem://")
    assert a.links["autopilot.can"]["target"] != b.links["autopilot.can"]["target"]
    assert a.links["sonar_head.serial"]["target"] != b.links["sonar_head.serial"]["target"]
    for summary in (a, b):
        server, adapter = summary.nodes["server"], summary.nodes["sonar_head"]
        head = summary.nodes["sonar_head_mock"]
        assert adapter["pings_in"] - 1 <= server["pings_received"] <= adapter["pings_in"]
        # every echo the head took answered one of its own pings and came from its own server
        # (how many fit in 3 wall seconds depends on the machine's load, so it is not asserted)
        assert head.get("echoes_unsolicited", 0) == 0
        assert head["echoes_complete"] + head["echoes_incomplete"] <= server["echoes_published"]
        assert head["pings_sent"] == (head["echoes_complete"] + head["echoes_incomplete"]
                                      + head["echo_timeouts"] + head["pings_in_flight"])


def test_run_failed_carries_the_summary(echoloop_launch: Any) -> None:
    server = {"name": "server", "entry": "hil_bridge.server:SimServer",
              "params": {"scene": {"clock": {"mode": "fast"}}, "stop_after_s": 0.5}}
    with pytest.raises(RunFailed) as exc:
        echoloop_launch({"nodes": [server]}, duration=0.3, expect=["server.ticks == -1"])
    assert exc.value.summary.exit_status == EXIT_EXPECT
    assert isinstance(exc.value, AssertionError)
