"""Trajectory replay: drive a vehicle along a logged trajectory so pings get echoes from a scene.

``echoloop replay FILE`` builds a launch description in code (plain data, the same runner as
``echoloop launch``): a :class:`~hil_bridge.server.sim_server.SimServer` whose scene has one path
vehicle following ``FILE`` (:func:`hil_bridge.recording.logs.load_trajectory`: linear position,
shortest-arc heading), a sonar mounted on it, and optionally a :class:`Pinger` node that pings at
a fixed rate. External pingers (a sonar-head adapter with a real head) can ping
``/sonar/<id>/ping`` instead; the server answers each at the vehicle's pose when the ping was
emitted (its stamp).

File formats (:mod:`hil_bridge.recording.logs`, ``docs/server.md``): CSV/NPZ columns in local ENU or
geodetic, PX4 ULog, ArduPilot DataFlash, MAVLink tlog, ROS 2 bags and echoloop recordings.
Multi-vehicle logs (swarm traces, recordings, tlogs of several systems) need ``vehicle_id``.

The vehicle's time axis starts at the file's first ``t`` (of the segment flown, when position
jumps split the log): sim time 0 is mapped to it. The run pace is the server clock's real-time
factor ``rate``, or as fast as the CPU allows with ``clock_mode="fast"``
(:func:`build_replay_launch`); echoes, the forest tiles along the path
(built ahead of the vehicle) and ``/forest/points`` are computed in a worker process, so they
never hold the interpreter whose tick loop keeps that pace (the server reports the pace it
kept, ``rate_achieved``).
"""

from __future__ import annotations

import math
import threading
import time
from collections import deque
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import numpy as np

from hil_bridge.bus.faults import Faults
from hil_bridge.files.config import load_yaml
from sim_core.config import ConfigError, from_dict
from sim_core.rng import derive_rng, make_rng
from sim_core.scene import SceneSpec

__all__ = ["DEFAULT_REPLAY_SCENE", "Pinger", "build_replay_launch"]

#: Scene used when none is given: the seed 000 forest (tiled) around the replayed vehicle.
DEFAULT_REPLAY_SCENE: dict[str, Any] = {
    "forest": {"preset": "seed000-fig5d", "tiled": True},
}


#: ``next_ns`` of a lockstep head's last ping (``max_pings``): no later ping is due
NEVER_NS = 2**62


class Pinger:
    """Launchable node that pings ``/sonar/<sonar_id>/ping`` at ``rate_hz``, of the wall clock
    or, with ``clock: sim``, of the bus's sim time (``/clock``: the same pings a sim second at
    any ``--speed``, and none while the sim stands still).

    ``Pinger(name, *, bus, sonar_id=0, rate_hz=10.0, az=0.0, el=0.0, beamwidth=0.7,
    beamwidth_range=None, seed=0, max_pings=None, sonar_ids=None, clock="wall")``. With
    ``beamwidth_range = [lo, hi]`` each ping's beamwidth is drawn from U(lo, hi) (seed 000 used
    [30°, 65°]). Pings are stamped with the bus's sim time (``/clock``) when sent, their
    emission. It subscribes to the echoes and reports how many came back, with ping -> echo
    latency percentiles (ms).
    ``sonar_ids``: ping several sonars from one node (one clock subscription for all), each
    at ``rate_hz`` from its own phase, drawn uniformly over a period (``seed``); ``max_pings``
    then counts per sonar. ``failure()`` says why it failed (its ping thread or an echo
    callback raised), or None.

    ``lockstep: true`` (with ``clock: sim``; a fast replay's pinger): a sonar head of a
    lockstep server (its ``sonar_heads``). Pings are due on the sim grid ``k / rate_hz`` from
    sim time 0, each stamped with its due time and the next one's (``next_ns``), so the server
    holds at each due tick until the ping is there; before the next ping it waits for the
    echoes of the last (at most ``echo_wait_s`` wall seconds, then counted in
    ``echo_waits_timed_out``), so a replay runs as fast as the echoes are computed and every
    ping is answered. ``finished()`` is then whether no echo is outstanding.
    """

    def __init__(
        self,
        name: str,
        *,
        bus: str,
        sonar_id: int = 0,
        rate_hz: float = 10.0,
        az: float = 0.0,
        el: float = 0.0,
        beamwidth: float = 0.7,
        beamwidth_range: tuple[float, float] | list[float] | None = None,
        seed: int = 0,
        max_pings: int | None = None,
        sonar_ids: list[int] | tuple[int, ...] | None = None,
        clock: str = "wall",
        lockstep: bool = False,
        echo_wait_s: float = 5.0,
    ) -> None:
        if clock not in ("wall", "sim"):
            raise ValueError(f"clock: expected 'wall' or 'sim', got {clock!r}")
        if lockstep and clock != "sim":
            raise ValueError("lockstep: a lockstep sonar head pings on sim time (clock: sim)")
        if not echo_wait_s > 0:
            raise ValueError(f"echo_wait_s: expected > 0 s, got {echo_wait_s}")
        if not rate_hz > 0:
            raise ValueError(f"rate_hz: expected > 0, got {rate_hz}")
        if not 0 < beamwidth < np.pi:
            raise ValueError(f"beamwidth: expected 0 < beamwidth < pi rad, got {beamwidth}")
        if beamwidth_range is not None:
            lo, hi = (float(v) for v in beamwidth_range)
            if not 0 < lo <= hi < np.pi:
                raise ValueError(f"beamwidth_range: expected 0 < lo <= hi < pi, got {[lo, hi]}")
        if max_pings is not None and max_pings < 1:
            raise ValueError(f"max_pings: expected >= 1, got {max_pings}")
        ids = [int(sonar_id)] if sonar_ids is None else [int(i) for i in sonar_ids]
        if not ids or len(set(ids)) != len(ids) or min(ids) < 0:
            raise ValueError(f"sonar_ids: expected distinct ids >= 0, got {sonar_ids}")
        self.name = name
        self.bus = bus
        self.sonar_ids = tuple(ids)
        self.sonar_id = ids[0]
        self.period_s = 1.0 / float(rate_hz)
        self.sim_clock = clock == "sim"
        self.lockstep = bool(lockstep)
        self.echo_wait_s = float(echo_wait_s)
        self.az, self.el, self.beamwidth = float(az), float(el), float(beamwidth)
        self.beamwidth_range = None if beamwidth_range is None else (lo, hi)
        self.max_pings = max_pings
        self._rng = make_rng(seed)
        self._seed = seed
        self._lock = threading.Lock()
        self._echoed = threading.Condition(self._lock)
        self._outstanding: set[tuple[int, int]] = set()
        self._ticked = threading.Event()
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self._node: Any = None
        self._pubs: dict[int, Any] = {}
        self._sent: dict[tuple[int, int], int] = {}
        self._c = {"pings_sent": 0, "echoes_received": 0, "echoes_unmatched": 0,
                   "echo_samples": 0, "echo_waits_timed_out": 0}
        self._latency_ms: deque[float] = deque(maxlen=10000)
        self._last_echo: Any = None
        #: what went wrong: its ping thread, its node's callbacks
        self.faults = Faults(name)

    def start(self) -> None:
        from hil_bridge.bus.clock import SimClock
        from hil_bridge.bus.messages import SonarEcho, SonarPing
        from hil_bridge.bus.node import Node
        from hil_bridge.bus.qos import SENSOR

        self._node = Node(self.name, bus=self.bus, clock=SimClock("lockstep"),
                          faults=self.faults)
        self._node.follow_bus_clock()
        if self.lockstep:  # its first ping waits for the server's first tick
            from hil_bridge.bus.messages import Clock
            from hil_bridge.bus.qos import LATCHED

            self._node.create_subscription(Clock, "/clock", lambda _m: self._ticked.set(),
                                           qos=LATCHED)
        self._pubs = {
            i: self._node.create_publisher(SonarPing, f"/sonar/{i}/ping", qos=SENSOR)
            for i in self.sonar_ids
        }
        for i in self.sonar_ids:
            self._node.create_subscription(SonarEcho, f"/sonar/{i}/echo", self._on_echo,
                                           qos=SENSOR)
        self._node.start()
        self._thread = threading.Thread(target=self.faults.guarded("ping loop", self._loop),
                                        name=f"{self.name}-ping", daemon=True)
        self._thread.start()

    def stop(self) -> None:
        self._stop.set()
        if self._thread is not None:
            self._thread.join()
            self._thread = None
        if self._node is not None:
            self._node.stop()
            self._node = None

    def stats(self) -> dict[str, Any]:
        from hil_bridge.bus.stats import percentiles

        with self._lock:
            out: dict[str, Any] = dict(self._c)
            out["ping_echo_ms"] = percentiles(list(self._latency_ms))
        return out

    def failure(self, *, final: bool = False) -> str | None:
        """Why the pinger failed (:mod:`hil_bridge.bus.faults`), or None."""
        return self.faults.failure(final=final)

    def finished(self) -> bool | None:
        """A lockstep head: whether every ping sent has its echo; else None (no end)."""
        if not self.lockstep:
            return None
        with self._lock:
            return not self._outstanding

    @property
    def last_echo(self) -> Any:
        """The most recent :class:`~hil_bridge.bus.messages.SonarEcho` received (or None)."""
        with self._lock:
            return self._last_echo

    def _loop(self) -> None:
        from hil_bridge.bus.messages import SonarPing

        n = len(self.sonar_ids)
        phases = [0.0] if n == 1 else (
            derive_rng(self._seed, "phase").uniform(0.0, self.period_s, n).tolist())
        start = 0.0 if self.lockstep else (
            self._node.now_ns() / 1e9 if self.sim_clock else time.monotonic())
        due = [start + ph for ph in phases]
        seqs = [0] * n
        sent = [0] * n
        while self.lockstep and not self._ticked.wait(0.1):
            if self._stop.is_set():
                return
        while not self._stop.is_set():
            k = min(range(n), key=due.__getitem__)
            if self.max_pings is not None and sent[k] >= self.max_pings:
                due[k] = math.inf
                if all(math.isinf(d) for d in due):
                    break
                continue
            if (self.lockstep and self._wait_for_echoes()) or self._wait_until(due[k]):
                break
            sonar, seq = self.sonar_ids[k], seqs[k]
            bw = self.beamwidth
            if self.beamwidth_range is not None:
                bw = float(self._rng.uniform(*self.beamwidth_range))
            with self._lock:
                self._sent[(sonar, seq)] = time.monotonic_ns()
                if len(self._sent) > 4096:
                    self._sent.pop(next(iter(self._sent)))
                self._c["pings_sent"] += 1
                if self.lockstep:
                    self._outstanding.add((sonar, seq))
            stamp, next_ns = self._node.now_ns(), -1
            if self.lockstep:  # the last of max_pings holds the server at no later tick
                last = self.max_pings is not None and sent[k] + 1 >= self.max_pings
                stamp = round(due[k] * 1e9)
                next_ns = NEVER_NS if last else round((due[k] + self.period_s) * 1e9)
            self._pubs[sonar].publish(SonarPing(
                stamp_ns=stamp, ping_seq=seq, az=self.az, el=self.el,
                beamwidth=bw, encoding=2, sonar_id=sonar, next_ns=next_ns,
            ))
            seqs[k] = (seq + 1) % 65536
            sent[k] += 1
            due[k] = start + phases[k] + sent[k] * self.period_s  # on the grid, no drift

    def _wait_for_echoes(self) -> bool:
        """Until every ping sent has its echo, or ``echo_wait_s``; True if stopped."""
        deadline = time.monotonic() + self.echo_wait_s
        with self._echoed:
            while self._outstanding and not self._stop.is_set():
                left = deadline - time.monotonic()
                if left <= 0:
                    self._c["echo_waits_timed_out"] += 1
                    self._outstanding.clear()
                    break
                self._echoed.wait(min(left, 0.1))
        return self._stop.is_set()

    def _wait_until(self, due_s: float) -> bool:
        """Wait until ``due_s`` (wall, or sim seconds with ``clock: sim``); True if stopped."""
        if not self.sim_clock:
            return self._stop.wait(max(0.0, due_s - time.monotonic()))
        due_ns = round(due_s * 1e9)
        while not self._node.clock.sleep_until(due_ns, timeout=0.1):
            if self._stop.is_set():
                return True
        return self._stop.is_set()

    def _on_echo(self, msg: Any) -> None:
        now = time.monotonic_ns()
        with self._lock:
            t_ping = self._sent.pop((int(msg.sonar_id), int(msg.ping_seq)), None)
            if t_ping is None:
                self._c["echoes_unmatched"] += 1
            else:
                self._latency_ms.append((now - t_ping) / 1e6)
            if self._outstanding:
                self._outstanding.discard((int(msg.sonar_id), int(msg.ping_seq)))
                self._echoed.notify_all()
            self._c["echoes_received"] += 1
            self._c["echo_samples"] += int(msg.samples.shape[-1])
            self._last_echo = msg


def build_replay_launch(
    trajectory: str | Path,
    *,
    vehicle_id: int | None = None,
    scene: str | Path | Mapping[str, Any] | None = None,
    sonar_rate_hz: float | None = 10.0,
    sonar: Mapping[str, Any] | None = None,
    pinger: Mapping[str, Any] | None = None,
    rate: float = 1.0,
    state_rate_hz: float = 50.0,
    bus: str | None = None,
    clock_mode: str = "realtime",
    topic: str | None = None,
    origin: tuple[float, float, float] | None = None,
    max_speed_mps: float = 150.0,
    segment: int | None = None,
    until_s: float | None = None,
) -> tuple[dict[str, Any], float]:
    """Launch mapping (for :func:`hil_bridge.launch.runner.run`) replaying ``trajectory``, and its
    length.

    ``scene``: a scene YAML path or mapping (validated) whose ``forest`` and ``seed`` are used,
    the rest is replaced; default :data:`DEFAULT_REPLAY_SCENE`. The replayed vehicle gets id
    ``vehicle_id`` (default 0, or the file's id) and sonar 0 is mounted on it with ``sonar``
    settings (``fidelity``, ``echo`` overrides). ``sonar_rate_hz`` None: no built-in pinger;
    ``pinger``: extra :class:`Pinger` params (default beamwidths U(30°, 65°) as seed 000).
    The server stops ticking at the trajectory's end (the vehicle rests at its last pose) and is
    then ``finished`` once every ping has its echo: run the launch with ``until_finished`` to
    end there. ``topic``, ``origin``, ``max_speed_mps`` and ``segment`` go to the log reader
    (:func:`hil_bridge.recording.logs.read_log`). ``until_s``: replay only the first
    ``until_s`` sim seconds of the trajectory (default all of it).

    ``clock_mode`` ``fast``: every node runs on the sim clock, as fast as the CPU allows. The
    server's clock is ``fast`` without a pinger (its echoes, should another node ping, then
    computed in a thread of its own: ``echo_worker: thread``, no worker process to start);
    with one it is ``lockstep`` with the pinger
    as its sonar head (``sonar_heads``, the pinger's ``lockstep``): pings are due every
    ``1 / sonar_rate_hz`` sim seconds from sim time 0, the server holds at each due tick until
    the ping came, and the pinger waits for each echo before its next ping, so every ping is
    answered at its pose however fast the replay goes. ``realtime``: the server paces sim time
    at ``rate`` and the pinger pings on the wall clock.
    Returns ``(launch mapping, the replayed duration in wall seconds at rate)``.
    """
    from hil_bridge.recording.logs import load_trajectory

    traj = load_trajectory(trajectory, vehicle_id=vehicle_id, topic=topic, origin=origin,
                           max_speed_mps=max_speed_mps, segment=segment)
    source: Mapping[str, Any]
    if scene is None:
        source = DEFAULT_REPLAY_SCENE
    elif isinstance(scene, Mapping):
        source = scene
    else:
        loaded = load_yaml(scene)
        if loaded is None:
            loaded = {}
        if not isinstance(loaded, Mapping):
            raise ConfigError(f"{scene}: expected a scene mapping, got {loaded!r}")
        source = loaded
    try:
        from_dict(SceneSpec, source, path="scene")
    except ConfigError as exc:
        raise ConfigError(f"{scene}: {exc}") from None
    base: dict[str, Any] = {k: source[k] for k in ("seed", "forest") if k in source}
    vid = 0 if vehicle_id is None else int(vehicle_id)
    path: dict[str, Any] = {"kind": "file", "file": str(trajectory), "loop": False}
    if vehicle_id is not None:
        path["id"] = int(vehicle_id)
    if topic is not None:
        path["topic"] = topic
    if origin is not None:
        path["origin"] = [float(v) for v in origin]
    path["max_speed_mps"] = float(max_speed_mps)
    if segment is not None:
        path["segment"] = int(segment)
    base["vehicles"] = [{"id": vid, "path": path, "time_offset_s": -float(traj.t[0])}]
    if "forest" in base:
        base["sonars"] = [{"id": 0, "mount": vid, **dict(sonar or {})}]
    base["state_rate_hz"] = state_rate_hz
    pinged = sonar_rate_hz is not None and "forest" in base
    heads = clock_mode == "fast" and pinged
    base["clock"] = {"mode": "lockstep" if heads else clock_mode, "rate": rate}
    if until_s is not None and not until_s > 0:
        raise ValueError(f"until_s: expected sim seconds > 0, got {until_s}")
    length = traj.duration if until_s is None else min(traj.duration, float(until_s))
    # echoes, the tiles along the path and /forest/points are computed in a worker process,
    # never holding the interpreter the tick loop paces the replay with; a fast replay without
    # its pinger has no pace to keep and nothing to echo: no worker to start (and wait for)
    worker = "thread" if clock_mode == "fast" and not heads else "process"
    server: dict[str, Any] = {"scene": base, "stop_after_s": length, "echo_worker": worker}
    if heads:
        server["sonar_heads"] = [0]
    nodes: list[dict[str, Any]] = [
        {"name": "server", "entry": "hil_bridge.server:SimServer", "params": server},
    ]
    if pinged and sonar_rate_hz is not None:
        ping_params: dict[str, Any] = {"beamwidth_range": [math.radians(30), math.radians(65)]}
        if heads:
            ping_params.update({"clock": "sim", "lockstep": True})
        ping_params.update(dict(pinger or {}))
        if "beamwidth" in ping_params:
            ping_params.pop("beamwidth_range")
        nodes.append({
            "name": "pinger", "entry": "hil_bridge.replay:Pinger",
            "params": {"sonar_id": 0, "rate_hz": float(sonar_rate_hz), **ping_params},
        })
    launch: dict[str, Any] = {"nodes": nodes}
    if bus is not None:
        launch["bus"] = bus
    return launch, length / rate
