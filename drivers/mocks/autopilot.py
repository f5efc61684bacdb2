"""A glider autopilot emulator on a python-can bus: :class:`MockAutopilot`.

It is the other end of :class:`drivers.can.adapter.AutopilotAdapter` and speaks only the CAN
profile (``drivers/can/glider.dbc``, docs/can.md): for each node id it flies it assembles the
glider's state samples (GLIDER_STATE_POS, QUAT, RATES, MOTION: only frames of one sample, by
:class:`drivers.can.samples.SampleAssembler`; a torn sample is dropped and counted) and its
neighbour list (NEIGHBOR_POS + NEIGHBOR_MOTION, positions relative to the glider), runs a
controller at its control rate and sends AUTOPILOT_CMD; it sends AUTOPILOT_HEARTBEAT at
``heartbeat_hz`` for every node.

Controllers:

* ``unified`` / ``baseline`` — seed 002's Boids (``sim_core.soaring.controller_command``) on the
  glider's own state and its neighbours, commands clipped to the law's bank and speed envelope
  (the glider applies the same limits, so flying these commands reproduces the swarm). The
  default control rate is ``1 / law.dt``, the rate the seed's controller is tuned for.
* ``path`` — :class:`PathFollower`, pure pursuit along a closed route of waypoints (by default
  a figure-eight like the seed 000 "8" route) at a fixed airspeed, for a low-flying sonar
  vehicle; default control rate 10 Hz.

A node without fresh state (older than ``state_timeout_s``), or whose glider is dead, is not
commanded; its heartbeat says ``NO_STATE``.

**Lockstep** (docs/can.md): a state sample whose GLIDER_STATE_POS has ``lockstep = 1`` is
answered at once, on the receive thread, with one AUTOPILOT_CMD (``answer = 1``,
``answer_counter`` = the sample's ``state_counter``) computed from that sample and the
neighbour list sent with it: the autopilot acts on sim time, one command per state step,
whatever the wall clock does. Its control timer leaves such nodes alone; a node whose latest
sample is not a lockstep one is commanded at ``rate_hz`` again.

Launchable (``Cls(name, *, bus, **params)``): the ``bus`` argument is part of the contract; a
device mock has no use for the echoloop bus. An exception in its receive or control loop is
counted (``loop_errors``) and reported to its ``faults``: ``failure()`` names it.
"""

from __future__ import annotations

import math
import threading
import time
from collections import Counter
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from drivers.can.bus import CanBusConfig, CanLink
from drivers.can.codec import MAX_NODE_ID, DecodedFrame, GliderCanCodec
from drivers.can.samples import STATE_FRAMES, SampleAssembler
from hil_bridge.bus.faults import Faults
from hil_bridge.errors import CodecError
from hil_bridge.files.soaring import load_law
from hil_bridge.outputs import check_output
from sim_core.soaring.boids import GliderObs, controller_command
from sim_core.soaring.law import Law

__all__ = [
    "AP_MODES",
    "CONTROLLER_CODES",
    "PATH_RATE_HZ",
    "MockAutopilot",
    "NodeView",
    "PathFollower",
    "ProfileReceiver",
    "figure_eight_waypoints",
]

#: Default control rate of the path follower, Hz.
PATH_RATE_HZ = 10.0
#: ap_mode values of AUTOPILOT_HEARTBEAT (the DBC's value table).
AP_MODES = {"INIT": 0, "AUTO": 1, "NO_STATE": 2, "FAULT": 3}
#: ap_controller values of AUTOPILOT_HEARTBEAT.
CONTROLLER_CODES = {"unified": 0, "baseline": 1, "path": 2}

F8 = NDArray[np.float64]
_NO_OBS = GliderObs(x=0.0, y=0.0, z=0.0, heading=0.0, speed=0.0, vz=0.0)


def _wrap(angle: F8) -> F8:
    return np.asarray((angle + np.pi) % (2.0 * np.pi) - np.pi, dtype=np.float64)


def figure_eight_waypoints(
    *, center: Sequence[float] = (0.0, 0.0), half_length_m: float = 60.0, n: int = 64
) -> F8:
    """A figure-eight route (lemniscate of Gerono), shape (n, 2) metres ENU.

    x = c_x + L sin t, y = c_y + (L/2) sin 2t over t in [0, 2 pi): two lobes of width L crossing
    at the centre, the shape of the seed 000 "8" route.
    """
    if n < 4:
        raise ValueError(f"n must be >= 4 waypoints, got {n}")
    if not half_length_m > 0:
        raise ValueError(f"half_length_m must be > 0 m, got {half_length_m}")
    t = np.linspace(0.0, 2.0 * np.pi, n, endpoint=False)
    return np.stack(
        [center[0] + half_length_m * np.sin(t), center[1] + 0.5 * half_length_m * np.sin(2 * t)],
        axis=1,
    )


class PathFollower:
    """Pure pursuit along a closed polyline for N vehicles (N == 1 is the single case).

    Each vehicle keeps a target waypoint index. Every call advances it while the target is
    closer than ``lookahead_m``, then commands the bank of the circular arc through the target
    tangent to the current heading: with heading error eta and distance d to the target,
    turn rate = 2 v sin(eta) / d, bank = atan(v * turn rate / g), clipped to +-``bank_max_rad``
    (positive bank turns towards increasing heading). Airspeed is ``airspeed_mps``.
    """

    def __init__(
        self,
        waypoints: ArrayLike,
        *,
        n_vehicles: int = 1,
        lookahead_m: float = 25.0,
        airspeed_mps: float = 10.0,
        bank_max_rad: float = math.radians(30.0),
        g: float = 9.81,
    ) -> None:
        wp = np.asarray(waypoints, dtype=np.float64)
        if wp.ndim != 2 or wp.shape[1] != 2 or wp.shape[0] < 2:
            raise ValueError(f"waypoints must have shape (M >= 2, 2), got {wp.shape}")
        if not np.all(np.isfinite(wp)):
            raise ValueError("waypoints must be finite")
        if not lookahead_m > 0:
            raise ValueError(f"lookahead_m must be > 0 m, got {lookahead_m}")
        if not airspeed_mps > 0:
            raise ValueError(f"airspeed_mps must be > 0 m/s, got {airspeed_mps}")
        if not 0 < bank_max_rad < math.pi / 2:
            raise ValueError(f"bank_max_rad must be in (0, pi/2), got {bank_max_rad}")
        self.waypoints = wp
        self.lookahead_m = float(lookahead_m)
        self.airspeed_mps = float(airspeed_mps)
        self.bank_max_rad = float(bank_max_rad)
        self.g = float(g)
        self._index: NDArray[np.intp] | None = None
        self._n = int(n_vehicles)

    @property
    def target_index(self) -> NDArray[np.intp] | None:
        """Current target waypoint per vehicle, shape (N,) (-1 until a vehicle is first
        active), None before the first call."""
        return self._index

    def command(
        self, xy: ArrayLike, heading: ArrayLike, speed: ArrayLike, active: ArrayLike = True
    ) -> tuple[F8, F8]:
        """(bank rad, airspeed m/s), each shape (N,), for positions ``xy`` (N, 2) m, heading
        (N,) rad from +x and airspeed (N,) m/s. Only ``active`` vehicles (bool, (N,) or
        scalar) advance along the route; the others' outputs are meaningless (no state)."""
        p = np.asarray(xy, dtype=np.float64).reshape(self._n, 2)
        psi = np.asarray(heading, dtype=np.float64).reshape(self._n)
        v = np.maximum(np.asarray(speed, dtype=np.float64).reshape(self._n), 0.1)
        act = np.broadcast_to(np.asarray(active, dtype=bool), (self._n,))
        wp = self.waypoints
        m = wp.shape[0]
        nearest = np.argmin(((p[:, None, :] - wp[None, :, :]) ** 2).sum(axis=2), axis=1)
        if self._index is None:
            self._index = np.full(self._n, -1, dtype=np.intp)
        idx = np.where(act & (self._index < 0), nearest, self._index).astype(np.intp)
        for _ in range(m):
            dist = np.hypot(*(wp[np.maximum(idx, 0)] - p).T)
            near = act & (dist < self.lookahead_m)
            if not near.any():
                break
            idx = np.where(near, (idx + 1) % m, idx)
        self._index = idx
        idx = np.maximum(idx, 0)
        delta = wp[idx] - p
        dist = np.maximum(np.hypot(delta[:, 0], delta[:, 1]), 1e-6)
        eta = _wrap(np.arctan2(delta[:, 1], delta[:, 0]) - psi)
        turn_rate = 2.0 * v * np.sin(eta) / dist
        bank = np.clip(np.arctan(v * turn_rate / self.g), -self.bank_max_rad, self.bank_max_rad)
        return bank, np.full(self._n, self.airspeed_mps)


@dataclass(slots=True)
class NodeView:
    """What the autopilot knows about one node's glider (a snapshot; monotonic times in s)."""

    own: GliderObs | None = None
    alive: bool = False
    state_counter: int = -1
    state_time: float = -math.inf
    neighbours: F8 = field(default_factory=lambda: np.zeros((0, 6)))
    neighbour_set: int = -1
    bridge_time: float = -math.inf
    bridge_mode: int = 0
    cmd_state: int = 0
    sim_time_ms: int = 0
    lockstep: bool = False
    attitude: F8 = field(default_factory=lambda: np.full(4, np.nan))
    body_rates: F8 = field(default_factory=lambda: np.full(3, np.nan))


class ProfileReceiver:
    """Assembles bridge → autopilot frames into one :class:`NodeView` per node (thread-safe).

    State: the frames of one sample (GLIDER_STATE_POS, QUAT and RATES when sent, MOTION) go
    through a :class:`SampleAssembler`; a whole sample replaces the view's state, attitude and
    body rates at once (NaN attitude for a sample sent without one), a torn one leaves the view
    as it was (``samples_torn``, ``samples_unverified``). Neighbours: NEIGHBOR_POS/
    NEIGHBOR_MOTION pairs of slots 0..nb_count-1 sharing one ``nb_set`` form a list; positions
    are made absolute with the glider's latest position (its latest POS frame). A
    list with a missing or foreign frame is discarded and counted (``nb_incomplete``); the
    previous list stays.
    """

    def __init__(self, nodes: Sequence[int]) -> None:
        self._lock = threading.Lock()
        self._views = {int(n): NodeView() for n in nodes}
        self._pos: dict[int, tuple[float, float, float]] = {}
        self._samples = SampleAssembler()
        self._nb_pos: dict[int, dict[int, tuple[float, float, float]]] = {n: {} for n in nodes}
        self._nb_rows: dict[int, dict[int, list[float]]] = {n: {} for n in nodes}
        self._nb_set: dict[int, int] = {}
        self.counters: Counter[str] = Counter()

    def feed(self, frame: DecodedFrame, now: float) -> bool:
        """Take one decoded frame received at monotonic time ``now``; False if not for us."""
        node = frame.node_id
        if node not in self._views:
            return False
        s = frame.signals
        with self._lock:
            view = self._views[node]
            if frame.name in STATE_FRAMES:
                if frame.name == "GLIDER_STATE_POS":  # the reference of neighbour positions
                    self._pos[node] = (s["x_m"], s["y_m"], s["z_m"])
                sample = self._samples.feed(frame)
                if sample is not None:
                    view.own = GliderObs(x=sample.x, y=sample.y, z=sample.z,
                                         heading=sample.heading, speed=sample.airspeed,
                                         vz=sample.vz)
                    view.alive, view.lockstep = sample.alive, sample.lockstep
                    view.state_counter, view.state_time = sample.counter, now
                    view.attitude = np.array(sample.attitude or (np.nan,) * 4)
                    view.body_rates = np.array(sample.body_rates or (np.nan,) * 3)
            elif frame.name == "NEIGHBOR_POS":
                slot = int(s["nb_slot"])
                if slot == 0:
                    self._nb_pos[node].clear()
                self._nb_pos[node][slot] = (s["nb_dx_m"], s["nb_dy_m"], s["nb_dz_m"])
            elif frame.name == "NEIGHBOR_MOTION":
                self._feed_nb_motion(node, view, s)
            elif frame.name == "BRIDGE_HEARTBEAT":
                view.bridge_time = now
                view.bridge_mode = int(s["bridge_mode"])
                view.cmd_state = int(s["cmd_state"])
                view.sim_time_ms = int(s["sim_time_ms"])
                self.counters["bridge_heartbeats"] += 1
            else:
                return False
        return True

    def _feed_nb_motion(self, node: int, view: NodeView, s: Mapping[str, float]) -> None:
        count, slot, nb_set = int(s["nb_count"]), int(s["nb_slot"]), int(s["nb_set"])
        if count == 0:
            view.neighbours = np.zeros((0, 6))
            view.neighbour_set = nb_set
            self._nb_rows[node].clear()
            self.counters["nb_sets"] += 1
            return
        rows = self._nb_rows[node]
        if self._nb_set.get(node) != nb_set or slot == 0:
            rows.clear()
            self._nb_set[node] = nb_set
        rel = self._nb_pos[node].get(slot)
        own = self._pos.get(node)
        if rel is None or own is None or slot >= count:
            self.counters["nb_incomplete"] += 1
            rows.clear()
            return
        rows[slot] = [
            own[0] + rel[0], own[1] + rel[1], own[2] + rel[2],
            s["nb_heading_rad"], s["nb_airspeed_mps"], s["nb_vz_mps"],
        ]
        if slot == count - 1:
            if len(rows) == count:
                view.neighbours = np.array([rows[i] for i in range(count)], dtype=np.float64)
                view.neighbour_set = nb_set
                self.counters["nb_sets"] += 1
            else:
                self.counters["nb_incomplete"] += 1
            rows.clear()

    def counts(self) -> dict[str, int]:
        """Snapshot of the assembly counters (the state samples' too)."""
        with self._lock:
            return dict(self.counters) | dict(self._samples.counters)

    def view(self, node: int) -> NodeView:
        """A copy of the current view of ``node``."""
        with self._lock:
            v = self._views[node]
            return NodeView(
                own=v.own, alive=v.alive, state_counter=v.state_counter, state_time=v.state_time,
                neighbours=v.neighbours.copy(), neighbour_set=v.neighbour_set,
                bridge_time=v.bridge_time, bridge_mode=v.bridge_mode, cmd_state=v.cmd_state,
                sim_time_ms=v.sim_time_ms, lockstep=v.lockstep, attitude=v.attitude.copy(),
                body_rates=v.body_rates.copy(),
            )


def _parse_nodes(gliders: Any) -> tuple[int, ...]:
    if isinstance(gliders, int) and not isinstance(gliders, bool):
        gliders = (gliders,)
    if isinstance(gliders, str):
        gliders = [g for g in gliders.split(",") if g.strip()]
    try:
        nodes = tuple(int(g) for g in gliders)
    except (TypeError, ValueError):
        raise ValueError(
            f"gliders: expected node ids 0..{MAX_NODE_ID} (list or '0,1,2'), got {gliders!r}"
        ) from None
    if not nodes or len(set(nodes)) != len(nodes):
        raise ValueError(f"gliders: expected unique node ids, got {list(nodes)}")
    bad = [n for n in nodes if not 0 <= n <= MAX_NODE_ID]
    if bad:
        raise ValueError(f"gliders: node ids must be in 0..{MAX_NODE_ID}, got {bad}")
    return nodes


def _load_law(law: str | Path | Mapping[str, Any] | Law | None) -> Law:
    if law is None:
        return Law()
    if isinstance(law, Law):
        return law
    if isinstance(law, Mapping):
        return Law.from_dict(law)
    return load_law(law)


class MockAutopilot:
    """Autopilot emulator for node ids ``gliders`` on a python-can bus (module docstring).

    Params: ``interface``, ``channel``, ``bitrate`` (python-can bus), ``gliders`` (node ids it
    flies), ``controller`` (unified | baseline | path), ``law`` (law YAML path or mapping;
    default the packaged seed law), ``rate_hz`` (control rate; default ``1 / law.dt`` for Boids,
    10 Hz for ``path``), ``heartbeat_hz``, ``state_timeout_s``, ``waypoints`` ((M, 2) route for
    ``path``; default :func:`figure_eight_waypoints`), ``path_airspeed_mps``, ``lookahead_m``,
    ``bank_max_rad`` (path follower), ``can_log`` (candump log of its own traffic; ``overwrite``
replaces an existing one), ``faults``.
    """

    def __init__(
        self,
        name: str = "mock_autopilot",
        *,
        bus: str = "",
        interface: str = "virtual",
        channel: str | int | None = None,
        bitrate: int | None = None,
        gliders: Any = (0,),
        controller: str = "unified",
        law: str | Path | Mapping[str, Any] | Law | None = None,
        rate_hz: float | None = None,
        heartbeat_hz: float = 10.0,
        state_timeout_s: float = 1.0,
        waypoints: ArrayLike | None = None,
        path_airspeed_mps: float = 10.0,
        lookahead_m: float = 25.0,
        bank_max_rad: float = math.radians(30.0),
        can_log: str | Path | None = None,
        faults: Mapping[str, Any] | None = None,
        overwrite: bool = False,
    ) -> None:
        if controller not in CONTROLLER_CODES:
            raise ValueError(
                f"controller: expected one of {sorted(CONTROLLER_CODES)}, got {controller!r}"
            )
        self.name = name
        self.bus_url = bus
        self.nodes = _parse_nodes(gliders)
        self.controller = controller
        self.law = _load_law(law)
        if rate_hz is None:
            rate_hz = PATH_RATE_HZ if controller == "path" else 1.0 / self.law.dt
        self.rate_hz = float(rate_hz)
        if not self.rate_hz > 0:
            raise ValueError(f"rate_hz must be > 0, got {rate_hz}")
        if not heartbeat_hz > 0:
            raise ValueError(f"heartbeat_hz must be > 0, got {heartbeat_hz}")
        if not state_timeout_s > 0:
            raise ValueError(f"state_timeout_s must be > 0 s, got {state_timeout_s}")
        self.heartbeat_hz = float(heartbeat_hz)
        self.state_timeout_s = float(state_timeout_s)
        self.bus_config = CanBusConfig.from_params(
            interface=interface, channel=channel, bitrate=bitrate, faults=dict(faults or {}) or None
        )
        self.can_log = can_log
        self.overwrite = overwrite
        if can_log is not None:
            check_output(can_log, overwrite=overwrite)
        self.follower: PathFollower | None = None
        if controller == "path":
            route = figure_eight_waypoints() if waypoints is None else waypoints
            self.follower = PathFollower(
                route, n_vehicles=len(self.nodes), lookahead_m=lookahead_m,
                airspeed_mps=path_airspeed_mps, bank_max_rad=bank_max_rad, g=self.law.g,
            )
        self.codec = GliderCanCodec()
        self.receiver = ProfileReceiver(self.nodes)
        self._stop = threading.Event()
        self._threads: list[threading.Thread] = []
        self._link: CanLink | None = None
        self._counters: Counter[str] = Counter()
        self._count_lock = threading.Lock()
        self._cmd_counter = dict.fromkeys(self.nodes, 0)
        self._ctl_lock = threading.Lock()  # the control timer and lockstep answers share state
        self._hb_counter = 0
        self._last_cmd: dict[int, tuple[float, float]] = {}
        self._started = False
        #: what went wrong in its loops (:mod:`hil_bridge.bus.faults`)
        self.faults = Faults(name)

    # -- launchable contract ------------------------------------------------------------------
    def start(self) -> None:
        """Open the CAN bus and start the receive and control threads (non-blocking)."""
        if self._started:
            return
        self._started = True
        self._link = CanLink(self.bus_config, log_path=self.can_log, stop_event=self._stop,
                             overwrite=self.overwrite)
        for target, suffix in ((self._rx_loop, "rx"), (self._tx_loop, "tx")):
            t = threading.Thread(target=self.faults.guarded(f"{suffix} loop", target),
                                 name=f"{self.name}-{suffix}", daemon=True)
            t.start()
            self._threads.append(t)

    def stop(self) -> None:
        """Stop the threads and close the bus (idempotent)."""
        self._stop.set()
        for t in self._threads:
            t.join(timeout=5.0)
        self._threads.clear()
        if self._link is not None:
            self._link.close()

    def stats(self) -> dict[str, Any]:
        with self._count_lock:
            out: dict[str, Any] = dict(self._counters)
        out.update({f"rx_{k}": v for k, v in self.receiver.counts().items()})
        if self._link is not None:
            out.update({f"can_{k}": v for k, v in self._link.stats().items()})
            out["links"] = {"can": self._link.report()}
        sat = self.codec.saturation_counts()
        out["saturated_tx"] = sum(sat["tx"].values())
        out["saturated_rx"] = sum(sat["rx"].values())
        out["controller"] = self.controller
        out["nodes"] = list(self.nodes)
        return out

    def failure(self, *, final: bool = False) -> str | None:
        """Why the mock failed (an exception in its loops), or None."""
        return self.faults.failure(final=final)

    def last_command(self, node: int) -> tuple[float, float] | None:
        """The last (bank_cmd, airspeed_cmd) sent for ``node``, None if none yet."""
        with self._count_lock:
            return self._last_cmd.get(node)

    def _inc(self, key: str, n: int = 1) -> None:
        with self._count_lock:
            self._counters[key] += n

    # -- receive ------------------------------------------------------------------------------
    def _rx_loop(self) -> None:
        link = self._link
        if link is None:
            return
        while not self._stop.is_set():
            msg = link.recv(0.05)
            if msg is None:
                continue
            try:
                frame = self.codec.decode(msg)
            except CodecError:
                self._inc("rx_decode_errors")
                continue
            try:
                now = time.monotonic()
                if self.receiver.feed(frame, now):
                    self._inc("rx_frames_used")
                    if frame.name == "GLIDER_STATE_MOTION":
                        self._answer_lockstep(
                            frame.node_id, int(frame.signals["state_counter"]), now)
            except Exception as exc:
                self._inc("loop_errors")
                self.faults.report(f"assembling CAN frame {frame.name}", exc)

    # -- control ------------------------------------------------------------------------------
    def _tx_loop(self) -> None:
        now = time.monotonic()
        next_ctl, next_hb = now, now
        ctl_period, hb_period = 1.0 / self.rate_hz, 1.0 / self.heartbeat_hz
        while not self._stop.is_set():
            now = time.monotonic()
            try:
                if now >= next_ctl:
                    next_ctl = max(next_ctl + ctl_period, now)
                    self._control(now)
                if now >= next_hb:
                    next_hb = max(next_hb + hb_period, now)
                    self._heartbeat(now)
            except Exception as exc:
                self._inc("loop_errors")
                self.faults.report("control cycle", exc)
            self._stop.wait(max(0.0, min(next_ctl, next_hb) - time.monotonic()))

    def _fresh(self, view: NodeView, now: float) -> bool:
        return view.own is not None and view.alive and now - view.state_time <= self.state_timeout_s

    def _control(self, now: float) -> None:
        views = {n: self.receiver.view(n) for n in self.nodes}
        fresh = [n for n in self.nodes if self._fresh(views[n], now) and not views[n].lockstep]
        if not fresh:
            return
        with self._ctl_lock:
            for node, (bank, speed) in self._commands(views, fresh).items():
                self._send_cmd(node, bank, speed)

    def _answer_lockstep(self, node: int, counter: int, at: float) -> None:
        """Answer the lockstep sample ``counter`` of ``node`` whose MOTION arrived ``at``
        (module doc); a torn sample never reached the view and is not answered."""
        views = {n: self.receiver.view(n) for n in self.nodes}
        view = views.get(node)
        if (view is None or not view.lockstep or view.state_counter != counter
                or view.state_time != at):
            return
        if view.own is None or not view.alive:
            self._inc("lockstep_dead_samples")
            return
        with self._ctl_lock:
            command = self._commands(views, [node]).get(node)
            if command is not None:
                self._send_cmd(node, *command, answer_counter=counter)
                self._inc("lockstep_answers")

    def _send_cmd(
        self, node: int, bank: float, speed: float, *, answer_counter: int | None = None
    ) -> None:
        link = self._link
        if link is None:
            return
        self._cmd_counter[node] = (self._cmd_counter[node] + 1) % 256
        msg = self.codec.encode(
            "AUTOPILOT_CMD", node,
            {"bank_cmd_rad": bank, "airspeed_cmd_mps": speed,
             "cmd_counter": self._cmd_counter[node], "answer": int(answer_counter is not None),
             "answer_counter": answer_counter or 0},
        )
        if link.send(msg):
            self._inc("commands_sent")
            with self._count_lock:
                self._last_cmd[node] = (bank, speed)
        else:
            self._inc("commands_dropped")

    def _commands(
        self, views: Mapping[int, NodeView], fresh: Sequence[int]
    ) -> dict[int, tuple[float, float]]:
        out: dict[int, tuple[float, float]] = {}
        if self.follower is not None:
            obs = [views[n].own or _NO_OBS for n in self.nodes]
            xy = np.array([[o.x, o.y] for o in obs])
            psi = np.array([o.heading for o in obs])
            v = np.array([o.speed for o in obs])
            bank, speed = self.follower.command(
                xy, psi, v, active=np.array([n in fresh for n in self.nodes])
            )
            for i, n in enumerate(self.nodes):
                if n in fresh:
                    out[n] = (float(bank[i]), float(speed[i]))
            return out
        law = self.law
        for n in fresh:
            own = views[n].own
            if own is None:
                continue
            bank_i, speed_i = controller_command(
                own, views[n].neighbours, law,
                controller="baseline" if self.controller == "baseline" else "unified",
            )
            if not (math.isfinite(bank_i) and math.isfinite(speed_i)):
                self._inc("commands_nonfinite")
                continue
            out[n] = (
                min(max(bank_i, law.bankMin), law.bankMax),
                min(max(speed_i, law.forwardSpeedMin), law.forwardSpeedMax),
            )
        return out

    def _heartbeat(self, now: float) -> None:
        link = self._link
        if link is None:
            return
        self._hb_counter = (self._hb_counter + 1) % 256
        with self._count_lock:
            rx_errors = self._counters["rx_decode_errors"]
        for node in self.nodes:
            view = self.receiver.view(node)
            if view.own is None:
                mode, age_ms = AP_MODES["INIT"], 65535.0
            else:
                age_ms = min(65535.0, max(0.0, 1000.0 * (now - view.state_time)))
                mode = AP_MODES["AUTO"] if self._fresh(view, now) else AP_MODES["NO_STATE"]
            msg = self.codec.encode(
                "AUTOPILOT_HEARTBEAT", node,
                {"ap_counter": self._hb_counter, "ap_mode": mode,
                 "ap_controller": CONTROLLER_CODES[self.controller],
                 "ap_state_age_ms": age_ms, "ap_rx_errors": min(rx_errors, 65535)},
            )
            self._inc("heartbeats_sent" if link.send(msg) else "heartbeats_dropped")
