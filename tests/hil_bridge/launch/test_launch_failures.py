"""Every failure a run sees ends in its exit status, naming the node and the place.

A callback, a timer, a driver or mock loop, the echo service and its workers, a constructor
or start() that raises: the run ends (``stopped_by == "failure"``) with exit 1 and one failure
naming the node. A fault a node declares recoverable fails the run only if it never recovers.
A ``--plot`` that fails after the run is reported without hiding the run's own status.
Every run is in a private domain (the CLI ones in the first free domain) and bounded by a
long duration it is not expected to reach; no wall-clock time is asserted.
"""

from __future__ import annotations

import multiprocessing
import os
import signal
import threading
from pathlib import Path
from typing import Any

import pytest
import yaml

from hil_bridge.bus.domain import Domain
from hil_bridge.cli import main as echoloop
from hil_bridge.launch.runner import (
    EXIT_AFTER_RUN,
    EXIT_EXPECT,
    EXIT_FAILED,
    LaunchSpec,
    RunSummary,
    run,
)
from hil_bridge.server.echo_pool import WORKER_NAME

FAULTY = "tests.hil_bridge.launch.faulty_nodes"
#: an upper bound on each run; a run that reaches it did not see the failure it should
BOUND_S = 120.0

SERVER: dict[str, Any] = {
    "name": "server", "entry": "hil_bridge.server:SimServer",
    "params": {"scene": {"swarm": {"overrides": {"numAgents": 2, "dt": 0.1}},
                         "state_rate_hz": 20}},
}
SONAR_SCENE: dict[str, Any] = {
    "forest": {"preset": "seed000-fig5d", "tile_size_m": 10.0, "query_radius_m": 4.0},
    "sonars": [{"id": 0, "mount": 1, "fidelity": "fast", "echo": {"samples": 8000}}],
    "vehicles": [{"id": 1, "path": {"kind": "points", "points": [[2, 5, 2], [18, 5, 2]]}}],
}


def _faulty(mode: str, name: str = "faulty", **params: Any) -> dict[str, Any]:
    return {"name": name, "entry": f"{FAULTY}:Faulty", "params": {"mode": mode, **params}}


def _run(tmp_path: Path, nodes: list[dict[str, Any]], **kw: Any) -> RunSummary:
    launch = {"allow_modules": [FAULTY], "nodes": nodes}
    domain = Domain.private(tmp_path / "domain")
    return run(launch, duration=kw.pop("duration", BOUND_S), domain=domain,
               bus=domain.bus_url, handle_signals=False, **kw)


def _failed(summary: RunSummary, source: str) -> str:
    """The one failure of the run, from ``source``; its message."""
    assert summary.exit_status == EXIT_FAILED, summary.failures
    assert [f.source for f in summary.failures] == [source], summary.failures
    return summary.failures[0].message


@pytest.mark.parametrize(
    ("mode", "place"),
    [("callback", "faulty failed: callback /clock: ValueError: cannot handle clock"),
     ("timer", "faulty failed: timer Faulty._tick: ZeroDivisionError: timer bug")],
    ids=["callback", "timer"],
)
def test_a_callback_or_timer_that_raises_ends_the_run_naming_the_node(
    tmp_path: Path, mode: str, place: str
) -> None:
    summary = _run(tmp_path, [SERVER, _faulty(mode)])
    assert summary.stopped_by == "failure"
    assert _failed(summary, "faulty").startswith(place)
    assert summary.nodes["faulty"]["callback_errors"] >= 1
    assert summary.nodes["server"]["tick_error"] == ""  # the others were stopped cleanly


def test_a_node_whose_constructor_raises_fails_the_run_and_the_built_ones_stop(
    tmp_path: Path,
) -> None:
    summary = _run(tmp_path, [SERVER, _faulty("constructor"), _faulty("callback", "never")])
    assert summary.stopped_by == "failure"
    assert _failed(summary, "faulty") == (
        "faulty failed: constructor raised RuntimeError: wiring bug in the constructor")
    assert list(summary.nodes) == ["server"]  # the node after it was never built
    assert summary.nodes["server"]["ticks"] == 0  # built, stopped, never started


def test_a_node_whose_start_raises_fails_the_run(tmp_path: Path) -> None:
    summary = _run(tmp_path, [SERVER, _faulty("start")])
    assert summary.stopped_by == "failure"
    assert _failed(summary, "faulty") == "faulty failed: start() raised OSError: device busy"
    assert summary.nodes["server"]["tick_error"] == ""


def test_a_recoverable_fault_that_recovers_leaves_exit_0(tmp_path: Path) -> None:
    done = threading.Event()
    summary = _run(tmp_path, [SERVER, _faulty("recovers", done=done)], stop_event=done)
    assert summary.stopped_by == "stop_event"
    assert summary.failures == [] and summary.exit_status == 0
    assert summary.nodes["faulty"]["faults"] == 1  # it happened, and it is counted


def test_a_recoverable_fault_that_never_recovers_fails_at_the_end(tmp_path: Path) -> None:
    summary = _run(tmp_path, [SERVER, _faulty("never_recovers")], duration=0.5)
    assert summary.stopped_by == "duration"  # never a reason to end the run early
    assert _failed(summary, "faulty") == (
        "faulty failed: link: port vanished (declared recoverable, never recovered)")


def test_a_failure_without_the_final_parameter_is_still_asked(tmp_path: Path) -> None:
    old = {"name": "old", "entry": f"{FAULTY}:OldStyle", "params": {"asked_before_failing": 3}}
    summary = _run(tmp_path, [old])
    assert summary.stopped_by == "failure"  # asked while the run went, as the others
    assert _failed(summary, "old") == "old failed: legacy reason"
    assert summary.nodes["old"]["asked"] == 4


def test_a_tick_loop_that_dies_ends_the_run(tmp_path: Path,
                                            monkeypatch: pytest.MonkeyPatch) -> None:
    from hil_bridge.server.fleet import Fleet

    def broken(self: Fleet, *args: Any) -> None:
        raise FloatingPointError("integrator diverged")

    monkeypatch.setattr(Fleet, "advance", broken)
    summary = _run(tmp_path, [SERVER])
    assert summary.stopped_by == "failure"
    assert _failed(summary, "server") == (
        "server failed: tick loop: FloatingPointError: integrator diverged")


def test_a_can_adapter_loop_error_fails_the_adapter(tmp_path: Path,
                                                   monkeypatch: pytest.MonkeyPatch) -> None:
    from drivers.can.adapter import AutopilotAdapter

    def broken(self: AutopilotAdapter, now: float) -> None:
        raise KeyError("glider 7")

    monkeypatch.setattr(AutopilotAdapter, "_supervise", broken)
    adapter = {"name": "autopilot", "entry": "drivers.can.adapter:AutopilotAdapter",
               "params": {"gliders": [0]}}
    summary = _run(tmp_path, [SERVER, adapter])
    assert summary.stopped_by == "failure"
    assert _failed(summary, "autopilot") == (
        "autopilot failed: CAN transmit cycle: KeyError: 'glider 7'")
    assert summary.nodes["autopilot"]["loop_errors"] >= 1


def test_a_mock_autopilot_error_fails_the_mock(tmp_path: Path,
                                              monkeypatch: pytest.MonkeyPatch) -> None:
    from drivers.mocks.autopilot import MockAutopilot

    def broken(self: MockAutopilot, now: float) -> None:
        raise ArithmeticError("controller diverged")

    monkeypatch.setattr(MockAutopilot, "_control", broken)
    mock = {"name": "mock_autopilot", "entry": "drivers.mocks.autopilot:MockAutopilot",
            "params": {"gliders": [0]}}
    summary = _run(tmp_path, [SERVER, mock])
    assert summary.stopped_by == "failure"
    assert _failed(summary, "mock_autopilot") == (
        "mock_autopilot failed: control cycle: ArithmeticError: controller diverged")


SONAR_PAIR = [
    {"name": "sonar_head_mock", "entry": "drivers.mocks.sonar_head:MockSonarHead",
     "params": {"pty": True}},
    {"name": "sonar_head", "entry": "drivers.serial.adapter:SonarHeadAdapter",
     "params": {"ping_rate_hz": 10}},
]


def test_a_sonar_head_mock_loop_error_fails_the_mock(tmp_path: Path,
                                                    monkeypatch: pytest.MonkeyPatch) -> None:
    from drivers.mocks.sonar_head import MockSonarHead

    def broken(self: MockSonarHead, now: float) -> None:
        raise RuntimeError("ping table corrupt")

    monkeypatch.setattr(MockSonarHead, "_expire", broken)  # its transmit loop, at once
    summary = _run(tmp_path, [SERVER, *SONAR_PAIR])
    assert summary.stopped_by == "failure"
    assert _failed(summary, "sonar_head_mock") == (
        "sonar_head_mock failed: tx loop: RuntimeError: ping table corrupt")


def test_a_sonar_head_adapter_device_loop_error_fails_the_adapter(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    from drivers.serial.adapter import SonarHeadAdapter

    def broken(self: SonarHeadAdapter, ping: Any, frame: Any) -> None:
        raise RuntimeError("ping handler bug")

    monkeypatch.setattr(SonarHeadAdapter, "_on_ping", broken)  # on the link's reader thread
    summary = _run(tmp_path, [SERVER, *SONAR_PAIR])
    assert summary.stopped_by == "failure"
    assert _failed(summary, "sonar_head") == (
        "sonar_head failed: link callback _on_bytes: RuntimeError: ping handler bug")


def test_an_echo_service_thread_that_dies_fails_the_server(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    from hil_bridge.server.echo_service import EchoService

    def broken(self: EchoService, workers: Any) -> None:
        raise RuntimeError("scheduler bug")

    monkeypatch.setattr(EchoService, "_serve", broken)
    server = {**SERVER, "params": {"scene": SONAR_SCENE}}
    summary = _run(tmp_path, [server])
    assert summary.stopped_by == "failure"
    assert _failed(summary, "server") == "server failed: echo service: RuntimeError: scheduler bug"


def test_an_echo_worker_process_killed_fails_the_server(tmp_path: Path) -> None:
    killed: list[int] = []

    def kill_the_worker(_spec: LaunchSpec) -> None:
        # the server's start() returned once its worker was up
        workers = [p for p in multiprocessing.active_children() if p.name == WORKER_NAME]
        assert len(workers) == 1
        killed.append(workers[0].pid or 0)
        os.kill(killed[0], signal.SIGKILL)

    server = {**SERVER, "params": {"scene": SONAR_SCENE, "echo_worker": "pool",
                                   "echo_workers": 1}}
    summary = _run(tmp_path, [server], on_started=kill_the_worker)
    assert summary.stopped_by == "failure"
    assert _failed(summary, "server") == (
        f"server failed: echo worker {killed[0]}: exited (code -{int(signal.SIGKILL)})")


def _launch_file(tmp_path: Path) -> str:
    path = tmp_path / "launch.yaml"
    path.write_text(yaml.safe_dump({"bus": f"mem://plot_fails{id(tmp_path)}", "nodes": [
        {**SERVER, "params": {**SERVER["params"], "stop_after_s": 1.0}}]}), encoding="utf-8")
    return str(path)


@pytest.mark.parametrize(("expect", "status"), [("server.ticks >= 1", EXIT_AFTER_RUN),
                                                 ("server.ticks < 0", EXIT_EXPECT)],
                         ids=["good-run", "failed-expectation"])
def test_a_plot_that_fails_after_the_run_never_replaces_its_status(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str],
    expect: str, status: int,
) -> None:
    def broken(mcap: Any, png: Any) -> None:
        raise RuntimeError("no display backend")

    monkeypatch.setattr("hil_bridge.cli.launch.plot_recording", broken)
    png = tmp_path / "run.png"
    code = echoloop(["launch", _launch_file(tmp_path), "--duration", "1.0", "--domain", "auto",
                     "--record", str(tmp_path / "run.mcap"), "--plot", str(png),
                     "--expect", expect])
    err = capsys.readouterr().err
    assert code == status, err
    assert "echoloop launch: plot failed after the run: RuntimeError: no display backend" in err
    assert not png.exists()
