"""Replay at the asked rate: does a logged flight through a big forest keep to ``--rate``, and
does ``--duration`` hold?

A flight log (CSV ``t, x, y, z`` at 25 Hz, written here: a 366 m stadium loop at 5 m/s, 6 m up,
across the whole 160 × 80 m maple forest of ``launch/bench_multisonar.yaml``, 978,432 leaves in
32 tiles of 20 m) is replayed as ``echoloop replay LOG --scene … --rate R --duration D`` does
(:func:`hil_bridge.replay.trajectory.build_replay_launch`, a claimed domain, its ZeroMQ bus):
states at 50 Hz, sonar 0 on the vehicle pinged at 10 Hz, and ``/forest/points`` along the whole
route
(every tile of the forest). *Rate kept* is the server's ``rate_achieved`` (sim time / wall time
of its ticks) over the asked rate; *sim covered* is the sim time served over ``R × D``; *run
after start* is the wall time from every node running to the run's end (stopping included)
against ``D``. The replay computes echoes, tiles and points in a worker process (``echo_worker:
process``); the last row is the echo thread it used before (issue 12: a 4× replay of a swarm
trace ran 14× slow, most of it re-summing the tile cache's sizes, which ``TiledForest`` now
keeps as a running total). Issue 12's goal: the rate within 5 %, ``--duration`` held.

*Fast replay of a real log*: ``echoloop replay tests/data/flightlogs/ardupilot_quadplane_sitl.tlog
--fast --domain auto`` (the 208.4 s ArduPilot QuadPlane tlog through the default seed 000
forest) run as a user runs it, a fresh process, timed from its start to its exit (reading the
log, starting and stopping the node processes included), with the sonar off (``--sonar 0``) and
pinging at 10 Hz of sim time (``--sonar 10``: the pinger is the lockstep server's sonar head,
each ping answered before the next). *× real time* is the log's 208.4 s over that wall time.
Issue 43's goals: ≥ 20× with the sonar off, ≥ 5× pinging at 10 Hz, on 2 cores.
"""

from __future__ import annotations

import json
import math
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

import numpy as np

from bench._util import table
from hil_bridge.bus.domain import claim_first_free
from hil_bridge.files.config import load_yaml
from hil_bridge.launch.runner import run as launch_run
from hil_bridge.replay.trajectory import build_replay_launch

TITLE = "Replay at the asked rate"

ROOT = Path(__file__).resolve().parent.parent
FOREST_FROM = ROOT / "launch" / "bench_multisonar.yaml"
#: (asked rate, --duration wall s, echo worker)
CASES = [(1.0, 10.0, "process"), (2.0, 10.0, "process"), (4.0, 10.0, "process"),
         (16.0, 4.5, "process"), (4.0, 10.0, "thread")]
SPEED_MPS = 5.0
LOG_HZ = 25.0
REAL_LOG = ROOT / "tests" / "data" / "flightlogs" / "ardupilot_quadplane_sitl.tlog"
#: the built-in pinger's rate of each fast case (0: sonar off)
FAST_SONAR_HZ = (0.0, 10.0)


def write_log(path: Path) -> float:
    """The stadium loop across the forest as a CSV flight log; returns its duration (s)."""
    straight, r, x0 = 120.0, 20.0, 20.0
    length = 2 * straight + 2 * math.pi * r
    s = np.arange(0.0, length, SPEED_MPS / LOG_HZ)
    x = np.empty_like(s)
    y = np.empty_like(s)
    legs = np.cumsum([straight, math.pi * r, straight])
    a = s < legs[0]
    x[a], y[a] = x0 + s[a], 20.0
    b = (s >= legs[0]) & (s < legs[1])
    phi = (s[b] - legs[0]) / r
    x[b], y[b] = x0 + straight + r * np.sin(phi), 40.0 - r * np.cos(phi)
    c = (s >= legs[1]) & (s < legs[2])
    x[c], y[c] = x0 + straight - (s[c] - legs[1]), 60.0
    d = s >= legs[2]
    phi = (s[d] - legs[2]) / r
    x[d], y[d] = x0 - r * np.sin(phi), 40.0 + r * np.cos(phi)
    t = s / SPEED_MPS
    rows = ["t,x,y,z"] + [f"{ti:.3f},{xi:.4f},{yi:.4f},6.0" for ti, xi, yi in zip(t, x, y,
                                                                                strict=True)]
    path.write_text("\n".join(rows) + "\n", encoding="utf-8")
    return float(t[-1])


def measure(log: Path, rate: float, duration: float, worker: str) -> dict[str, Any]:
    scene = load_yaml(FOREST_FROM)["nodes"][0]["params"]["scene"]
    launch, _ = build_replay_launch(log, scene={"forest": scene["forest"]}, rate=rate)
    launch["nodes"][0]["params"]["echo_worker"] = worker
    started: list[float] = []
    with claim_first_free() as (domain, _):
        summary = launch_run(launch, duration=duration, domain=domain, handle_signals=False,
                             on_started=lambda _spec: started.append(time.monotonic()))
    after_start = time.monotonic() - started[0]
    if summary.failures:
        raise RuntimeError(f"bench_replay ({rate}x, {worker}): {summary.failures}")
    s = summary.nodes["server"]
    return {"rate": rate, "duration": duration, "worker": worker, "server": s,
            "pinger": summary.nodes["pinger"], "after_start": after_start}


def row(r: dict[str, Any]) -> list[Any]:
    s = r["server"]
    asked = r["rate"] * r["duration"]
    kept = s["rate_achieved"] / r["rate"]
    pings = max(1, s["pings_received"])
    return [
        f"{r['rate']:g}×", f"{r['duration']:g}", r["worker"], f"{s['rate_achieved']:.3f}",
        f"{100.0 * kept:.1f}", f"{100.0 * s['sim_time_s'] / asked:.1f}",
        f"{r['after_start']:.2f}", f"{100.0 * s['late_ticks'] / max(1, s['ticks']):.2f}",
        f"{s['echoes_published']} / {s['pings_received']} "
        f"({100.0 * s['echoes_published'] / pings:.0f} %)",
        f"{s['ping_echo_ms']['p50']:.1f} / {s['ping_echo_ms']['p99']:.1f}",
    ]


HEADER = ["rate", "--duration s", "echo worker", "rate_achieved", "rate kept %",
          "sim covered %", "run after start s", "late ticks %", "echoes / pings",
          "ping → echo p50 / p99 ms"]


def measure_fast(sonar_hz: float) -> dict[str, Any]:
    """``echoloop replay REAL_LOG --fast --domain auto --sonar HZ --json`` in a fresh process:
    its wall time and summary."""
    cmd = [sys.executable, "-m", "hil_bridge.cli", "replay", str(REAL_LOG), "--fast",
           "--domain", "auto", "--sonar", f"{sonar_hz:g}", "--json"]
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    t0 = time.monotonic()
    done = subprocess.run(cmd, cwd=ROOT, env=env, capture_output=True, text=True, check=False)
    wall = time.monotonic() - t0
    if done.returncode != 0:
        raise RuntimeError(f"bench_replay fast (--sonar {sonar_hz:g}): exit "
                           f"{done.returncode}: {done.stderr.strip()[-500:]}")
    return {"sonar_hz": sonar_hz, "wall_s": wall, "summary": json.loads(done.stdout)}


def fast_row(r: dict[str, Any]) -> list[Any]:
    summary = r["summary"]
    s = summary["nodes"]["server"]
    length = summary["log"]["duration_s"]
    pinger = summary["nodes"].get("pinger", {})
    return [
        "off" if not r["sonar_hz"] else f"{r['sonar_hz']:g} Hz sim", f"{length:.1f}",
        f"{r['wall_s']:.2f}", f"{length / r['wall_s']:.1f}", f"{s['tick_wall_s']:.2f}",
        s["clock_mode"], summary["stopped_by"],
        f"{pinger.get('pings_sent', 0)} / {pinger.get('echoes_received', 0)}",
        f"{s['echo_compute_ms']['p50']:.2f}" if r["sonar_hz"] else "–",
    ]


FAST_HEADER = ["sonar", "log s", "wall s", "× real time", "ticking wall s", "server clock",
               "stopped by", "pings / echoes", "echo compute p50 ms"]


def run_fast() -> str:
    """The *fast replay of a real log* table (module docstring)."""
    return table(FAST_HEADER, [fast_row(measure_fast(hz)) for hz in FAST_SONAR_HZ])


def run(out_dir: Path) -> str:
    with tempfile.TemporaryDirectory(prefix="bench_replay_") as tmp:
        log = Path(tmp) / "flight.csv"
        length = write_log(log)
        rows = [measure(log, rate, duration, worker) for rate, duration, worker in CASES]
    return (f"{__doc__}\nLog: {length:.1f} s.\n\n"
            f"{table(HEADER, [row(r) for r in rows])}\n\n"
            f"Fast replay of a real log:\n\n{run_fast()}\n")
