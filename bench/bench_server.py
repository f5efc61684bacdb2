"""Simulation server: does echo synthesis delay the 250 Hz state stream?

The real :class:`hil_bridge.server.SimServer` runs the seed 000 forest with a sonar vehicle on the
"8" route at ``state_rate_hz = 250`` (realtime clock), on an in-process ``mem://`` bus so that
only the server's own threads compete. A subscriber timestamps every ``/glider/0/state`` on
arrival; we report the inter-arrival gaps (ideal 4 ms) and the server's late ticks, for three
configurations measured in the same run: no pings (baseline), 10 Hz pings with echoes computed in
the server's echo thread (``echo_worker: thread``, the default), and 10 Hz pings with echoes in
the spawned worker process (``echo_worker: process``). Pings carry beamwidths U(30°, 65°).
"""

from __future__ import annotations

import threading
import time
from pathlib import Path
from typing import Any

import numpy as np

from bench._util import table
from hil_bridge.messages import GliderState
from hil_bridge.node import Node
from hil_bridge.replay import Pinger
from hil_bridge.server import SimServer

TITLE = "Server: 250 Hz state stream while echoes are computed"

RUN_S = 10.0
WARMUP_S = 4.0
SCENE: dict[str, Any] = {
    "forest": {"preset": "seed000-fig5d", "tiled": True, "tile_size_m": 20.0},
    "sonars": [{"id": 0, "mount": 0, "fidelity": "fast"}],
    "vehicles": [{"id": 0, "path": {
        "kind": "figure_eight", "speed_mps": 3.0,
        "params": {"center": [8.0, 7.0], "half_length": 7.0, "half_width": 5.0,
                   "altitude": 2.0, "count": 400}}}],
    "state_rate_hz": 250,
    "clock": {"mode": "realtime"},
}


def _measure(label: str, worker: str, ping_hz: float) -> dict[str, Any]:
    bus = f"mem://bench_server_{label}"
    srv = SimServer("server", bus=bus, scene=SCENE, echo_worker=worker)
    arrivals: list[int] = []
    lock = threading.Lock()
    obs = Node("observer", bus=bus)

    def on_state(_msg: GliderState) -> None:
        now = time.monotonic_ns()
        with lock:
            arrivals.append(now)

    obs.create_subscription(GliderState, "/glider/0/state", on_state)
    pinger = None
    if ping_hz > 0:
        pinger = Pinger("pinger", bus=bus, rate_hz=ping_hz,
                        beamwidth_range=(np.radians(30), np.radians(65)))
    obs.start()
    srv.start()
    if pinger is not None:
        pinger.start()
    time.sleep(WARMUP_S)  # start-up: the worker starts and the first forest tiles are built
    with lock:
        t_start = np.asarray(arrivals, dtype=np.float64)
        arrivals.clear()
    late0 = srv.stats()["late_ticks"]
    echoes0 = srv.stats()["echoes_published"]
    time.sleep(RUN_S)
    st = srv.stats()
    with lock:
        t = np.asarray(arrivals, dtype=np.float64)
    if pinger is not None:
        pinger.stop()
    srv.stop()
    obs.stop()
    gaps = np.diff(t) / 1e6
    start_gaps = np.diff(t_start) / 1e6
    return {
        "start_max": float(start_gaps.max()) if start_gaps.size else float("nan"),
        "start_over20": int(np.count_nonzero(start_gaps > 20.0)),
        "label": label, "states": len(t), "p50": float(np.percentile(gaps, 50)),
        "p99": float(np.percentile(gaps, 99)), "max": float(gaps.max()),
        "over20": int(np.count_nonzero(gaps > 20.0)), "late": st["late_ticks"] - late0,
        "echoes": st["echoes_published"] - echoes0,
        "compute_p50": st["echo_compute_ms"]["p50"],
    }


def run(out_dir: Path) -> str:
    rows = [
        _measure("no pings", "thread", 0.0),
        _measure("10 Hz pings, echo thread", "thread", 10.0),
        _measure("10 Hz pings, echo process", "process", 10.0),
    ]
    base = rows[0]
    body = table(
        ["configuration", "start-up: gap max ms", "start-up: gaps > 20 ms", "states",
         "gap p50 ms", "gap p99 ms", "gap max ms", "gaps > 20 ms", "late ticks", "echoes",
         "echo compute p50 ms", "p99 / baseline p99"],
        [[r["label"], f"{r['start_max']:.1f}", r["start_over20"], r["states"],
          f"{r['p50']:.2f}", f"{r['p99']:.2f}", f"{r['max']:.1f}", r["over20"], r["late"],
          r["echoes"],
          "-" if r["echoes"] == 0 else f"{r['compute_p50']:.1f}",
          f"{r['p99'] / base['p99']:.2f}"] for r in rows],
    )
    return (
        f"{__doc__}\nStart-up = the first {WARMUP_S:.0f} s (worker start, first tiles built); "
        f"then {RUN_S:.0f} s steady state. Ideal gap 4.00 ms.\n\n{body}\n"
    )
