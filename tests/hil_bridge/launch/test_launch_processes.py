"""Nodes as processes (hil_bridge.launch.process, hil_bridge.launch.host): a node whose process
dies in any way ends the run with exit 1 naming it and its last log lines; containers share a
process; --only/--skip; echoloop run joins another launch's bus; a killed launcher leaves
nothing behind."""

from __future__ import annotations

import contextlib
import json
import os
import shutil
import signal
import socket
import subprocess
import sys
import threading
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest

from hil_bridge.bus.domain import Domain, claim_first_free, use
from hil_bridge.launch.runner import EXIT_FAILED, run
from hil_bridge.priority import can_realtime, realtime_priority
from hil_bridge.server.shared_tiles import stores_of
from sim_core.config import ConfigError
from tests.hil_bridge.server._killed import alive

pytestmark = pytest.mark.processes

ROOT = Path(__file__).resolve().parents[3]
CRASH = "tests.hil_bridge.launch.crashnodes:Crasher"
ALLOW = ["tests.hil_bridge.launch.crashnodes"]


@pytest.fixture
def domain() -> Iterator[Domain]:
    """A free numbered domain, claimed for the test (its bus crosses processes)."""
    with claim_first_free(Domain(int.from_bytes(os.urandom(1)) % 60 + 20)) as (dom, _), \
            use(dom):
        yield dom


def _launch(*nodes: dict[str, Any]) -> dict[str, Any]:
    return {"allow_modules": ALLOW, "nodes": list(nodes)}


def _crasher(name: str, how: str, **extra: Any) -> dict[str, Any]:
    return {"name": name, "entry": CRASH, "params": {"how": how}, **extra}


@pytest.mark.parametrize(("how", "why"), [
    ("abort", "killed by SIGABRT"),
    ("sigkill", "killed by SIGKILL"),
    ("exit", "exit code 3"),
])
def test_a_node_process_that_dies_ends_the_run_naming_it(domain: Domain, how: str,
                                                         why: str) -> None:
    summary = run(_launch(_crasher("calm", "none"), _crasher("doomed", how)),
                  duration=120.0, handle_signals=False, domain=domain)
    assert summary.mode == "processes"
    assert summary.stopped_by == "failure"
    assert summary.exit_status == EXIT_FAILED
    [failure] = summary.failures
    assert failure.source == "doomed"
    assert why in failure.message
    assert f"doomed: about to die by {how}" in failure.message  # its last log lines
    assert summary.nodes["calm"]["pid"] != os.getpid()


def test_a_node_process_freezes_its_heap_once_built_and_again_once_started(
    domain: Domain,
) -> None:
    """hil_bridge.lifetime.freeze_heap: a full collection in a running node's process walks what
    the run keeps, not the modules, scene and nodes it was built with."""
    node = {"name": "heap", "entry": "tests.hil_bridge.launch.heapnodes:HeapReporter",
            "params": {}}
    summary = run({"allow_modules": ["tests.hil_bridge.launch.heapnodes"], "nodes": [node]},
                  duration=0.5, handle_signals=False, domain=domain)
    assert summary.exit_status == 0, summary.failures
    stats = summary.nodes["heap"]
    assert stats["frozen_when_built"] == 0  # a fresh interpreter: frozen after construction
    assert stats["frozen_when_started"] > 10_000  # the imports, the node
    assert not stats["walks_start_objects"]  # frozen again once started
    assert stats["walks_run_objects"]  # what the run keeps is collected as ever
    # the run's 1,000 survivors and little else: without the freeze, every frozen object too
    assert 1000 <= stats["full_collection_walks"] < stats["frozen_when_started"] / 5


def test_a_node_that_fails_to_start_is_named(domain: Domain) -> None:
    summary = run(_launch(_crasher("calm", "none"), _crasher("doomed", "raise")),
                  duration=30.0, handle_signals=False, domain=domain)
    assert summary.exit_status == EXIT_FAILED
    assert summary.stopped_by == "failure"
    [failure] = summary.failures
    assert failure.source == "doomed"
    assert "doomed: start() raised RuntimeError: doomed refuses to start" in failure.message


def test_nodes_of_one_container_share_a_process(domain: Domain) -> None:
    summary = run(_launch(_crasher("a", "none", container="pair"),
                          _crasher("b", "none", container="pair"), _crasher("c", "none")),
                  duration=0.5, handle_signals=False, domain=domain)
    assert summary.exit_status == 0, summary.failures
    pids = {name: stats["pid"] for name, stats in summary.nodes.items()}
    assert pids["a"] == pids["b"] != pids["c"]
    assert os.getpid() not in pids.values()


def test_only_and_skip_choose_the_nodes(domain: Domain) -> None:
    nodes = (_crasher("a", "none"), _crasher("b", "none"), _crasher("c", "none"))
    assert list(run(_launch(*nodes), duration=0.3, handle_signals=False, domain=domain,
                    only=["a", "c"]).nodes) == ["a", "c"]
    assert list(run(_launch(*nodes), duration=0.3, handle_signals=False, domain=domain,
                    skip=["a"]).nodes) == ["b", "c"]
    with pytest.raises(ConfigError, match="unknown node"):
        run(_launch(*nodes), duration=0.3, handle_signals=False, domain=domain, skip=["zz"])


def test_a_mem_bus_keeps_the_threads() -> None:
    summary = run(_launch(_crasher("a", "none")), duration=0.2, handle_signals=False,
                  bus="mem://threads_only")
    assert summary.mode == "threads"
    assert summary.nodes["a"]["pid"] == os.getpid()
    with pytest.raises(ConfigError, match="crosses processes"):
        run(_launch(_crasher("a", "none")), duration=0.2, handle_signals=False,
            bus="mem://threads_only", processes=True)


def _cli(*args: str, domain: Domain) -> subprocess.Popen[str]:
    env = {**os.environ, "PYTHONPATH": str(ROOT), "ECHOLOOP_DOMAIN": str(domain.number)}
    return subprocess.Popen([sys.executable, "-m", "hil_bridge.cli", *args], cwd=ROOT, env=env,
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)


def _wait_for_line(proc: subprocess.Popen[str], needle: str, timeout: float = 120.0) -> None:
    assert proc.stderr is not None
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        line = proc.stderr.readline()
        if not line and proc.poll() is not None:
            break
        if needle in line:
            return
    raise AssertionError(f"no {needle!r} on stderr (exit {proc.poll()})")


def _children(pid: int) -> list[int]:
    out: list[int] = []
    with contextlib.suppress(OSError):
        for task in os.listdir(f"/proc/{pid}/task"):
            with open(f"/proc/{pid}/task/{task}/children") as f:
                out += [int(c) for c in f.read().split()]
    return out


def _port_free(port: int) -> bool:
    """As ZeroMQ binds (SO_REUSEADDR: connections in TIME_WAIT do not hold the port)."""
    with socket.socket() as s:
        s.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        try:
            s.bind(("127.0.0.1", port))
        except OSError:
            return False
    return True


def test_echoloop_run_joins_the_bus_of_a_launch_that_skips_its_node(domain: Domain) -> None:
    launch = _cli("launch", str(ROOT / "launch" / "demo.yaml"), "--duration", "60",
                  "--skip", "autopilot", "--expect", "server.cmd_applied > 0", domain=domain)
    try:
        _wait_for_line(launch, "running server")
        node = _cli("run", "drivers.can.adapter:AutopilotAdapter", "--name", "autopilot",
                    "--param", "gliders={0: 0, 1: 1, 2: 2, 3: 3, 4: 4, 5: 5, 6: 6, 7: 7}",
                    "--duration", "6", "--expect", "autopilot.cmd_forwarded > 0",
                    domain=domain)
        out, err = node.communicate(timeout=120)
        assert node.returncode == 0, out + err
    finally:
        launch.send_signal(signal.SIGTERM)
        out, err = launch.communicate(timeout=120)
    assert launch.returncode == 0, out + err[-3000:]


@pytest.mark.parametrize("worker", ["pool", "nodes"])
def test_a_launcher_killed_with_sigkill_leaves_nothing_behind(domain: Domain,
                                                              worker: str) -> None:
    launch = _cli("launch", str(ROOT / "launch" / "demo.yaml"), "--duration", "120",
                  "--param", f"server.echo_worker={worker}", "--param", "server.echo_workers=1",
                  domain=domain)
    try:
        _wait_for_line(launch, "running server")
        hosts = _children(launch.pid)
        workers = [c for h in hosts for c in _children(h)]
        assert len(hosts) == 6, hosts
        assert workers, f"the server's echo {worker} has no process"
        link = domain.path("sonar0")
        assert link.is_symlink()
        # the pool's shared tiles, the echo nodes' pose ring
        stores = [s for h in hosts for s in stores_of(h)]
        assert stores, f"the server's echo {worker} shares nothing in memory"
    finally:
        launch.kill()
        launch.communicate(timeout=60)
    deadline = time.monotonic() + 60
    left: dict[str, Any] = {}
    while time.monotonic() < deadline:
        left = {"processes": [p for p in hosts + workers if alive(p)],
                "link": link.is_symlink() or link.exists(),
                "shared stores": [s for s in stores if s.exists()],
                "bus ports": [p for p in domain.ports if not _port_free(p)]}
        if not any(left.values()):
            break
        time.sleep(0.2)
    assert not any(left.values()), left


def test_a_realtime_node_runs_its_threads_fifo_built_at_normal_its_children_normal(
    domain: Domain,
) -> None:
    """A node's ``realtime`` key: the threads its process starts (its own, the bus's I/O
    thread) run SCHED_FIFO at it, its constructor does not, processes it starts inherit it
    unless started within normal_children; once it started, every Python thread of its process
    runs at it (none holds the interpreter lock at normal priority); the others run normal. The
    launcher's threads run real time while the run lasts, its caller's thread only then, and a
    thread of its caller's not at all."""
    sched = "tests.hil_bridge.launch.schednodes:SchedReporter"
    seen: list[int] = []
    caller_stop = threading.Event()
    caller = threading.Thread(target=caller_stop.wait, daemon=True)  # the caller's own thread
    caller.start()

    def during(_spec: object) -> None:
        seen.extend([realtime_priority(), realtime_priority(caller.native_id or 0)])

    summary = run({"allow_modules": ["tests.hil_bridge.launch.schednodes"], "nodes": [
        {"name": "rt", "entry": sched, "realtime": 7},
        {"name": "plain", "entry": sched}]}, duration=0.5, handle_signals=False, domain=domain,
        on_started=during)
    caller_stop.set()
    assert realtime_priority() == 0  # the caller's thread is itself again
    assert summary.exit_status == 0, summary.failures
    rt, plain = summary.nodes["rt"], summary.nodes["plain"]
    assert "scheduling" not in plain
    assert {k: plain[k] for k in ("built_at", "started_at", "asked_at", "thread", "child",
                                  "child_normal")} == dict.fromkeys(
        ("built_at", "started_at", "asked_at", "thread", "child", "child_normal"), 0)
    assert (plain["io"], plain["threads"]) == ([0], [0])
    if not can_realtime(7):  # no CAP_SYS_NICE / RLIMIT_RTPRIO here: normal, and why
        assert rt["scheduling"].startswith("normal (fifo 7 not permitted")
        assert (rt["thread"], rt["io"], rt["threads"], seen) == (0, [0], [0], [0, 0])
        return
    assert rt["scheduling"] == "fifo 7"
    assert seen == [1, 0]  # the launcher's thread at the monitor's priority; the caller's not
    assert (rt["built_at"], rt["started_at"], rt["asked_at"], rt["threads"]) == (0, 7, 7, [7])
    assert (rt["thread"], rt["thread_after"], rt["io"]) == (7, 7, [7])
    assert (rt["child"], rt["child_normal"]) == (7, 0)


def _launch_rt(tmp_path: Path, domain: Domain, *extra: str, prefix: tuple[str, ...] = (),
               also: str = "") -> tuple[dict[str, Any], str]:
    """``echoloop launch`` of one SchedReporter asking for realtime 7 (and the nodes ``also``
    lists, YAML lines): its stats, the launch's stderr."""
    launch = tmp_path / "rt.yaml"
    launch.write_text(
        "allow_modules: [tests.hil_bridge.launch.schednodes]\n"
        "nodes:\n  - {name: rt, entry: 'tests.hil_bridge.launch.schednodes:SchedReporter',"
        " realtime: 7}\n" + also)
    proc = subprocess.run(
        [*prefix, sys.executable, "-m", "hil_bridge.cli", "launch", str(launch), "--duration",
         "0.5", "--domain", str(domain.number), "--json", *extra],
        cwd=ROOT, capture_output=True, text=True, timeout=120)
    assert proc.returncode == 0, proc.stderr
    return json.loads(proc.stdout)["nodes"]["rt"], proc.stderr


def test_no_realtime_runs_a_realtime_file_at_normal_priority(domain: Domain,
                                                             tmp_path: Path) -> None:
    stats, _ = _launch_rt(tmp_path, domain, "--no-realtime")
    assert "scheduling" not in stats
    assert (stats["started_at"], stats["thread"], stats["io"]) == (0, 0, [0])


@pytest.mark.skipif(os.geteuid() != 0 or not shutil.which("setpriv"),
                    reason="dropping CAP_SYS_NICE for a child needs root and setpriv")
def test_a_refused_realtime_runs_the_node_normal_and_says_why(domain: Domain,
                                                              tmp_path: Path) -> None:
    """Without CAP_SYS_NICE (and with the default RLIMIT_RTPRIO of 0) the OS refuses
    SCHED_FIFO: the run goes on at normal priority, the stats say why, and the run warns once,
    however many of its processes asked."""
    stats, err = _launch_rt(tmp_path, domain, prefix=(
        "setpriv", "--bounding-set", "-sys_nice", "--inh-caps", "-sys_nice"), also=(
        "  - {name: rt2, entry: 'tests.hil_bridge.launch.schednodes:SchedReporter',"
        " realtime: 5}\n"))
    assert stats["scheduling"] == "normal (fifo 7 not permitted: Operation not permitted)"
    assert (stats["started_at"], stats["thread"], stats["io"]) == (0, 0, [0])
    [line] = [ln for ln in err.splitlines() if "realtime" in ln]
    assert line.endswith("realtime: SCHED_FIFO 7 not permitted (ulimit -r 0, no CAP_SYS_NICE): "
                         "rt (7), rt2 (5) run at normal priority (docs/launch.md, Real time)")
