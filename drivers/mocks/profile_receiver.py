"""What the mock autopilot knows of each node's glider, assembled from the bridge's frames.

:class:`ProfileReceiver` takes the bridge → autopilot frames of the CAN profile
(``drivers/can/glider.dbc``, docs/can.md) and keeps one :class:`NodeView` per node id: the
glider's latest whole state sample (by :class:`drivers.can.samples.SampleAssembler`), its
latest whole neighbour list and the bridge's heartbeat. Used by
:class:`drivers.mocks.autopilot.MockAutopilot`.
"""

from __future__ import annotations

import math
import threading
from collections import Counter
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import NDArray

from drivers.can.codec import DecodedFrame
from drivers.can.samples import STATE_FRAMES, SampleAssembler
from sim_core.soaring.boids import GliderObs

__all__ = ["NodeView", "ProfileReceiver"]

F8 = NDArray[np.float64]


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
