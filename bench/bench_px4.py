"""PX4 HIL: the node's added latency per lockstep step, the HITL link budget, the sensor model.

1. **Lockstep at 250 Hz against the PX4 double.** A launch in processes, each node in its own
   (``--isolate``, the floor's like the node's; composition: ``bench/bench_speed.py``; the server in
   lockstep at 250 Hz with one 6-DoF glider; the :class:`~drivers.mavlink.px4.Px4Hil` node
   with seeded sensor noise, GNSS at 10 Hz, ground truth at 50 Hz) and the PX4 protocol double
   (:mod:`drivers.mocks.px4_double`, a process of its own) flying ``STEPS`` lockstep steps:
   the node's own time per step (state in → ``HIL_SENSOR`` written, plus
   ``HIL_ACTUATOR_CONTROLS`` in → surfaces published: ``added_latency_us``), the double's round
   trip (controls out → next ``HIL_SENSOR`` in: the node both ways, the bus both ways, the
   server's tick) and the steps per second. Baseline in the same run, launch for launch:
   ``bench/px4_floor.py`` in the node's place (the same bus subscription, publisher, QoS and
   socket; one fixed ``HIL_SENSOR`` per state, one ``SurfaceCmd`` per controls: no sensors,
   no message building), the floor of a Python node on this machine. Medians of ``REPEAT``
   launches each, interleaved.
2. **HITL link budget at 921600 baud.** The node on a serial link (a pty pair: the double
   holds its master, as a Pixhawk's USB would, and counts every byte), in real time, with a
   two-eared sonar pinged at 20 Hz (two ``DISTANCE_SENSOR`` per ping), ``HIL_SENSOR`` at
   250 Hz, ``HIL_GPS`` at 10 Hz and ``HIL_STATE_QUATERNION`` at 50 Hz: the bytes a second
   the flight controller receives, as a share of the link (921600 baud, 10 bits a byte);
   again with the HITL defaults (no ground truth).
3. **The sensor model.** :meth:`sim_core.sensors.SensorSuite.sample` for one vehicle with
   noise (the compiled kernel and what wraps it), and its kernels' compile time in a fresh
   process with an empty numba cache against loading them from the cache.
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
from hil_bridge.bus.domain import Domain, claim_first_free

TITLE = "PX4 HIL: node latency per lockstep step, HITL link budget, sensor model"

ROOT = Path(__file__).resolve().parent.parent
STEPS = 5000
REPEAT = 3
HITL_STEPS = 2500
BAUD_BYTES_S = 921600 / 10


def _launch_spec(entry: str, params: dict[str, Any], *, sonar: bool = False) -> dict[str, Any]:
    scene: dict[str, Any] = {
        "state_rate_hz": 250,
        "clock": {"mode": "lockstep", "lockstep_timeout_s": 5.0,
                  "lockstep_start_timeout_s": 120.0},
        "vehicles": [{"id": 7, "sixdof": {}, "path": {
            "kind": "points", "points": [[0, 0, 400], [700, 0, 400]]}}],
    }
    nodes: list[dict[str, Any]] = [
        {"name": "server", "entry": "hil_bridge.server:SimServer",
         "params": {"autopilots": [7], "scene": scene}},
        {"name": "px4", "entry": entry, "params": params},
    ]
    if sonar:
        scene["forest"] = {"tiled": True, "tile_size_m": 20.0, "spec": {
            "domain": [0.0, -100.0, 1000.0, 100.0], "min_distance_m": 4.0,
            "species": [{"name": "maple", "tree": "maple", "rate": 0.001, "count": 60}]}}
        scene["sonars"] = [{"id": 0, "mount": 7, "mount_rpy_rad": [0.0, 1.5707963267948966, 0.0],
                            "ears": [{"position_m": [0.0, 0.015, 0.0]},
                                     {"position_m": [0.0, -0.015, 0.0]}]}]
        nodes.append({"name": "pinger", "entry": "hil_bridge.replay:Pinger",
                      "params": {"sonar_id": 0, "rate_hz": 20.0, "beamwidth": 0.7}})
    spec: dict[str, Any] = {"description": "bench: PX4 HIL", "nodes": nodes}
    if entry.startswith("bench."):
        spec["allow_modules"] = [entry.split(":")[0]]
    return spec


def _run(spec: dict[str, Any], domain: Domain, tmp: Path, double_args: list[str]
         ) -> tuple[dict[str, Any], dict[str, Any]]:
    """Launch ``spec`` in ``domain``, fly the double with ``double_args``: (the double's
    report, the launch summary's nodes)."""
    assert domain.number is not None
    path = tmp / "px4_bench.yaml"
    path.write_text(yaml.safe_dump(spec, sort_keys=False))
    proc = subprocess.Popen(
        [sys.executable, "-m", "hil_bridge.cli", "launch", str(path), "--domain",
         str(domain.number), "--duration", "600", "--json", "--isolate"], cwd=ROOT, text=True,
        stdout=subprocess.PIPE, stderr=subprocess.PIPE, env=dict(os.environ, PYTHONUNBUFFERED="1"))
    try:
        assert proc.stderr is not None
        for line in proc.stderr:
            if "echoloop launch: running" in line:
                break
        else:
            raise RuntimeError(f"bench px4: the launch never ran: {proc.communicate()[1]}")
        double = subprocess.run([sys.executable, "-m", "drivers.mocks.px4_double", *double_args,
                                 "--timeout", "60"], cwd=ROOT, capture_output=True, text=True,
                                timeout=600)
        proc.send_signal(signal.SIGTERM)
        out, err = proc.communicate(timeout=120)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.communicate()
    report = json.loads(double.stdout.splitlines()[-1])
    if double.returncode != 0 or proc.returncode != 0:
        raise RuntimeError(f"bench px4: {report.get('error')} / {err[-2000:]}")
    return report, json.loads(out)["nodes"]


def _lockstep_once(entry: str, params: dict[str, Any], domain: Domain, tmp: Path
                   ) -> dict[str, float]:
    assert domain.number is not None
    report, nodes = _run(_launch_spec(entry, params), domain, tmp, [
        "--url", f"tcp://127.0.0.1:{4560 + domain.number}", "--steps", str(STEPS),
        "--boot-steps", "0"])  # the floor cannot pace a booting PX4: both answered at once
    added = nodes["px4"]["added_latency_us"]
    rtt = np.array(report["rtt_us"][100:])
    wall = np.array(report["wall_times"][100:])
    return {"p50": added["p50"], "p99": added["p99"], "rtt50": float(np.percentile(rtt, 50)),
            "rtt99": float(np.percentile(rtt, 99)),
            "steps_s": (len(wall) - 1) / float(wall[-1] - wall[0])}


def _lockstep_section() -> str:
    node = {"vehicle_id": 7, "seed": 1}
    runs: dict[str, list[dict[str, float]]] = {"node": [], "floor": []}
    with tempfile.TemporaryDirectory() as tmp, claim_first_free(Domain(45)) as (domain, _):
        for _ in range(REPEAT):
            runs["node"].append(_lockstep_once("drivers.mavlink.px4:Px4Hil", node, domain,
                                               Path(tmp)))
            runs["floor"].append(_lockstep_once("bench.px4_floor:Px4Floor", {"vehicle_id": 7},
                                                domain, Path(tmp)))
    rows = []
    for name, label in (("node", "the PX4 HIL node"), ("floor", "its floor (same run)")):
        r = runs[name]
        rows.append([label] + [f"{median([x[k] for x in r]):.0f}" for k in (
            "p50", "p99", "rtt50", "rtt99", "steps_s")])
    node_p50 = median([x["p50"] for x in runs["node"]])
    floor_p50 = median([x["p50"] for x in runs["floor"]])
    return (
        f"### Lockstep at 250 Hz against the PX4 double: {STEPS} steps, medians of {REPEAT} "
        "launches each, interleaved\n\n"
        + table(["node", "added µs p50", "added µs p99", "double round trip µs p50", "p99",
                 "steps/s"], rows)
        + f"\n\nThe node's own work beyond its floor: {node_p50 - floor_p50:.0f} µs at p50 "
        f"({node_p50 / floor_p50:.2f}× the floor's). Goal (issue 41): added ≤ 200 µs p50, "
        "≤ 500 µs p99.\n"
    )


def _hitl_once(ground_truth_hz: float | None, domain: Domain, tmp: Path) -> dict[str, Any]:
    link = tmp / "px4-usb"
    params: dict[str, Any] = {"vehicle_id": 7, "link": f"serial://{link}?baud=921600",
                              "ranges": {"sonars": [{"sonar_id": 0, "fov_deg": 40.0}]}}
    if ground_truth_hz is not None:
        params["ground_truth_hz"] = ground_truth_hz
    report, _ = _run(_launch_spec("drivers.mavlink.px4:Px4Hil", params, sonar=True), domain,
                     tmp, ["--url", f"pty://{link}", "--hitl", "--steps", str(HITL_STEPS)])
    wall = report["wall_times"]
    seconds = float(wall[-1] - wall[0])
    counts = report["counts"]
    return {"bytes_s": report["bytes_in"] / seconds, "seconds": seconds,
            "rates": {k: counts.get(k, 0) / seconds for k in (
                "HIL_SENSOR", "HIL_GPS", "DISTANCE_SENSOR", "HIL_STATE_QUATERNION")}}


def _hitl_section() -> str:
    rows = []
    with tempfile.TemporaryDirectory() as tmp, claim_first_free(Domain(46)) as (domain, _):
        for label, gt in (("issue 41's mix (ground truth at 50 Hz)", 50.0),
                          ("HITL defaults (no ground truth)", None)):
            r = _hitl_once(gt, domain, Path(tmp))
            rates = r["rates"]
            rows.append([label, f"{r['seconds']:.1f}", f"{rates['HIL_SENSOR']:.0f}",
                         f"{rates['HIL_GPS']:.1f}", f"{rates['DISTANCE_SENSOR']:.1f}",
                         f"{rates['HIL_STATE_QUATERNION']:.1f}", f"{r['bytes_s']:.0f}",
                         f"{100 * r['bytes_s'] / BAUD_BYTES_S:.1f} %"])
    return (
        "### HITL link budget at 921600 baud, through a pty pair, in real time\n\n"
        + table(["messages", "s measured", "HIL_SENSOR /s", "HIL_GPS /s", "DISTANCE_SENSOR /s",
                 "HIL_STATE_QUATERNION /s", "bytes/s to PX4", "share of the link"], rows)
        + "\n\nThe share is the bytes a second the double read over 92,160 bytes a second "
        "(921600 baud, 8N1). Goal (issue 41): ≤ 50 % for the first row's mix.\n"
    )


_SAMPLE = """
import time
import numpy as np
from sim_core.sensors import SensorSpec, SensorSuite, SensorTruth
from sim_core.sensors.kernels import warm_up
t0 = time.perf_counter()
warm_up()
print(time.perf_counter() - t0)
"""


def _sensor_section() -> str:
    from sim_core.sensors import SensorSpec, SensorSuite, SensorTruth
    from sim_core.sensors.kernels import warm_up

    warm_up()
    truth = SensorTruth.of([[47.0, 8.0, 400.0]], [[20.0, 0.0, -0.7]], [[1.0, 0.0, 0.0, 0.0]],
                           [[0.01, 0.0, 0.0]], [[0.0, 0.0, 9.81]], [20.0])
    times = []
    for _ in range(5):
        suite = SensorSuite(SensorSpec(), 1, seed=1)
        t0 = time.perf_counter()
        for k in range(20000):
            suite.sample(k * 4_000_000, truth)
        times.append((time.perf_counter() - t0) / 20000)
    compile_s, load_s = [], []
    for _ in range(3):
        with tempfile.TemporaryDirectory() as cache:
            env = dict(os.environ, NUMBA_CACHE_DIR=cache)
            for out in (compile_s, load_s):  # an empty cache, then the one just written
                r = subprocess.run([sys.executable, "-c", _SAMPLE], cwd=ROOT, env=env,
                                   capture_output=True, text=True, check=True)
                out.append(float(r.stdout.strip()))
    return (
        "### The sensor model\n\n"
        + table(["measure", "median"], [
            ["`SensorSuite.sample`, one vehicle with noise, µs a sample (5 × 20,000)",
             f"{median(times) * 1e6:.1f}"],
            ["its kernels compiled, empty numba cache, s (3 fresh processes)",
             f"{median(compile_s):.2f}"],
            ["its kernels loaded from the cache, s (same processes' caches)",
             f"{median(load_s):.3f}"],
        ])
        + "\n\n`make` compiles the kernels once at install (`sim_core.sensors.kernels.warm_up`); "
        "a node loads them when it starts, before its first state.\n"
    )


def run(out_dir: Path) -> str:
    del out_dir
    return _lockstep_section() + "\n" + _hitl_section() + "\n" + _sensor_section()
