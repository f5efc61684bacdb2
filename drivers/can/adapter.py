"""The CAN autopilot adapter node: bus topics ⇄ the glider CAN profile (docs/can.md).

``AutopilotAdapter`` (launch node name ``autopilot``) bridges the echoloop bus and a python-can
bus carrying the "raw" profile of ``drivers/can/glider.dbc``:

* ``/glider/<id>/state`` → GLIDER_STATE_POS + GLIDER_STATE_QUAT + GLIDER_STATE_RATES +
  GLIDER_STATE_MOTION at ``state_rate_hz`` (the latest state, while it is younger than
  ``state_timeout_s`` of wall time; the attitude frames only for states that carry one,
  otherwise ``attitude_missing`` is counted; MOTION completes the sample). The gliders' samples
  are spread over the period rather than sent in one burst: the period has
  ``min(gliders, STATE_SLOTS)`` slots, and slot k sends the samples of the k-th, (k+n)-th, ...
  glider. A burst of every glider's sample (4 frames each) queues the last glider's sample
  behind the others on a real bus, and on the virtual bus wakes every receiving process at
  once, every period;
* ``/glider/<id>/neighbors`` → NEIGHBOR_POS + NEIGHBOR_MOTION pairs (positions relative to the
  state sent in the same tick, at most 15, nearest first), right after the state frames, when a
  new list has arrived and at most at ``neighbor_rate_hz``;
* AUTOPILOT_CMD (``bank_cmd_rad``, ``airspeed_cmd_mps``) → ``/glider/<id>/cmd`` at once;
* BRIDGE_HEARTBEAT out and AUTOPILOT_HEARTBEAT in, per node, at ``heartbeat_hz``.

The frames' signal values come from :mod:`drivers.can.bridge_frames`. Command supervision, per
glider at ``heartbeat_hz``, publishes the last command again (``HOLD``) or the failsafe command
(``FAILSAFE``) when commands stop: :mod:`drivers.can.supervision`.

**Lockstep** (``/clock`` says ``lockstep``; docs/can.md). The periodic state stream stops;
instead each new state *step* of a glider is sent at once as one lockstep sample:
GLIDER_STATE_POS with ``lockstep = 1``, the neighbour list of the same step (if one came), the
attitude frames, then GLIDER_STATE_MOTION, so the sample completes with its neighbours. The
autopilot answers it with one AUTOPILOT_CMD (``answer = 1``, ``answer_counter`` = the sample's
``state_counter``), which is published as ``/glider/<id>/cmd`` with the ``step`` and stamp of
the state it answers: the server waits for exactly that (:mod:`hil_bridge.server.lockstep`). A state
the server sends again (the same tick again: same step and stamp) while its answer is missing is
sent again. Command ages for HOLD and FAILSAFE are then measured in sim time, so a simulation
that waits for something else never ages the commands; held and failsafe commands carry the step
of the last command.

The control path has priority on the node's executor: state and ``/clock`` callbacks run before
neighbour lists, and malformed bus messages are dropped and counted before they queue
(:mod:`hil_bridge.bus.node`), so a flood on one topic cannot hold states back.

**One unit on the wire at a time.** Two threads send: the CAN transmit thread (the periodic
samples, the heartbeats) and the node's executor (lockstep samples). A lock is held for the
whole of each unit (a sample with its neighbour list, a heartbeat), sample counter included, so
at any switch of ``/clock`` between free-running and lockstep every sample's frames go out
together and in counter order (without it, a switch could send one sample's frames inside
another's, which the autopilot tears, docs/can.md); no free-running sample goes out once
lockstep has begun. :class:`~drivers.can.bus.CanLink` then sees one sender at a time.

Bus errors are absorbed by :class:`drivers.can.bus.CanLink` (retry with back-off, bus-off
recovery, re-open); no exception leaves the adapter's CAN threads
(:class:`drivers.can.endpoint.CanEndpoint`): anything unexpected is counted as ``loop_errors``
and reported to the node's ``faults`` (a failure of the node, naming the loop: the launch run
exits non-zero). Counters are in :meth:`stats` and published on ``/diagnostics`` (by the node,
every ``diagnostics_period_s``, without the latency percentiles: :meth:`counters`).
"""

from __future__ import annotations

import math
import threading
import time
from collections import Counter, deque
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from drivers.can.bridge_frames import (
    MAX_NEIGHBOURS,
    Frame,
    attitude_frames,
    bridge_mode,
    has_attitude,
    heartbeat_frame,
    motion_frame,
    neighbour_frames,
    pos_frame,
)
from drivers.can.bus import CanBusConfig
from drivers.can.codec import MAX_NODE_ID, DecodedFrame
from drivers.can.endpoint import CanEndpoint
from drivers.can.supervision import AP_FAULT, CMD_STATES, best_glide_speed, next_cmd_state
from hil_bridge.bus.clock import SimClock
from hil_bridge.bus.codec import Envelope
from hil_bridge.bus.messages import Clock, GliderCmd, GliderNeighbors, GliderState
from hil_bridge.bus.node import Node, Publisher
from hil_bridge.bus.qos import SENSOR, QoSProfile
from hil_bridge.bus.stats import percentiles
from hil_bridge.outputs import check_output

__all__ = ["AutopilotAdapter", "parse_gliders"]

_LINK_STATE_CODES = {"up": 0, "degraded": 1, "bus_off": 2, "down": 3, "closed": 4}
#: most slots a state period is split into (module docstring)
STATE_SLOTS = 10


def parse_gliders(gliders: Any) -> dict[int, int]:
    """Glider id → node id. A list gives node ids by position (``[3, 7]`` → {3: 0, 7: 1});
    a mapping gives them explicitly (``{3: 0, 7: 5}``). Node ids 0..15, unique."""
    if isinstance(gliders, int) and not isinstance(gliders, bool):
        gliders = [gliders]
    if isinstance(gliders, str):
        gliders = [x for x in gliders.split(",") if x.strip()]
    try:
        pairs = (
            [(int(g), int(n)) for g, n in gliders.items()]
            if isinstance(gliders, Mapping)
            else [(int(g), i) for i, g in enumerate(gliders)]
        )
    except (TypeError, ValueError):
        raise ValueError(
            "gliders: expected a list of glider ids or a mapping {glider_id: node_id}, "
            f"got {gliders!r}"
        ) from None
    mapping = dict(pairs)
    if not mapping:
        raise ValueError("gliders: expected at least one glider id")
    if len(mapping) != len(pairs):
        raise ValueError(f"gliders: duplicate glider id in {gliders!r}")
    nodes = list(mapping.values())
    if len(set(nodes)) != len(nodes):
        raise ValueError(f"gliders: node ids must be unique, got {mapping}")
    bad = [n for n in nodes if not 0 <= n <= MAX_NODE_ID]
    if bad:
        raise ValueError(f"gliders: node ids must be in 0..{MAX_NODE_ID}, got {bad}")
    return mapping


@dataclass(slots=True)
class _Glider:
    gid: int
    node: int
    state: GliderState | None = None
    state_wall: float = -math.inf
    neighbours: GliderNeighbors | None = None
    nb_new: bool = False
    nb_sent_wall: float = -math.inf
    state_counter: int = 0
    nb_set: int = 0
    last_cmd: tuple[float, float] | None = None
    cmd_wall: float = -math.inf
    cmd_counter: int | None = None
    ap_wall: float = -math.inf
    ap_mode: int = 0
    ap_counter: int | None = None
    ap_alive: bool = False
    cmd_state: int = 0
    hb_counter: int = 0
    fwd_step: int = -1
    answered_step: int = -1
    cmd_step: int = -1
    cmd_sim_ns: int = 0
    sample_steps: dict[int, tuple[int, int]] = field(default_factory=dict)


def _positive(name: str, value: float) -> float:
    v = float(value)
    if not (v > 0 and math.isfinite(v)):
        raise ValueError(f"{name}: expected a finite number > 0, got {value!r}")
    return v


class AutopilotAdapter(Node):
    """Launchable CAN adapter (see the module docstring). Node name ``autopilot`` in launch files.

    Params: ``interface``, ``channel``, ``bitrate`` (python-can bus), ``can_log`` (candump log
    path, ``.log``), ``gliders`` (glider ids, or {glider_id: node_id}), ``state_rate_hz`` (50),
    ``neighbor_rate_hz`` (10), ``heartbeat_hz`` (10), ``state_timeout_s`` (1.0),
    ``cmd_timeout_s`` (1.0), ``failsafe_after_s`` (3.0), ``failsafe_bank_rad`` (0),
    ``failsafe_airspeed_mps`` (best glide), ``heartbeat_timeout_s`` (1.0), ``can_options``
    (extra ``can.Bus`` kwargs), ``faults`` (:class:`CanFaultConfig` mapping),
    ``diagnostics_period_s`` (1.0), ``overwrite`` (replace an existing ``can_log``),
    ``state_max_age_s`` (0.1: a state older than this in sim time, against ``/clock``, is
    dropped and counted ``stale`` instead of reaching the autopilot; None: no limit).
    """

    def __init__(
        self,
        name: str = "autopilot",
        *,
        bus: str | None = None,
        interface: str = "virtual",
        channel: str | int | None = None,
        bitrate: int | None = None,
        can_log: str | Path | None = None,
        gliders: Any = (0,),
        state_rate_hz: float = 50.0,
        neighbor_rate_hz: float = 10.0,
        heartbeat_hz: float = 10.0,
        state_timeout_s: float = 1.0,
        cmd_timeout_s: float = 1.0,
        failsafe_after_s: float = 3.0,
        failsafe_bank_rad: float = 0.0,
        failsafe_airspeed_mps: float | None = None,
        heartbeat_timeout_s: float = 1.0,
        can_options: Mapping[str, Any] | None = None,
        faults: Mapping[str, Any] | None = None,
        diagnostics_period_s: float = 1.0,
        overwrite: bool = False,
        state_max_age_s: float | None = 0.1,
    ) -> None:
        self.gliders = parse_gliders(gliders)
        self.state_max_age_s = (None if state_max_age_s is None
                                else _positive("state_max_age_s", state_max_age_s))
        self.state_rate_hz = _positive("state_rate_hz", state_rate_hz)
        self.neighbor_rate_hz = _positive("neighbor_rate_hz", neighbor_rate_hz)
        self.heartbeat_hz = _positive("heartbeat_hz", heartbeat_hz)
        self.state_timeout_s = _positive("state_timeout_s", state_timeout_s)
        self.cmd_timeout_s = _positive("cmd_timeout_s", cmd_timeout_s)
        self.failsafe_after_s = _positive("failsafe_after_s", failsafe_after_s)
        if self.failsafe_after_s < self.cmd_timeout_s:
            raise ValueError(
                f"failsafe_after_s ({failsafe_after_s}) must be >= cmd_timeout_s ({cmd_timeout_s})"
            )
        self.heartbeat_timeout_s = _positive("heartbeat_timeout_s", heartbeat_timeout_s)
        self.failsafe_cmd = (
            float(failsafe_bank_rad),
            _positive("failsafe_airspeed_mps", failsafe_airspeed_mps)
            if failsafe_airspeed_mps is not None else best_glide_speed(),
        )
        if not abs(self.failsafe_cmd[0]) < math.pi / 2:
            raise ValueError(f"failsafe_bank_rad: expected |bank| < pi/2, got {failsafe_bank_rad}")
        self.bus_config = CanBusConfig.from_params(
            interface=interface, channel=channel, bitrate=bitrate,
            options=dict(can_options or {}), faults=dict(faults) if faults else None,
        )
        if can_log is not None:
            check_output(can_log, overwrite=overwrite)
        super().__init__(
            name, bus=bus, clock=SimClock("lockstep"), diagnostics_period_s=diagnostics_period_s
        )
        self._glider = {gid: _Glider(gid, node) for gid, node in self.gliders.items()}
        gliders = tuple(self._glider.values())
        n_slots = min(len(gliders), STATE_SLOTS)
        #: the gliders whose state samples each slot of a state period sends
        self._slots = tuple(gliders[k::n_slots] for k in range(n_slots))
        self._slots_sent = 0
        self._by_node = {g.node: g for g in self._glider.values()}
        self._glock = threading.Lock()
        #: held for all the frames of one unit on the wire (module docstring); taken before
        #: ``_glock``, never while holding it
        self._tx_lock = threading.Lock()
        self._c: Counter[str] = Counter()
        #: its CAN side: codec, link, receive and transmit threads
        self.can = CanEndpoint(self.name, self.bus_config, faults=self.faults, count=self._inc,
                               log_path=can_log, overwrite=overwrite, loop_prefix="can-")
        self._start_wall = time.monotonic()
        self._lockstep = False
        self._lockstep_since_ns = 0
        self._cmd_pubs: dict[int, Publisher[GliderCmd]] = {}
        self._state_ms: deque[tuple[int, float]] = deque(maxlen=10000)
        states = QoSProfile("state", depth=SENSOR.depth, max_age_s=self.state_max_age_s)
        for gid in self.gliders:
            self._cmd_pubs[gid] = self.create_publisher(GliderCmd, f"/glider/{gid}/cmd", SENSOR)
            # a glider's states and neighbour lists share one ordered lane: a lockstep sample
            # takes the neighbour list of its step, which the server publishes before the state
            self.create_subscription(
                GliderState, f"/glider/{gid}/state", self._make_state_cb(gid), states,
                envelope=True, priority=True, lane=f"glider{gid}",
            )
            self.create_subscription(
                GliderNeighbors, f"/glider/{gid}/neighbors", self._make_nb_cb(gid), SENSOR,
                priority=True, lane=f"glider{gid}",
            )
        self.follow_bus_clock()
        self.create_subscription(Clock, "/clock", self._on_clock, SENSOR, priority=True)

    # -- launchable contract ------------------------------------------------------------------
    def start(self) -> AutopilotAdapter:
        """Start the bus node, open the CAN bus and start the CAN threads (non-blocking)."""
        if not self.can.open():
            return self
        super().start()
        self._start_wall = time.monotonic()
        self.can.run(  # methods looked up at each call, as a patched one would be
            lambda frame: self._on_frame(frame),
            [(1.0 / (self.state_rate_hz * len(self._slots)), lambda now: self._send_states(now)),
             (1.0 / self.heartbeat_hz, lambda now: self._heartbeat_cycle(now))],
            rx_place="handling CAN frame", tx_place="CAN transmit cycle",
        )
        return self

    def stop(self) -> None:
        """Stop the CAN threads, close the CAN bus (flushing the log) and the node (idempotent)."""
        self.can.stop()
        super().stop()

    def counters(self) -> dict[str, Any]:
        """Node counters plus ``can_*`` (link), adapter counters, saturation, per-glider
        ``cmd_state:<id>`` / ``ap_alive:<id>`` / ``ap_mode:<id>`` (numbers, so they reach
        ``/diagnostics``): :meth:`stats` without its latency percentiles. ``/diagnostics`` is
        taken from these every period on the executor that runs the state callbacks, where the
        percentiles of 10,000 samples held them for 3-12 ms of CPU a time (at 250 Hz states)."""
        out = super().stats()  # the Node's own (its counters() would call back into stats())
        with self._glock:
            out.update(self._c)
            for g in self._glider.values():
                out[f"cmd_state:{g.gid}"] = g.cmd_state
                out[f"ap_alive:{g.gid}"] = int(g.ap_alive)
                out[f"ap_mode:{g.gid}"] = g.ap_mode
        out.update(self.can.stats())
        if "can_state" in out:  # a number for /diagnostics, the name as can_link
            out["can_link"] = str(out["can_state"])
            out["can_state"] = _LINK_STATE_CODES.get(out["can_link"], -1)
        return out

    def stats(self) -> dict[str, Any]:
        """:meth:`counters` and ``state_latency_ms`` (bus publish -> state callback percentiles
        over the last 10,000 states, :func:`hil_bridge.bus.stats.percentiles`; also
        ``state_latency_ms_by_glider``; meaningful when the publisher runs on this host)."""
        out = self.counters()
        with self._glock:
            samples = list(self._state_ms)
        by_glider: dict[int, list[float]] = {gid: [] for gid in self.gliders}
        for gid, ms in samples:
            by_glider[gid].append(ms)
        out["state_latency_ms"] = percentiles([ms for _, ms in samples])
        out["state_latency_ms_by_glider"] = {
            str(gid): percentiles(ms) for gid, ms in by_glider.items()}
        return out

    def cmd_state(self, gid: int) -> str:
        """The current command supervision state of glider ``gid`` (a key of CMD_STATES)."""
        with self._glock:
            code = self._glider[gid].cmd_state
        return next(k for k, v in CMD_STATES.items() if v == code)

    # -- bus callbacks (node executor thread) -------------------------------------------------
    def _on_clock(self, msg: Clock) -> None:
        with self._glock:
            if msg.lockstep and not self._lockstep:
                self._lockstep_since_ns = msg.stamp_ns
            self._lockstep = bool(msg.lockstep)

    def _make_state_cb(self, gid: int) -> Any:
        def on_state(env: Envelope) -> None:
            now_ns = time.monotonic_ns()
            msg = env.msg
            if not isinstance(msg, GliderState):
                return
            with self._glock:
                g = self._glider[gid]
                resent = g.state is not None and msg.stamp_ns == g.state.stamp_ns and (
                    g.answered_step < msg.step)
                forward = self._lockstep and (msg.step != g.fwd_step or resent)
                g.state, g.state_wall = msg, now_ns / 1e9
                self._c["states_in"] += 1
                self._state_ms.append((gid, (now_ns - env.header.pub_ns) / 1e6))
                if forward:
                    g.fwd_step = msg.step
            if forward:
                self._send_lockstep_sample(g, msg)

        return on_state

    def _make_nb_cb(self, gid: int) -> Any:
        def on_neighbors(msg: GliderNeighbors) -> None:
            with self._glock:
                g = self._glider[gid]
                g.neighbours, g.nb_new = msg, True
                self._c["neighbor_lists_in"] += 1

        return on_neighbors

    def _stamp(self, g: _Glider) -> int:
        t = self.now_ns()
        return max(t, g.state.stamp_ns) if g.state is not None else t

    # -- CAN transmit -------------------------------------------------------------------------
    def _heartbeat_cycle(self, now: float) -> None:
        self._supervise(now)
        self._send_heartbeats()

    def _send(self, name: str, node: int, values: Mapping[str, float]) -> bool:
        try:
            return self.can.send(name, node, values)
        except ValueError:
            self._inc("tx_encode_errors")
            return False

    def _send_frames(self, node: int, frames: Sequence[Frame]) -> bool:
        """Send ``frames`` in order, every one even after one failed; whether all went out."""
        return all([self._send(name, node, values) for name, values in frames])

    def _attitude_frames(self, st: GliderState, counter: int) -> list[Frame]:
        if not has_attitude(st):
            self._inc("attitude_missing")
        return attitude_frames(st, counter)

    def _inc(self, key: str, n: int = 1) -> None:
        with self._glock:
            self._c[key] += n

    def _send_lockstep_sample(self, g: _Glider, st: GliderState) -> None:
        """One lockstep sample: POS (lockstep = 1), the neighbour list, attitude, MOTION."""
        with self._tx_lock:
            self._send_lockstep_unit(g, st)

    def _send_lockstep_unit(self, g: _Glider, st: GliderState) -> None:
        with self._glock:
            nbs = g.neighbours
            if nbs is not None and nbs.step != st.step:
                nbs = None
            if nbs is not None:
                g.nb_set, g.nb_new = (g.nb_set + 1) % 16, False
            nb_set = g.nb_set
            g.state_counter = (g.state_counter + 1) % 16
            counter = g.state_counter
            g.sample_steps[counter] = (st.step, st.stamp_ns)
        ok = self._send_frames(g.node, [pos_frame(st, lockstep=True)])
        if nbs is not None:
            self._send_neighbours(g, st, nbs, nb_set)
        ok &= self._send_frames(
            g.node, [*self._attitude_frames(st, counter), motion_frame(st, counter)])
        self._inc("lockstep_samples_sent" if ok else "states_dropped")

    def _send_states(self, now: float) -> None:
        """The state samples of the slots due by ``now`` (module docstring): slot i of the run
        is due ``i / (state_rate_hz * slots)`` s after the start; a call that comes late sends
        every slot it missed, at most one period's, so each glider keeps ``state_rate_hz``."""
        if self._lockstep:
            return
        n = len(self._slots)
        due = math.floor((now - self._start_wall) * self.state_rate_hz * n) + 1
        for i in range(max(self._slots_sent, due - n), due):
            for g in self._slots[i % n]:
                self._send_sample(g, now)
        self._slots_sent = max(self._slots_sent, due)

    def _send_sample(self, g: _Glider, now: float) -> None:
        """Glider ``g``'s latest state (if fresh) as a sample, then its neighbour list if a new
        one is due; nothing once lockstep has begun."""
        with self._tx_lock:
            self._send_sample_unit(g, now)

    def _send_sample_unit(self, g: _Glider, now: float) -> None:
        with self._glock:
            st = g.state
            if self._lockstep or st is None or now - g.state_wall > self.state_timeout_s:
                return
            g.state_counter = (g.state_counter + 1) % 16
            counter = g.state_counter
            nbs = None
            if g.nb_new and now - g.nb_sent_wall >= 1.0 / self.neighbor_rate_hz:
                nbs, g.nb_new, g.nb_sent_wall = g.neighbours, False, now
                g.nb_set = (g.nb_set + 1) % 16
            nb_set = g.nb_set
        ok = self._send_frames(g.node, [pos_frame(st), *self._attitude_frames(st, counter),
                                        motion_frame(st, counter)])
        self._inc("states_sent" if ok else "states_dropped")
        if nbs is not None:
            self._send_neighbours(g, st, nbs, nb_set)

    def _send_neighbours(
        self, g: _Glider, own: GliderState, nbs: GliderNeighbors, nb_set: int
    ) -> None:
        if len(nbs.ids) > MAX_NEIGHBOURS:
            self._inc("nb_truncated")
        ok = self._send_frames(g.node, neighbour_frames(own, nbs, nb_set))
        self._inc("nb_lists_sent" if ok else "nb_lists_dropped")

    def _send_heartbeats(self) -> None:
        link = self.can.link
        link_state = link.state if link is not None else "down"
        for g in self._glider.values():
            with self._glock:
                g.hb_counter = (g.hb_counter + 1) % 256
                counter, state = g.hb_counter, g.cmd_state
                has_state = g.state is not None
                sim_ms = (g.state.stamp_ns // 1_000_000) % (1 << 32) if g.state is not None else 0
            mode = bridge_mode(has_state, link_state)
            with self._tx_lock:
                ok = self._send_frames(g.node, [heartbeat_frame(counter, mode, state, sim_ms)])
            self._inc("heartbeats_sent" if ok else "heartbeats_dropped")

    # -- command supervision ------------------------------------------------------------------
    def _cmd_age(self, g: _Glider, now: float) -> float:
        """Seconds since the last command (or the start): sim seconds in lockstep, else wall."""
        if self._lockstep:
            ref = g.cmd_sim_ns if g.last_cmd is not None else self._lockstep_since_ns
            return (self.now_ns() - ref) / 1e9
        return now - (g.cmd_wall if g.last_cmd is not None else self._start_wall)

    def _supervise(self, now: float) -> None:
        for g in self._glider.values():
            with self._glock:
                ap_alive = now - g.ap_wall <= self.heartbeat_timeout_s
                if g.ap_alive and not ap_alive:
                    self._c["ap_heartbeat_lost"] += 1
                g.ap_alive = ap_alive
                state = next_cmd_state(
                    has_cmd=g.last_cmd is not None, age_s=self._cmd_age(g, now),
                    ap_fault=ap_alive and g.ap_mode == AP_FAULT,
                    cmd_timeout_s=self.cmd_timeout_s, failsafe_after_s=self.failsafe_after_s,
                )
                if state != g.cmd_state:
                    if state == CMD_STATES["HOLD"]:
                        self._c["hold_entries"] += 1
                    elif state == CMD_STATES["FAILSAFE"]:
                        self._c["failsafe_entries"] += 1
                g.cmd_state = state
                last, step, stamp = g.last_cmd, g.cmd_step, self._stamp(g)
            if state == CMD_STATES["HOLD"] and last is not None:
                self._publish_cmd(g, last, step, stamp)
                self._inc("cmd_hold_published")
            elif state == CMD_STATES["FAILSAFE"]:
                self._publish_cmd(g, self.failsafe_cmd, step, stamp)
                self._inc("cmd_failsafe_published")

    def _publish_cmd(self, g: _Glider, cmd: tuple[float, float], step: int, stamp: int) -> None:
        self._cmd_pubs[g.gid].publish(
            GliderCmd(
                stamp_ns=stamp, bank_cmd=cmd[0], airspeed_cmd=cmd[1], glider_id=g.gid, step=step
            )
        )

    # -- CAN receive (the endpoint's receive thread) -----------------------------------------------
    def _on_frame(self, frame: DecodedFrame) -> None:
        g = self._by_node.get(frame.node_id)
        s = frame.signals
        if frame.name == "AUTOPILOT_CMD":
            if g is None:
                self._inc("rx_unknown_node")
                return
            cmd = (s["bank_cmd_rad"], s["airspeed_cmd_mps"])
            counter = int(s["cmd_counter"])
            with self._glock:
                if g.cmd_counter is not None and counter != (g.cmd_counter + 1) % 256:
                    self._c["cmd_frames_lost"] += (counter - g.cmd_counter - 1) % 256
                g.cmd_counter = counter
                g.last_cmd, g.cmd_wall = cmd, time.monotonic()
                if g.cmd_state == CMD_STATES["FAILSAFE"]:
                    self._c["failsafe_exits"] += 1
                g.cmd_state = CMD_STATES["FRESH"]
                self._c["cmd_frames_in"] += 1
                answered = g.sample_steps.get(int(s["answer_counter"])) if s["answer"] else None
                if answered is not None:
                    step, stamp = answered
                    g.answered_step = max(g.answered_step, step)
                    self._c["lockstep_answers"] += 1
                else:
                    step = g.state.step if g.state is not None else 0
                    stamp = self._stamp(g)
                    if s["answer"]:
                        self._c["lockstep_answers_unknown"] += 1
                g.cmd_step, g.cmd_sim_ns = step, stamp
            self._publish_cmd(g, cmd, step, stamp)
            self._inc("cmd_forwarded")
        elif frame.name == "AUTOPILOT_HEARTBEAT":
            if g is None:
                self._inc("rx_unknown_node")
                return
            counter = int(s["ap_counter"])
            with self._glock:
                if g.ap_counter is not None and counter != (g.ap_counter + 1) % 256:
                    self._c["ap_heartbeats_lost"] += (counter - g.ap_counter - 1) % 256
                g.ap_counter = counter
                g.ap_wall = time.monotonic()
                g.ap_mode = int(s["ap_mode"])
                self._c["ap_heartbeats_in"] += 1
        else:
            self._inc("rx_foreign_bridge")
