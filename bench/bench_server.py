"""Simulation server: does echo synthesis delay the 250 Hz state stream, and is every state
of the stream a new physics state?

**One sonar vehicle.** The real :class:`hil_bridge.server.sim_server.SimServer` runs the seed 000
forest with a sonar vehicle on the "8" route at ``state_rate_hz = 250`` (realtime clock), on an
in-process ``mem://`` bus so that only the server's own threads compete. A subscriber timestamps
every ``/glider/0/state`` on arrival; we report the inter-arrival gaps (ideal 4 ms) and the
server's late ticks, for three configurations measured in the same run: no pings (baseline),
10 Hz pings with echoes computed in the server's echo thread (``echo_worker: thread``, the
default), and 10 Hz pings with echoes in the spawned worker process (``echo_worker: process``).
Pings carry beamwidths U(30°, 65°).

**The whole loop at hardware rates.** The seed law's 40 gliders (the law's Boids every 0.5 s,
the continuous flight model every tick) and the sonar vehicle, at 50 and 250 Hz, with and
without 10 Hz pings, while an autopilot node commands glider 0 at 50 Hz. A subscriber keeps
every ``/glider/0/state`` and ``/glider/100/state``: *fresh* is the share of consecutive states
one tick apart whose pose differs (the zero-order hold the server had before gave 4 %); the
gaps are between arrivals of glider 0's states. CPU per tick is the tick thread's own CPU time
(``tick_cpu_s`` / ``ticks``); command → effect is the server's ``cmd_effect_ticks`` (1: flown
in the next tick; 2: it arrived while that tick was being computed). Long gaps: over 20 ms at
250 Hz, over two ticks at 50 Hz. Everything runs in one process here (server, pinger,
observer, autopilot), so all Python threads share one interpreter lock.
"""

from __future__ import annotations

import itertools
import threading
import time
from pathlib import Path
from typing import Any

import numpy as np

from bench._util import table
from hil_bridge.bus.messages import GliderState
from hil_bridge.bus.node import Node
from hil_bridge.replay.trajectory import Pinger
from hil_bridge.server.sim_server import SimServer

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


LOOP_S = 8.0
LOOP_WARMUP_S = 4.0


def _loop_scene(rate: float) -> dict[str, Any]:
    return {**SCENE, "state_rate_hz": rate, "swarm": {"law": "default", "seed": 2},
            "vehicles": [{**SCENE["vehicles"][0], "id": 100}],
            "sonars": [{"id": 0, "mount": 100, "fidelity": "fast"}]}


def _fresh(states: list[tuple[int, tuple[float, float, float]]], tick_ns: int) -> float:
    pairs = list(itertools.pairwise(states))
    ok = sum(1 for (ta, pa), (tb, pb) in pairs if tb - ta == tick_ns and pa != pb)
    return 100.0 * ok / max(1, len(pairs))


def _measure_loop(rate: float, ping_hz: float, worker: str = "thread") -> dict[str, Any]:
    from hil_bridge.bus.messages import GliderCmd
    from hil_bridge.bus.qos import QoSProfile

    bus = f"mem://bench_loop_{rate:g}_{ping_hz:g}_{worker}?depth=100000"
    srv = SimServer("server", bus=bus, scene=_loop_scene(rate), echo_worker=worker)
    keep = QoSProfile("bench_keep_all", depth=100_000)
    got: dict[int, list[tuple[int, tuple[float, float, float]]]] = {0: [], 100: []}
    arrivals: list[int] = []
    lock = threading.Lock()
    obs = Node("observer", bus=bus)

    def make(gid: int) -> Any:
        def on_state(msg: GliderState) -> None:
            now = time.monotonic_ns()
            with lock:
                got[gid].append((msg.stamp_ns, (msg.x, msg.y, msg.z)))
                if gid == 0:
                    arrivals.append(now)
        return on_state

    for gid in got:
        obs.create_subscription(GliderState, f"/glider/{gid}/state", make(gid), keep)
    cmd_pub = obs.create_publisher(GliderCmd, "/glider/0/cmd")
    pinger = None
    if ping_hz > 0:
        pinger = Pinger("pinger", bus=bus, rate_hz=ping_hz,
                        beamwidth_range=(np.radians(30), np.radians(65)))
    stop = threading.Event()

    def autopilot() -> None:
        i = 0
        while not stop.wait(0.02):
            i += 1
            cmd_pub.publish(GliderCmd(stamp_ns=0, bank_cmd=0.2 * (-1) ** (i // 10),
                                      airspeed_cmd=10.0))

    pilot = threading.Thread(target=autopilot, daemon=True)
    obs.start()
    srv.start()
    if pinger is not None:
        pinger.start()
    pilot.start()
    time.sleep(LOOP_WARMUP_S)
    st0 = srv.stats()
    with lock:
        for box in got.values():
            box.clear()
        arrivals.clear()
    time.sleep(LOOP_S)
    st = srv.stats()
    with lock:
        states = {g: list(v) for g, v in got.items()}
        t = np.asarray(arrivals, dtype=np.float64)
    stop.set()
    pilot.join()
    if pinger is not None:
        pinger.stop()
    srv.stop()
    obs.stop()
    gaps = np.diff(t) / 1e6
    ticks = st["ticks"] - st0["ticks"]
    long_gap = max(20.0, 2e3 / rate)
    return {
        "label": f"{rate:g} Hz" + (f", {ping_hz:g} Hz echoes ({worker})" if ping_hz else ""),
        "fresh": min(_fresh(v, srv.tick_ns) for v in states.values()),
        "p50": float(np.percentile(gaps, 50)), "p99": float(np.percentile(gaps, 99)),
        "max": float(gaps.max()), "over20": f"{np.count_nonzero(gaps > long_gap)} (> {long_gap:g})",
        "late": st["late_ticks"] - st0["late_ticks"], "ticks": ticks,
        "cpu_ms": 1e3 * (st["tick_cpu_s"] - st0["tick_cpu_s"]) / max(1, ticks),
        "echoes": st["echoes_published"] - st0["echoes_published"],
        "cmd": st["cmd_effect_ticks"],
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
    loop = [_measure_loop(50.0, 0.0), _measure_loop(250.0, 0.0), _measure_loop(250.0, 10.0),
            _measure_loop(250.0, 10.0, "process")]
    body2 = table(
        ["40 gliders + sonar vehicle", "fresh states %", "ticks", "tick CPU ms", "gap p50 ms",
         "gap p99 ms", "gap max ms", "long gaps (ms)", "late ticks", "echoes",
         "cmd → effect ticks p50 / p99 / max"],
        [[r["label"], f"{r['fresh']:.2f}", r["ticks"], f"{r['cpu_ms']:.2f}", f"{r['p50']:.2f}",
          f"{r['p99']:.2f}", f"{r['max']:.1f}", r["over20"], r["late"], r["echoes"],
          f"{r['cmd']['p50']:.0f} / {r['cmd']['p99']:.0f} / {r['cmd']['max']:.0f}"]
         for r in loop],
    )
    return (
        f"{__doc__}\nStart-up = the first {WARMUP_S:.0f} s (worker start, first tiles built); "
        f"then {RUN_S:.0f} s steady state. Ideal gap 4.00 ms.\n\n{body}\n\n"
        f"The whole loop: {LOOP_WARMUP_S:.0f} s start-up, then {LOOP_S:.0f} s measured.\n\n"
        f"{body2}\n"
    )
