"""Launch files: validation at load, overrides, a run that stops at its duration or on SIGTERM."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
from pathlib import Path
from typing import Any

import pytest
import yaml

from hil_bridge.launch.runner import load, parse_param_overrides, run
from sim_core.config import ConfigError

ROOT = Path(__file__).resolve().parents[3]

SERVER = {
    "name": "server",
    "entry": "hil_bridge.server:SimServer",
    "params": {"scene": {"swarm": {"overrides": {"numAgents": 2, "dt": 0.1}},
                         "state_rate_hz": 20}},
}


def _write(tmp_path: Path, data: dict[str, Any]) -> Path:
    path = tmp_path / "launch.yaml"
    path.write_text(yaml.safe_dump(data), encoding="utf-8")
    return path


@pytest.mark.parametrize(
    ("data", "match"),
    [
        ({"nodes": [SERVER], "colour": 1}, r"unknown key\(s\) \['colour'\]"),
        ({"nodes": [{**SERVER, "entry": "hil_bridge.nosuch:X"}]}, r"nodes\[0\]\.entry: cannot"),
        ({"nodes": [{**SERVER, "entry": "hil_bridge.server:Nope"}]}, "has no attribute 'Nope'"),
        ({"nodes": [{**SERVER, "entry": "hil_bridge.bus.stats:percentiles"}]}, "is not a class"),
        ({"nodes": [{**SERVER, "entry": "hil_bridge.errors:HilError"}]}, "not a launchable"),
        ({"nodes": [{**SERVER, "entry": "hil_bridge.server"}]}, "expected 'package.module:Class'"),
        ({"nodes": [SERVER, SERVER]}, "duplicate node name 'server'"),
        ({"nodes": []}, "at least one node"),
        ({"nodes": [{**SERVER, "extra": 1}]}, r"nodes\[0\]: unknown key"),
        ({"nodes": [SERVER], "duration": -1}, "duration"),
    ],
    ids=["unknown-key", "bad-module", "bad-attr", "not-class", "not-launchable", "no-colon",
         "duplicate", "empty", "node-key", "duration"],
)
def test_invalid_launch_files_fail_at_load(
    tmp_path: Path, data: dict[str, Any], match: str
) -> None:
    with pytest.raises(ConfigError, match=match):
        load(_write(tmp_path, data))


def test_param_overrides_reach_node_params(tmp_path: Path) -> None:
    path = _write(tmp_path, {"nodes": [SERVER]})
    over = parse_param_overrides(["server.scene.state_rate_hz=40", "server.echo_queue=2"])
    spec = load(path, params_overrides=over)
    assert spec.node("server").params["scene"]["state_rate_hz"] == 40
    assert spec.node("server").params["echo_queue"] == 2
    with pytest.raises(ConfigError, match=r"unknown node\(s\) \['sonar_head'\]"):
        load(path, params_overrides=parse_param_overrides(["sonar_head.port=/dev/null"]))
    with pytest.raises(ConfigError, match=r"expected NODE\.KEY=VALUE"):
        parse_param_overrides(["server=3"])


def test_bad_node_params_fail_before_running(tmp_path: Path) -> None:
    path = _write(tmp_path, {"bus": "mem://launch_bad", "nodes": [
        {**SERVER, "params": {**SERVER["params"], "colour": "red"}}]})
    with pytest.raises(ConfigError, match="colour"):
        run(path, duration=5.0, handle_signals=False)


def test_run_stops_at_duration_and_reports(tmp_path: Path) -> None:
    path = _write(tmp_path, {"bus": "mem://launch_duration", "nodes": [SERVER]})
    summary = run(path, duration=0.3, handle_signals=False)
    assert summary.stopped_by == "duration"
    assert summary.nodes["server"]["ticks"] > 0
    topics = summary.monitor["topics"]
    assert topics["/glider/0/state"]["count"] > 0
    assert summary.monitor["state_latency_ms"]["n"] > 0


def test_sigterm_stops_a_launch_cleanly(tmp_path: Path) -> None:
    path = _write(tmp_path, {"bus": "mem://launch_sigterm", "nodes": [SERVER]})
    proc = subprocess.Popen(
        [sys.executable, "-m", "hil_bridge.launch", str(path), "--json"],
        cwd=ROOT, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
        env={**os.environ, "PYTHONPATH": str(ROOT)},
    )
    try:
        assert proc.stderr is not None
        line = proc.stderr.readline()
        assert "running server" in line
        proc.send_signal(signal.SIGTERM)
        out, err = proc.communicate(timeout=60)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
    assert proc.returncode == 0, err
    summary = json.loads(out)
    assert summary["stopped_by"] == "SIGTERM"
    # the server ran and was stopped cleanly (it may not have ticked yet on a loaded machine)
    assert summary["nodes"]["server"]["tick_error"] == ""
    assert summary["nodes"]["server"]["sim_time_s"] >= 0.0


_PLANTED = '''
from pathlib import Path
Path("imported.marker").write_text("the planted module ran")


class Node:
    def __init__(self, name, *, bus):
        self.name = name

    def start(self):
        pass

    def stop(self):
        pass

    def stats(self):
        return {}
'''


def _launch_in(cwd: Path, data: dict[str, Any], *extra: str) -> subprocess.CompletedProcess[str]:
    (cwd / "l.yaml").write_text(yaml.safe_dump(data), encoding="utf-8")
    return subprocess.run(
        [sys.executable, "-m", "hil_bridge.cli", "launch", "l.yaml", "--duration", "0.2",
         "--bus", "mem://planted", *extra],
        cwd=cwd, capture_output=True, text=True, timeout=120, check=False,
        env={**os.environ, "PYTHONPATH": str(ROOT)},
    )


@pytest.mark.parametrize("planted", ["planted", "drivers"])
def test_a_module_planted_in_the_working_directory_never_runs(tmp_path: Path,
                                                             planted: str) -> None:
    """Entries are checked before any import: a module in the working directory (or a package
    there shadowing one of the project's) is refused, and its code never runs."""
    if planted == "drivers":
        (tmp_path / "drivers").mkdir()
        (tmp_path / "drivers" / "__init__.py").write_text(_PLANTED, encoding="utf-8")
        entry = "drivers:Node"
        match = "not from the installed echoloop"
    else:
        (tmp_path / "planted.py").write_text(_PLANTED, encoding="utf-8")
        entry = "planted:Node"
        match = "is not allowed"
    proc = _launch_in(tmp_path, {"nodes": [SERVER, {"name": "x", "entry": entry}]})
    assert proc.returncode == 1, proc.stderr
    assert match in proc.stderr and len(proc.stderr.strip().splitlines()) == 1, proc.stderr
    assert not (tmp_path / "imported.marker").exists()


def test_allow_modules_and_allow_module_let_a_listed_module_in(tmp_path: Path) -> None:
    (tmp_path / "planted.py").write_text(_PLANTED, encoding="utf-8")
    node = {"name": "x", "entry": "planted:Node"}
    proc = _launch_in(tmp_path, {"allow_modules": ["planted"], "nodes": [node]})
    assert proc.returncode == 0, proc.stderr
    assert (tmp_path / "imported.marker").exists()
    (tmp_path / "imported.marker").unlink()
    proc = _launch_in(tmp_path, {"nodes": [node]}, "--allow-module", "planted")
    assert proc.returncode == 0, proc.stderr
    assert (tmp_path / "imported.marker").exists()
    (tmp_path / "imported.marker").unlink()
    # every entry is checked before the first import: an allowed one is not imported either
    proc = _launch_in(tmp_path, {"allow_modules": ["planted"],
                                 "nodes": [node, {"name": "y", "entry": "evil:Node"}]})
    assert proc.returncode == 1 and "'evil' is not allowed" in proc.stderr
    assert not (tmp_path / "imported.marker").exists()


def test_the_launch_runs_the_proxy_a_server_would_embed() -> None:
    from hil_bridge.launch.spec import launch_proxy, node_params, resolve_entry
    from hil_bridge.server import SimServer

    spec = load(ROOT / "launch" / "demo.yaml")
    assert launch_proxy(spec)
    server = spec.nodes[0]
    assert resolve_entry(server.entry) is SimServer
    assert node_params(server, SimServer, overwrite=False)["embed_proxy"] is False
    external = load(ROOT / "launch" / "demo.yaml",
                    params_overrides=parse_param_overrides(["server.embed_proxy=false"]))
    assert not launch_proxy(external)  # the bus's proxy is someone else's
