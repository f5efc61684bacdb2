"""A glider autopilot emulator on a python-can bus: :class:`MockAutopilot`.

It is the other end of :class:`drivers.can.adapter.AutopilotAdapter` and speaks only the CAN
profile (``drivers/can/glider.dbc``, docs/can.md): for each node id it flies it assembles the
glider's state samples (GLIDER_STATE_POS, QUAT, RATES, MOTION: only frames of one sample, by
:class:`drivers.can.samples.SampleAssembler`; a torn sample is dropped and counted) and its
neighbour list (NEIGHBOR_POS + NEIGHBOR_MOTION, positions relative to the glider) into what it
knows of the glider (:mod:`drivers.mocks.profile_receiver`), runs a
controller at its control rate and sends AUTOPILOT_CMD; it sends AUTOPILOT_HEARTBEAT at
``heartbeat_hz`` for every node.

Controllers:

* ``unified`` / ``baseline`` — seed 002's Boids (``sim_core.soaring.controller_command``) on the
  glider's own state and its neighbours, commands clipped to the law's bank and speed envelope
  (the glider applies the same limits, so flying these commands reproduces the swarm). The
  default control rate is ``1 / law.dt``, the rate the seed's controller is tuned for.
* ``path`` — :class:`~drivers.mocks.path_follower.PathFollower`, pure pursuit along a closed
  route of waypoints (by default a figure-eight like the seed 000 "8" route) at a fixed
  airspeed, for a low-flying sonar vehicle; default control rate 10 Hz.

A node without fresh state (older than ``state_timeout_s``), or whose glider is dead, is not
commanded; its heartbeat says ``NO_STATE``.

**Lockstep** (docs/can.md): a state sample whose GLIDER_STATE_POS has ``lockstep = 1`` is
answered at once, on the receive thread, with one AUTOPILOT_CMD (``answer = 1``,
``answer_counter`` = the sample's ``state_counter``) computed from that sample and the
neighbour list sent with it: the autopilot acts on sim time, one command per state step,
whatever the wall clock does. Its control timer leaves such nodes alone; a node whose latest
sample is not a lockstep one is commanded at ``rate_hz`` again.

Launchable (``Cls(name, *, bus, **params)``): the ``bus`` argument is part of the contract; a
device mock has no use for the echoloop bus. Its CAN threads are those of the bridge
(:class:`drivers.can.endpoint.CanEndpoint`): an exception in its receive or control loop is
counted (``loop_errors``) and reported to its ``faults``: ``failure()`` names it.
"""

from __future__ import annotations

import math
import threading
import time
from collections import Counter
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import ArrayLike

from drivers.can.bus import CanBusConfig
from drivers.can.codec import MAX_NODE_ID, DecodedFrame
from drivers.can.endpoint import CanEndpoint
from drivers.mocks.path_follower import PathFollower, figure_eight_waypoints
from drivers.mocks.profile_receiver import NodeView, ProfileReceiver
from hil_bridge.bus.faults import Faults
from hil_bridge.files.soaring import load_law
from hil_bridge.outputs import check_output
from sim_core.soaring.boids import GliderObs, controller_command
from sim_core.soaring.law import Law

__all__ = ["AP_MODES", "CONTROLLER_CODES", "PATH_RATE_HZ", "MockAutopilot"]

#: Default control rate of the path follower, Hz.
PATH_RATE_HZ = 10.0
#: ap_mode values of AUTOPILOT_HEARTBEAT (the DBC's value table).
AP_MODES = {"INIT": 0, "AUTO": 1, "NO_STATE": 2, "FAULT": 3}
#: ap_controller values of AUTOPILOT_HEARTBEAT.
CONTROLLER_CODES = {"unified": 0, "baseline": 1, "path": 2}

_NO_OBS = GliderObs(x=0.0, y=0.0, z=0.0, heading=0.0, speed=0.0, vz=0.0)


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
    ``path``; default :func:`~drivers.mocks.path_follower.figure_eight_waypoints`),
    ``path_airspeed_mps``, ``lookahead_m``, ``bank_max_rad`` (path follower), ``can_log``
    (candump log of its own traffic; ``overwrite`` replaces an existing one), ``faults``.
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
        if can_log is not None:
            check_output(can_log, overwrite=overwrite)
        self.follower: PathFollower | None = None
        if controller == "path":
            route = figure_eight_waypoints() if waypoints is None else waypoints
            self.follower = PathFollower(
                route, n_vehicles=len(self.nodes), lookahead_m=lookahead_m,
                airspeed_mps=path_airspeed_mps, bank_max_rad=bank_max_rad, g=self.law.g,
            )
        self.receiver = ProfileReceiver(self.nodes)
        self._counters: Counter[str] = Counter()
        self._count_lock = threading.Lock()
        self._cmd_counter = dict.fromkeys(self.nodes, 0)
        self._ctl_lock = threading.Lock()  # the control timer and lockstep answers share state
        self._hb_counter = 0
        self._last_cmd: dict[int, tuple[float, float]] = {}
        #: what went wrong in its loops (:mod:`hil_bridge.bus.faults`)
        self.faults = Faults(name)
        #: its CAN side: codec, link, receive and transmit threads
        self.can = CanEndpoint(name, self.bus_config, faults=self.faults, count=self._inc,
                               log_path=can_log, overwrite=overwrite)

    # -- launchable contract ------------------------------------------------------------------
    def start(self) -> None:
        """Open the CAN bus and start the receive and control threads (non-blocking)."""
        if not self.can.open():
            return
        self.can.run(  # methods looked up at each call, as a patched one would be
            lambda frame: self._on_frame(frame),
            [(1.0 / self.rate_hz, lambda now: self._control(now)),
             (1.0 / self.heartbeat_hz, lambda now: self._heartbeat(now))],
            rx_place="assembling CAN frame", tx_place="control cycle",
        )

    def stop(self) -> None:
        """Stop the threads and close the bus (idempotent)."""
        self.can.stop()

    def stats(self) -> dict[str, Any]:
        with self._count_lock:
            out: dict[str, Any] = dict(self._counters)
        out.update({f"rx_{k}": v for k, v in self.receiver.counts().items()})
        out.update(self.can.stats())
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

    # -- receive (the endpoint's receive thread) ----------------------------------------------
    def _on_frame(self, frame: DecodedFrame) -> None:
        now = time.monotonic()
        if self.receiver.feed(frame, now):
            self._inc("rx_frames_used")
            if frame.name == "GLIDER_STATE_MOTION":
                self._answer_lockstep(frame.node_id, int(frame.signals["state_counter"]), now)

    # -- control (the endpoint's transmit thread) ---------------------------------------------
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
        if self.can.link is None:
            return
        self._cmd_counter[node] = (self._cmd_counter[node] + 1) % 256
        sent = self.can.send(
            "AUTOPILOT_CMD", node,
            {"bank_cmd_rad": bank, "airspeed_cmd_mps": speed,
             "cmd_counter": self._cmd_counter[node], "answer": int(answer_counter is not None),
             "answer_counter": answer_counter or 0},
        )
        if sent:
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
        if self.can.link is None:
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
            sent = self.can.send(
                "AUTOPILOT_HEARTBEAT", node,
                {"ap_counter": self._hb_counter, "ap_mode": mode,
                 "ap_controller": CONTROLLER_CODES[self.controller],
                 "ap_state_age_ms": age_ms, "ap_rx_errors": min(rx_errors, 65535)},
            )
            self._inc("heartbeats_sent" if sent else "heartbeats_dropped")
