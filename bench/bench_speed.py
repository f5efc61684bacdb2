"""Faster than the clock: lockstep frames a second against the firmware doubles, composed and
isolated, and the demo's start-up.

1. **ArduPilot JSON lockstep.** A launch in processes (``echoloop launch``, a claimed domain):
   the server (one 6-DoF SGS 1-26, lockstep at 400 Hz) and the ``ArduPilotSitl`` node, and
   :class:`drivers.mocks.sitl_double.SitlDouble` in this process answering every frame at once
   (unpaced, ``FRAMES`` frames after a warm-up). Frames a second achieved, median of ``REPEAT``
   launches, interleaved: composed (the default: server and node in one process,
   :mod:`hil_bridge.bus.intra`) against ``--isolate`` (each a process) in the same run, and
   composed with the sonar under the glider pinged at 10 Hz of sim time over a maple forest.
2. **PX4 HIL lockstep.** The same with the ``Px4Hil`` node at 250 Hz and
   :mod:`drivers.mocks.px4_double` (a process of its own, booted at once), ``STEPS`` steps.
3. **Start-up.** ``echoloop launch launch/demo.yaml``: wall seconds from the command to the first
   ``/glider/0/state`` this process receives on the domain's bus, median of ``REPEAT``; *cold*:
   empty numba and bytecode caches (``NUMBA_CACHE_DIR``, ``PYTHONPYCACHEPREFIX`` on fresh
   directories), *warm*: the caches as the install left them.
"""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

import numpy as np
import yaml

from bench._util import median, table
from drivers.mocks.sitl_double import SitlDouble, WingLeveler
from hil_bridge.bus.domain import Domain, claim_first_free
from hil_bridge.bus.transport import open_transport

TITLE = "Faster than the clock: lockstep frames a second, composed and isolated; start-up"

ROOT = Path(__file__).resolve().parent.parent
FRAMES = 6000
STEPS = 5000
REPEAT = 3
_FOREST = {"tiled": True, "tile_size_m": 20.0, "spec": {
    "domain": [0.0, -100.0, 1000.0, 100.0], "min_distance_m": 4.0,
    "species": [{"name": "maple", "tree": "maple", "rate": 0.004, "count": 600}]}}


def _spec(rate: int, node: dict[str, Any], *, sonar: bool) -> dict[str, Any]:
    scene: dict[str, Any] = {
        "state_rate_hz": rate,
        "clock": {"mode": "lockstep", "lockstep_timeout_s": 5.0, "lockstep_start_timeout_s": 120.0},
        "vehicles": [{"id": 7, "sixdof": {}, "path": {
            "kind": "points", "points": [[0, 0, 30], [700, 0, 30]]}}],
    }
    nodes = [{"name": "server", "entry": "hil_bridge.server:SimServer",
              "params": {"autopilots": [7], "scene": scene}}, node]
    if sonar:
        scene["forest"] = _FOREST
        scene["sonars"] = [{"id": 0, "mount": 7, "fidelity": "fast",
                            "mount_rpy_rad": [0.0, 1.5707963267948966, 0.0]}]
        nodes.append({"name": "pinger", "entry": "hil_bridge.replay:Pinger",
                      "params": {"sonar_id": 0, "rate_hz": 10.0, "clock": "sim"}})
    return {"description": "bench: lockstep frames a second", "nodes": nodes}


def _launch(spec: dict[str, Any], domain: Domain, tmp: Path, args: list[str]
            ) -> subprocess.Popen[str]:
    path = tmp / "speed.yaml"
    path.write_text(yaml.safe_dump(spec, sort_keys=False))
    proc = subprocess.Popen(
        [sys.executable, "-m", "hil_bridge.cli", "launch", str(path), "--domain",
         str(domain.number), "--duration", "900", "--json", *args], cwd=ROOT, text=True,
        stdout=subprocess.PIPE, stderr=subprocess.PIPE, env=dict(os.environ, PYTHONUNBUFFERED="1"))
    assert proc.stderr is not None
    for line in proc.stderr:
        if "echoloop launch: running" in line:
            return proc
    proc.kill()
    raise RuntimeError(f"bench speed: the launch never ran: {proc.communicate()[1][-2000:]}")


def _end(proc: subprocess.Popen[str]) -> dict[str, Any]:
    proc.send_signal(signal.SIGTERM)
    out, err = proc.communicate(timeout=120)
    if proc.returncode != 0:
        raise RuntimeError(f"bench speed: the launch failed: {err[-2000:]}")
    return dict(json.loads(out))


def _ardupilot_once(args: list[str], sonar: bool, domain: Domain, tmp: Path) -> dict[str, float]:
    assert domain.number is not None
    proc = _launch(_spec(400, {"name": "sitl", "entry": "drivers.ardupilot.sitl:ArduPilotSitl",
                               "params": {"instances": [{"vehicle_id": 7}]}}, sonar=sonar),
                   domain, tmp, args)
    try:
        double = SitlDouble(port=9002 + 10 * domain.number, frame_rate=400, timeout_s=30.0)
        try:
            double.fly(400, WingLeveler())  # warm-up: connections, first ticks, first echoes
            t0 = time.perf_counter()
            double.fly(FRAMES, WingLeveler())
            wall = time.perf_counter() - t0
        finally:
            double.close()
        summary = _end(proc)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.communicate()
    sitl = summary["nodes"]["sitl"]
    echoes = summary["nodes"].get("pinger", {}).get("echoes_received", 0)
    return {"fps": FRAMES / wall, "stale": sitl["replies_stale"], "echoes": echoes}


def _px4_once(args: list[str], domain: Domain, tmp: Path) -> dict[str, float]:
    assert domain.number is not None
    proc = _launch(_spec(250, {"name": "px4", "entry": "drivers.mavlink.px4:Px4Hil",
                               "params": {"vehicle_id": 7, "seed": 1}}, sonar=False),
                   domain, tmp, args)
    try:
        double = subprocess.run(
            [sys.executable, "-m", "drivers.mocks.px4_double", "--url",
             f"tcp://127.0.0.1:{4560 + domain.number}", "--steps", str(STEPS), "--boot-steps",
             "0", "--timeout", "60"], cwd=ROOT, capture_output=True, text=True, timeout=600)
        _end(proc)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.communicate()
    report = json.loads(double.stdout.splitlines()[-1])
    if double.returncode != 0:
        raise RuntimeError(f"bench speed: the PX4 double failed: {report.get('error')}")
    wall = np.array(report["wall_times"][100:])
    return {"fps": (len(wall) - 1) / float(wall[-1] - wall[0])}


def _lockstep_section() -> str:
    configs: list[tuple[str, str, list[str], bool]] = [
        ("ArduPilot JSON, 400 Hz", "composed", [], False),
        ("ArduPilot JSON, 400 Hz", "isolated", ["--isolate"], False),
        ("ArduPilot JSON, 400 Hz, sonar 10 Hz over the forest", "composed", [], True),
        ("PX4 HIL, 250 Hz", "composed", [], False),
        ("PX4 HIL, 250 Hz", "isolated", ["--isolate"], False),
    ]
    runs: dict[int, list[dict[str, float]]] = {k: [] for k in range(len(configs))}
    with tempfile.TemporaryDirectory() as tmp, claim_first_free(Domain(40)) as (domain, _):
        for _ in range(REPEAT):  # interleaved: load changes hit every configuration
            for k, (what, _mode, args, sonar) in enumerate(configs):
                runs[k].append(_px4_once(args, domain, Path(tmp)) if what.startswith("PX4")
                               else _ardupilot_once(args, sonar, domain, Path(tmp)))
    base = {what: median([r["fps"] for r in runs[k]])
            for k, (what, mode, _, _) in enumerate(configs) if mode == "isolated"}
    rows = []
    for k, (what, mode, _, sonar) in enumerate(configs):
        fps = median([r["fps"] for r in runs[k]])
        ratio = base.get(what)
        vs = "1.00" if mode == "isolated" else "" if ratio is None else f"{fps / ratio:.2f}"
        rows.append([what, mode, f"{fps:.0f}", vs,
                     f"{fps / (400 if what.startswith('Ardu') else 250):.2f}",
                     f"{median([r.get('echoes', 0) for r in runs[k]]):.0f}" if sonar else "",
                     f"{sum(int(r.get('stale', 0)) for r in runs[k])}"])
    return (
        f"### Lockstep against the doubles, answered at once: {FRAMES} frames (ArduPilot) or "
        f"{STEPS} steps (PX4) after a warm-up, medians of {REPEAT} launches, interleaved\n\n"
        + table(["loop", "server and node", "frames/s", "vs isolated (same run)",
                 "× real time", "echoes per run", "stale replies"], rows)
        + "\n\nGoals (issue 44): ArduPilot ≥ 4,000 frames/s with the sonar off and ≥ 1,200 "
        "with it; PX4 ≥ 2,500 steps/s.\n"
    )


def _first_state_s(env: dict[str, str], domain: Domain) -> float:
    """Wall seconds from ``echoloop launch launch/demo.yaml`` to the first ``/glider/0/state``."""
    with open_transport(domain.bus_url) as bus:
        bus.subscribe(b"/glider/0/state\0")
        t0 = time.perf_counter()
        proc = subprocess.Popen(
            [sys.executable, "-m", "hil_bridge.cli", "launch", "launch/demo.yaml", "--domain",
             str(domain.number), "--duration", "3"], cwd=ROOT, env=env,
            stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
        try:
            frames = bus.recv(timeout=120)
            took = time.perf_counter() - t0
            proc.wait(timeout=120)
        finally:
            if proc.poll() is None:
                proc.kill()
                proc.wait()
    if frames is None or proc.returncode != 0:
        raise RuntimeError(f"bench speed: no state from the demo (exit {proc.returncode})")
    return took


def _startup_section() -> str:
    rows = []
    cold: list[float] = []
    warm: list[float] = []
    with tempfile.TemporaryDirectory() as tmp, claim_first_free(Domain(40)) as (domain, _):
        base = dict(os.environ)
        for k in range(REPEAT):
            empty = Path(tmp) / f"cold{k}"
            cold.append(_first_state_s({**base, "NUMBA_CACHE_DIR": str(empty / "numba"),
                                        "PYTHONPYCACHEPREFIX": str(empty / "pyc")}, domain))
            warm.append(_first_state_s(base, domain))
    rows.append(["cold (empty numba and bytecode caches)", f"{median(cold):.2f}",
                 f"{min(cold):.2f}", f"{max(cold):.2f}"])
    rows.append(["warm (the install's caches)", f"{median(warm):.2f}", f"{min(warm):.2f}",
                 f"{max(warm):.2f}"])
    return (
        f"### `echoloop launch launch/demo.yaml` to the first `/glider/0/state`, {REPEAT} runs "
        "each, interleaved\n\n"
        + table(["caches", "s median", "min", "max"], rows)
        + "\n\nGoal (issue 44): ≤ 1.5 s warm.\n"
    )


def run(out_dir: Path) -> str:
    del out_dir
    return _lockstep_section() + "\n" + _startup_section()
