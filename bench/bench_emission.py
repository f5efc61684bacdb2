"""Sonar pose at emission: how far is the pose an echo is computed at from the vehicle's true
pose at the ping's stamp, and what does waiting for the tick that covers the stamp add to the
ping → echo latency?

The truth is a path vehicle's path (:func:`sim_core.flight.path_state`, the function the
server samples at every tick): a 5 m circle at 6 m/s (bank 36°, 1.2 rad/s of yaw; three laps,
no loop join) and the 14 × 10 m "8" at 6 m/s (bank changing through the crossings). The
server ticks at 50 Hz (T = 20 ms). Errors: position |p − p_true| (mm) and attitude (the angle
of q* ⊗ q_true, degrees).

**Offline** (:class:`hil_bridge.server.fleet.Fleet` stepped tick by tick, 5 stamps drawn
uniformly per tick over 400 ticks, ``numpy`` seed 0): the pose the server used before for a
stamp after the newest tick (that tick's: *newest tick*), the pose it uses now once the
covering tick exists (*waited*: interpolated between the two ticks around the stamp), and the
pose it extrapolates when that tick is late, 0-1 and 1-2 tick periods past the newest tick.

**Live** (realtime :class:`hil_bridge.server.sim_server.SimServer` on a ``mem://`` bus, the
circle): a head pinging at 20 Hz on the wall clock stamps each ping with the sim time of its
firing (the newest ``/clock`` plus the wall time since it arrived), so its stamps fall between
ticks; with ``pose_wait_ticks`` 2 (default: wait for the covering tick) and 0 (no wait:
extrapolated at once). The error is that of each echo's pose
(``SonarEcho.position``/``orientation``) against the path at the ping's stamp;
``ping_wait_ms`` is the server's own count of how long each ping waited for its tick (wall),
``ping_extrapolated_ms`` how far past the newest tick an extrapolated pose lay (sim),
``ping_echo_ms`` arrival → echo published.
"""

from __future__ import annotations

import math
import threading
import time
from pathlib import Path
from typing import Any

import numpy as np

from bench._util import table
from hil_bridge.bus.messages import Clock, SonarEcho, SonarPing
from hil_bridge.bus.node import Node
from hil_bridge.files.scene import load_scene
from hil_bridge.server.fleet import Fleet
from hil_bridge.server.pose_history import VehiclePose
from hil_bridge.server.sim_server import SimServer
from sim_core.flight import path_state
from sim_core.pose import quat_conjugate, quat_multiply
from sim_core.scene import Scene

TITLE = "Server: sonar pose at emission"

TICK_NS = 20_000_000
OFFLINE_TICKS = 400
PER_TICK = 5
LIVE_S = 10.0
PING_HZ = 20.0
#: pings before this sim time are not measured (a path's first state: t < 0 clamps)
SETTLE_NS = 200_000_000


def _circle(laps: int = 3, n: int = 720) -> list[list[float]]:
    a = np.linspace(0.0, 2 * np.pi * laps, n * laps, endpoint=False)
    return [[8.0 + 5.0 * math.cos(t), 7.0 + 5.0 * math.sin(t), 2.0] for t in a]


PATHS: dict[str, dict[str, Any]] = {
    "circle": {"kind": "points", "speed_mps": 6.0, "loop": False, "points": _circle()},
    "8": {"kind": "figure_eight", "speed_mps": 6.0,
          "params": {"center": [8.0, 7.0], "half_length": 7.0, "half_width": 5.0,
                     "altitude": 2.0, "count": 400}},
}


def _scene(path: dict[str, Any], **extra: Any) -> dict[str, Any]:
    return {"vehicles": [{"id": 1, "path": path}], "state_rate_hz": 50, **extra}


def _angle_deg(qa: Any, qb: Any) -> float:
    d = quat_multiply(quat_conjugate(qa), qb)
    return math.degrees(2.0 * math.atan2(float(np.linalg.norm(d[1:])), abs(float(d[0]))))


def _error(scene: Scene, position: Any, orientation: Any, t_ns: int) -> tuple[float, float]:
    truth = path_state(scene.trajectories[1], t_ns / 1e9)
    return (1e3 * float(np.linalg.norm(np.asarray(position) - truth.position)),
            _angle_deg(orientation, truth.outputs.quat))


def _stats(errors: list[tuple[float, float]]) -> list[str]:
    e = np.asarray(errors)
    out = []
    for col, fmt in ((0, "{:.3f}"), (1, "{:.4f}")):
        x = e[:, col]
        out.append(" / ".join(fmt.format(v) for v in (np.median(x), np.percentile(x, 99),
                                                      x.max())))
    return out


def _offline(name: str) -> list[list[Any]]:
    scene = load_scene(_scene(PATHS[name]))
    fleet = Fleet(scene, tick_ns=TICK_NS, history_ids=[1])
    rng = np.random.default_rng(0)
    kinds = ("newest tick", "waited", "extrapolated 0-1 T", "extrapolated 1-2 T")
    errs: dict[str, list[tuple[float, float]]] = {k: [] for k in kinds}

    def add(kind: str, pose: VehiclePose, t_ns: int) -> None:
        errs[kind].append(_error(scene, pose.position, pose.orientation, t_ns))

    fleet.states()
    for _ in range(OFFLINE_TICKS):
        fleet.advance({})
        fleet.states()
        newest = fleet.history.recorded_ns
        if newest < SETTLE_NS + TICK_NS:
            continue
        for _ in range(PER_TICK):
            s = newest - TICK_NS + 1 + int(rng.integers(TICK_NS))
            add("waited", fleet.history.pose_at(1, s), s)
            s = newest + 1 + int(rng.integers(TICK_NS))
            add("newest tick", fleet.history.pose_at(1, s), s)
            add("extrapolated 0-1 T", fleet.history.pose_at(1, s, extrapolate_ns=2 * TICK_NS), s)
            s += TICK_NS
            add("extrapolated 1-2 T", fleet.history.pose_at(1, s, extrapolate_ns=2 * TICK_NS), s)
    return [[name, kind, len(errs[kind]), *_stats(errs[kind])] for kind in kinds]


def _live(wait_ticks: float) -> dict[str, Any]:
    spec = _scene(PATHS["circle"], forest={"preset": "seed000-fig5d", "query_radius_m": 3.0},
                  clock={"mode": "realtime"},
                  sonars=[{"id": 0, "mount": 1, "echo": {"samples": 8000}}])
    bus = f"mem://bench_emission_{wait_ticks:g}"
    srv = SimServer("server", bus=bus, scene=spec, pose_wait_ticks=wait_ticks)
    head = Node("head", bus=bus)
    pub = head.create_publisher(SonarPing, "/sonar/0/ping")
    lock = threading.Lock()
    clock = [-1, 0.0]  # newest /clock stamp, its arrival (monotonic s)
    echoes: list[SonarEcho] = []
    sent: dict[int, int] = {}

    def on_clock(msg: Clock) -> None:
        with lock:
            if msg.stamp_ns > clock[0]:
                clock[0], clock[1] = int(msg.stamp_ns), time.monotonic()

    def on_echo(msg: SonarEcho) -> None:
        with lock:
            echoes.append(msg)

    head.create_subscription(Clock, "/clock", on_clock)
    head.create_subscription(SonarEcho, "/sonar/0/echo", on_echo)
    head.start()
    srv.start()
    end = time.monotonic() + LIVE_S
    seq = 0
    while time.monotonic() < end:
        time.sleep(1.0 / PING_HZ)
        with lock:
            stamp = -1 if clock[0] < 0 else clock[0] + int((time.monotonic() - clock[1]) * 1e9)
        if stamp < SETTLE_NS:
            continue
        sent[seq] = stamp
        pub.publish(SonarPing(stamp_ns=stamp, ping_seq=seq, az=0.0, el=0.0, beamwidth=0.6))
        seq += 1
    time.sleep(0.5)  # the last echoes
    st = srv.stats()
    srv.stop()
    head.stop()
    scene = load_scene(spec)
    with lock:
        errs = [_error(scene, e.position, e.orientation, sent[e.ping_seq]) for e in echoes]
    return {"wait": wait_ticks, "st": st, "errs": errs, "sent": len(sent)}


def run(out_dir: Path) -> str:
    offline = _offline("circle") + _offline("8")
    body = table(["path", "pose used", "stamps", "position mm p50 / p99 / max",
                  "attitude ° p50 / p99 / max"], offline)
    live = [_live(2.0), _live(0.0)]
    rows = []
    for r in live:
        st = r["st"]
        wait = st["ping_wait_ms"]
        ahead = st["ping_extrapolated_ms"]
        rows.append([
            f"{r['wait']:g}", r["sent"], st["echoes_published"], st["ping_stamp_waited"],
            st["ping_stamp_extrapolated"], st["ping_stamp_future"], *_stats(r["errs"]),
            "-" if wait["n"] == 0 else f"{wait['p50']:.1f} / {wait['p99']:.1f} / "
                                       f"{wait['max']:.1f}",
            "-" if ahead["n"] == 0 else f"{ahead['p50']:.1f} / {ahead['max']:.1f}",
            f"{st['ping_echo_ms']['p50']:.1f} / {st['ping_echo_ms']['p99']:.1f}",
        ])
    body2 = table(["pose_wait_ticks", "pings", "echoes", "waited", "extrapolated",
                   "newest tick (future)", "position mm p50 / p99 / max",
                   "attitude ° p50 / p99 / max", "wait ms p50 / p99 / max",
                   "extrapolated ms p50 / max", "ping → echo ms p50 / p99"], rows)
    return (f"{__doc__}\nOffline, 50 Hz ticks:\n\n{body}\n\n"
            f"Live, {LIVE_S:.0f} s each, {PING_HZ:.0f} Hz pings:\n\n{body2}\n")
