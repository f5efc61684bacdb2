"""Lockstep: how fast the closed-loop demo runs when the server waits for its mocks.

``launch/demo.yaml`` (server with forest, 8 Boids gliders and a sonar vehicle; mock sonar head on
a pty behind the serial adapter; mock autopilots on a virtual CAN bus behind the CAN adapter),
run in-process in a private domain (``mem://`` bus), for ``RUN_S`` wall seconds each, in three
configurations measured in the same run: ``realtime`` (the baseline: sim time follows the wall
clock), ``lockstep`` (the mocks answer every state step and ping on sim time; the iq16 echoes
are paced to 921600 baud as on the real link), and ``lockstep`` with the head's byte pacing off
(``throttle: false``), which shows what the serial link costs. Reported per configuration: the
median over ``REPEAT`` runs of sim seconds per wall second (whole run, start-up included), the
lockstep stalls (must be 0), echoes, and process CPU seconds per sim second.
"""

from __future__ import annotations

import tempfile
import time
from pathlib import Path
from typing import Any

from bench._util import median, table
from hil_bridge.bus.domain import Domain
from hil_bridge.launch.runner import load, parse_param_overrides
from hil_bridge.launch.runner import run as launch_run

TITLE = "Lockstep demo: sim seconds per wall second, stalls"

ROOT = Path(__file__).resolve().parent.parent
RUN_S = 10.0
REPEAT = 3
CONFIGS: dict[str, list[str]] = {
    "realtime": [],
    "lockstep": ["server.scene.clock.mode=lockstep"],
    "lockstep, head unpaced": ["server.scene.clock.mode=lockstep",
                               "sonar_head_mock.throttle=false"],
}


def _once(overrides: list[str], where: Path) -> dict[str, Any]:
    spec = load(ROOT / "launch" / "demo.yaml", params_overrides=parse_param_overrides(overrides))
    domain = Domain.private(where)
    cpu0 = time.process_time()
    summary = launch_run(spec, duration=RUN_S, domain=domain, bus=domain.bus_url,
                         handle_signals=False)
    cpu = time.process_time() - cpu0
    server = summary.nodes["server"]
    sim_s = float(server["sim_time_s"])
    return {"rate": sim_s / summary.wall_s, "stalls": int(server["stalls"]), "sim_s": sim_s,
            "wall_s": summary.wall_s, "echoes": int(server["echoes_published"]),
            "cpu_per_sim_s": cpu / sim_s if sim_s else float("nan"),
            "failures": len(summary.failures)}


def _measure() -> dict[str, list[dict[str, Any]]]:
    results: dict[str, list[dict[str, Any]]] = {name: [] for name in CONFIGS}
    with tempfile.TemporaryDirectory() as tmp:
        for k in range(REPEAT):  # interleaved, so load changes hit every configuration
            for name, overrides in CONFIGS.items():
                results[name].append(_once(overrides, Path(tmp) / f"{k}-{len(results[name])}"))
    return results


def run(out_dir: Path) -> str:
    results = _measure()
    base = median([r["rate"] for r in results["realtime"]])
    rows = []
    for name, runs in results.items():
        rate = median([r["rate"] for r in runs])
        rows.append([
            name, f"{rate:.2f}", f"{rate / base:.2f}",
            f"{sum(r['stalls'] for r in runs)}", f"{median([r['sim_s'] for r in runs]):.1f}",
            f"{median([r['echoes'] for r in runs]):.0f}",
            f"{median([r['cpu_per_sim_s'] for r in runs]):.2f}",
            f"{sum(r['failures'] for r in runs)}",
        ])
    return (
        f"`launch/demo.yaml`, {REPEAT} runs of {RUN_S:.0f} s wall per configuration, "
        "interleaved, in-process in a private domain. Rate = sim seconds per wall second over "
        "the whole run (node start-up included); ratio against `realtime` in the same run.\n\n"
        + table(["configuration", "sim s / wall s (median)", "vs realtime", "stalls (all runs)",
                 "sim s per run", "echoes per run", "CPU s per sim s", "failed runs"], rows)
    )
