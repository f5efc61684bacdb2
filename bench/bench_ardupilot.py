"""ArduPilot SITL in the loop: the JSBSim glider's cost, and the JSON node's latency per frame.

1. **JSBSim glider on one core.** :class:`sim_core.sixdof.SixDofGliders` with 1 and 4 SGS 1-26
   gliders flies ``SIM_S`` s of 250 Hz ticks (two JSBSim steps of 2 ms per tick, controls set
   each tick, updraft asked each step) on one thread; CPU time per tick, per glider-tick and
   the real-time factor (sim s per CPU s). Baselines in the same run: the point-mass
   :class:`sim_core.flight.FlightModel` the swarm flies, for as many vehicles, and JSBSim's own
   ``run()`` alone (the C++ floor). Medians of ``REPEAT`` runs.
2. **The SITL node's added latency per frame.** A launch in processes, each node in its own
   (``--isolate``: composition is measured by ``bench/bench_speed.py``; server in lockstep at the
   frame rate with one 6-DoF glider; the ``ArduPilotSitl`` node) and the protocol double in this
   process sending servo packets paced at 400 Hz and 1200 Hz for ``FLY_S`` s of wall time: the
   node's own time per frame (packet in → surfaces published, plus state in → JSON sent),
   the double's round trip (the node, the bus both ways and the server's tick) and the frame
   rate achieved. Baseline in the same run: a bare UDP responder process answering each packet
   with a JSON line of the same size (the round trip of the OS and Python alone).
"""

from __future__ import annotations

import json
import os
import signal
import socket
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
from sim_core.flight import FlightModel, FlightParams
from sim_core.sixdof import SixDofGliders, SixDofSpec

TITLE = "ArduPilot SITL: JSBSim glider cost, JSON node latency per frame"

ROOT = Path(__file__).resolve().parent.parent
SIM_S = 20.0
TICK_S = 0.004
REPEAT = 5
RATES = (400, 1200)
FLY_S = 4.0
FLY_REPEAT = 3

_RESPONDER = """
import socket, sys
s = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
s.bind(("127.0.0.1", 0))
print(s.getsockname()[1], flush=True)
line = b"\\n" + b"x" * int(sys.argv[1]) + b"\\n"
while True:
    data, addr = s.recvfrom(4096)
    if data == b"stop":
        break
    s.sendto(line, addr)
"""


def _still(xy: np.ndarray) -> np.ndarray:
    return np.zeros(xy.shape[1])


def _jsbsim_cpu(n: int) -> float:
    g = SixDofGliders([SixDofSpec()] * n, np.array([[0.0, 40.0 * k, 800.0] for k in range(n)]),
                      np.zeros(n))
    u = np.tile([0.0, -0.15, 0.0, 0.0], (n, 1))
    ticks = round(SIM_S / TICK_S)
    t0 = time.thread_time()
    for _ in range(ticks):
        g.step(TICK_S, u, _still)
        g.outputs()
    return time.thread_time() - t0


def _point_mass_cpu(n: int) -> float:
    model = FlightModel.from_params([FlightParams()] * n, glide=[True] * n,
                                    polar=(-0.2, 0.1, -1.0))
    y = np.zeros((6, n))
    y[2], y[5] = 800.0, 12.0
    u = np.stack([np.zeros(n), np.full(n, 12.0)])
    ticks = round(SIM_S / TICK_S)
    t0 = time.thread_time()
    for _ in range(ticks):
        y, _ = model.step(y, u, TICK_S, substeps=2, updraft=_still)
    return time.thread_time() - t0


def _raw_run_cpu() -> float:
    g = SixDofGliders([SixDofSpec()], np.array([[0.0, 0.0, 800.0]]), np.zeros(1))
    fdm = g._fdm[0]
    fdm.set_dt(TICK_S / 2)
    steps = round(SIM_S / TICK_S) * 2
    t0 = time.thread_time()
    for _ in range(steps):
        fdm.run()
    return time.thread_time() - t0


def _cost_section() -> str:
    ticks = round(SIM_S / TICK_S)
    rows = []
    raw = median([_raw_run_cpu() for _ in range(REPEAT)])
    for n in (1, 4):
        runs = {"jsbsim": [], "point": []}
        for _ in range(REPEAT):  # interleaved, so load changes hit both
            runs["jsbsim"].append(_jsbsim_cpu(n))
            runs["point"].append(_point_mass_cpu(n))
        cpu, base = median(runs["jsbsim"]), median(runs["point"])
        rows.append([n, f"{cpu / ticks * 1e6:.0f}", f"{cpu / ticks / n * 1e6:.0f}",
                     f"{SIM_S / cpu:.0f}", f"{base / ticks * 1e6:.0f}", f"{cpu / base:.1f}"])
    return (
        f"### JSBSim SGS 1-26 on one core: {SIM_S:.0f} s of 250 Hz ticks, medians of {REPEAT}\n\n"
        + table(["gliders", "CPU µs per tick", "per glider-tick", "real-time factor",
                 "point-mass model, µs per tick (same run)", "JSBSim / point mass"], rows)
        + f"\n\nJSBSim's `run()` alone, one glider: {raw / (ticks * 2) * 1e6:.1f} µs per 2 ms "
        f"step, {raw / ticks * 1e6:.0f} µs of each tick's two (same run): the rest of a "
        "tick is the Python around it (properties read and written one by one, frames).\n"
    )


def _bench_launch(rate: int, path: Path) -> None:
    spec = {
        "description": "bench: one 6-DoF glider and the SITL node, lockstep at the frame rate",
        "nodes": [
            {"name": "server", "entry": "hil_bridge.server:SimServer", "params": {
                "autopilots": [7], "scene": {
                    "state_rate_hz": rate,
                    "clock": {"mode": "lockstep", "lockstep_timeout_s": 5.0,
                              "lockstep_start_timeout_s": 120.0},
                    "vehicles": [{"id": 7, "sixdof": {}, "path": {
                        "kind": "points", "points": [[0, 0, 400], [700, 0, 400]]}}],
                }}},
            {"name": "sitl", "entry": "drivers.ardupilot.sitl:ArduPilotSitl",
             "params": {"instances": [{"vehicle_id": 7}]}},
        ],
    }
    path.write_text(yaml.safe_dump(spec, sort_keys=False))


def _fly_once(rate: int, domain: Domain, launch_file: Path) -> dict[str, Any]:
    assert domain.number is not None
    proc = subprocess.Popen(
        [sys.executable, "-m", "hil_bridge.cli", "launch", str(launch_file), "--domain",
         str(domain.number), "--duration", "600", "--json", "--isolate"], cwd=ROOT, text=True,
        stdout=subprocess.PIPE, stderr=subprocess.PIPE, env=dict(os.environ, PYTHONUNBUFFERED="1"))
    try:
        assert proc.stderr is not None
        for line in proc.stderr:
            if "echoloop launch: running" in line:
                break
        double = SitlDouble(port=9002 + 10 * domain.number, frame_rate=rate, timeout_s=30.0)
        try:
            double.fly(rate // 2, WingLeveler())  # warm-up: connections, first ticks
            double.rtt_us.clear()
            frames = round(FLY_S * rate)
            t0 = time.perf_counter()
            double.fly(frames, WingLeveler(), paced=True)
            wall = time.perf_counter() - t0
            rtt = np.array(double.rtt_us)
        finally:
            double.close()
        proc.send_signal(signal.SIGTERM)
        out, _ = proc.communicate(timeout=120)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.communicate()
    sitl = json.loads(out)["nodes"]["sitl"]
    return {"added_p50": sitl["added_latency_us"]["p50"],
            "added_p99": sitl["added_latency_us"]["p99"],
            "rtt_p50": float(np.percentile(rtt, 50)), "rtt_p99": float(np.percentile(rtt, 99)),
            "fps": frames / wall, "stale": sitl["replies_stale"]}


def _floor_once(rate: int) -> tuple[float, float]:
    line_len = 330  # about the size of a state line
    proc = subprocess.Popen([sys.executable, "-c", _RESPONDER, str(line_len)],
                            stdout=subprocess.PIPE, text=True)
    try:
        assert proc.stdout is not None
        port = int(proc.stdout.readline())
        sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        sock.settimeout(5.0)
        rtt = []
        period = 1.0 / rate
        due = time.perf_counter()
        for _ in range(round(FLY_S * rate)):
            due += period
            time.sleep(max(0.0, due - time.perf_counter()))
            t0 = time.perf_counter_ns()
            sock.sendto(b"\0" * 40, ("127.0.0.1", port))
            sock.recvfrom(4096)
            rtt.append((time.perf_counter_ns() - t0) / 1e3)
        sock.sendto(b"stop", ("127.0.0.1", port))
        sock.close()
    finally:
        proc.wait(timeout=10)
    return float(np.percentile(rtt, 50)), float(np.percentile(rtt, 99))


def _latency_section() -> str:
    rows = []
    with tempfile.TemporaryDirectory() as tmp, claim_first_free(Domain(40)) as (domain, _):
        for rate in RATES:
            launch_file = Path(tmp) / f"bench_{rate}.yaml"
            _bench_launch(rate, launch_file)
            runs, floors = [], []
            for _ in range(FLY_REPEAT):
                runs.append(_fly_once(rate, domain, launch_file))
                floors.append(_floor_once(rate))
            rows.append([
                rate, f"{median([r['added_p50'] for r in runs]):.0f}",
                f"{median([r['added_p99'] for r in runs]):.0f}",
                f"{median([r['rtt_p50'] for r in runs]):.0f}",
                f"{median([r['rtt_p99'] for r in runs]):.0f}",
                f"{median([f[0] for f in floors]):.0f}", f"{median([f[1] for f in floors]):.0f}",
                f"{median([r['fps'] for r in runs]):.0f}",
                f"{sum(r['stale'] for r in runs)}",
            ])
    return (
        f"### The SITL node against the protocol double: {FLY_S:.0f} s paced at the frame rate "
        f"(after a warm-up), medians of {FLY_REPEAT} launches\n\n"
        + table(["frame rate Hz", "node added µs p50", "node added µs p99",
                 "double round trip µs p50", "p99", "bare UDP responder round trip µs p50 "
                 "(same run)", "p99", "frames/s achieved", "stale replies"], rows)
        + "\n\nEach frame is one tick of the server in lockstep (state rate = frame rate), "
        "so the round trip is the node, the bus both ways and the server's tick; the node's "
        "own part is `added_latency_us` from its summary.\n"
    )


def run(out_dir: Path) -> str:
    del out_dir
    return _cost_section() + "\n" + _latency_section()
