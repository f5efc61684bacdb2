"""Vehicle stepping for the simulation server: every vehicle of a scene, flown tick by tick.

:class:`Fleet` flies everything the server publishes on ``/glider/<id>/state``:

- the swarm's gliders (:class:`sim_core.continuous_swarm.ContinuousSwarm`): the law's
  controller decides every ``law.dt`` (:meth:`Fleet.decide`, on the ticks :meth:`Fleet.control_due`
  names: ``law.dt`` must be a whole number of ticks), and every glider flies the continuous
  model in between, on the law's held commands or on its autopilot's latest;
- commanded vehicles (``commanded: true``): their path until an autopilot's first command, then
  :mod:`sim_core.flight` on the held command (taken over at the pose the path had);
- 6-DoF vehicles (``sixdof:``): JSBSim aircraft (:class:`sim_core.sixdof.SixDofGliders`) from
  the start, on the held control surfaces (neutral until the first), in the swarm's updraft;
- path vehicles: sampled on their trajectory at each tick, with the attitude the path implies
  (:func:`sim_core.flight.path_state`).

:meth:`Fleet.advance` integrates from one tick to the next on the commands it is given (the
server passes those held when the tick starts, so a command received before tick k is flown
in the state of tick k). :meth:`Fleet.states` gives the state and attitude of every vehicle
and records the poses of the vehicles listed in ``history_ids`` (those carrying a sonar) in
:attr:`Fleet.history` (:class:`hil_bridge.server.pose_history.PoseHistory`), for pings emitted
between ticks. Only the history may be used from another thread than the one stepping the
fleet.
"""

from __future__ import annotations

import logging
from collections.abc import Iterable, Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray

from hil_bridge.server.pose_history import PoseHistory
from sim_core.config import ConfigError
from sim_core.flight import (
    BANK,
    HEADING,
    SPEED,
    FlightModel,
    FlightOutputs,
    X,
    Y,
    Z,
    path_state,
    path_states,
)
from sim_core.scene import Scene

log = logging.getLogger(__name__)

__all__ = ["Fleet", "FleetStates"]

F8 = NDArray[np.float64]
B8 = NDArray[np.bool_]


@dataclass(frozen=True, slots=True)
class FleetStates:
    """Every vehicle at one tick, rows in the order of ``ids`` (swarm gliders, then vehicles by
    id): ``position``, ``velocity`` (M, 3) m, m/s ENU; ``heading``, ``bank``, ``airspeed``,
    ``vz``, ``roll``, ``pitch``, ``yaw`` (M,); ``quat`` (M, 4) world-from-body; ``rates`` (M, 3)
    body rates rad/s; ``alive`` (M,); ``step`` (M,) the swarm's control step for gliders, the
    tick for vehicles."""

    t_ns: int
    ids: tuple[int, ...]
    position: F8
    velocity: F8
    heading: F8
    bank: F8
    airspeed: F8
    vz: F8
    roll: F8
    pitch: F8
    yaw: F8
    quat: F8
    rates: F8
    alive: B8
    step: NDArray[np.int64]


class Fleet:
    """Every vehicle of ``scene``, stepped at ``tick_ns`` with ``substeps`` integration steps per
    tick (at least; see :meth:`sim_core.flight.FlightModel.step`); ``history_s`` s of poses
    kept for each id in ``history_ids``."""

    def __init__(
        self,
        scene: Scene,
        *,
        tick_ns: int,
        substeps: int = 1,
        history_s: float = 2.0,
        history_ids: Iterable[int] = (),
    ) -> None:
        if tick_ns <= 0 or substeps < 1:
            raise ValueError(f"tick_ns > 0 and substeps >= 1 expected, got {tick_ns}, {substeps}")
        self.scene = scene
        self.tick_ns = tick_ns
        self.substeps = substeps
        self.tick = 0
        self.swarm: Any = scene.swarm
        self.glider_ids: tuple[int, ...] = scene.glider_ids
        self._gindex = {gid: i for i, gid in enumerate(self.glider_ids)}
        self.control_every = 0
        if self.swarm is not None:
            per = float(scene.law.dt) * 1e9 / tick_ns
            self.control_every = round(per)
            if self.control_every < 1 or abs(per - self.control_every) > 1e-6:
                raise ConfigError(
                    f"swarm: the law's dt ({scene.law.dt} s) must be a whole number of ticks "
                    f"of {tick_ns / 1e9} s (choose state_rate_hz accordingly)"
                )
        vehicles = sorted(scene.spec.vehicles, key=lambda v: v.id)
        self.vehicle_ids = tuple(v.id for v in vehicles)
        self._traj = scene.trajectories if vehicles else {}
        self._commanded = [v for v in vehicles if v.commanded]
        self._cindex = {v.id: i for i, v in enumerate(self._commanded)}
        self._vmodel: FlightModel | None = None
        n_c = len(self._commanded)
        if n_c:
            from sim_core.soaring.law import Law

            polar = Law()  # the SB-XC polar of the seed law, for vehicles that glide
            self._vmodel = FlightModel.from_params(
                [v.flight for v in self._commanded], glide=[v.glides for v in self._commanded],
                polar=(polar.Sink_A, polar.Sink_B, polar.Sink_C), g=polar.g,
            )
        self._sixdof_specs = [v for v in vehicles if v.sixdof is not None]
        self._sindex = {v.id: i for i, v in enumerate(self._sixdof_specs)}
        self.sixdof: Any = None
        if self._sixdof_specs:
            from sim_core.sixdof import CONTROLS, SixDofGliders

            starts = [path_state(self._traj[v.id], 0.0) for v in self._sixdof_specs]
            self.sixdof = SixDofGliders(
                [v.sixdof for v in self._sixdof_specs if v.sixdof is not None],
                np.array([s.position for s in starts]), np.array([s.heading for s in starts]),
                updraft=self._updraft,
            )
            self._surfaces = np.zeros((len(self._sixdof_specs), len(CONTROLS)))
        self._sixdof_out: Any = None
        self._sixdof_up = np.ones(len(self._sixdof_specs), dtype=bool)
        #: 6-DoF vehicles that came down (each warned of once)
        self.vehicles_down = 0
        self._vy = np.zeros((6, n_c))
        for i, v in enumerate(self._commanded):
            self._vy[:, i] = self._takeover_state(v.id, 0)
        self._vcmd = np.stack([self._vy[BANK], self._vy[SPEED]])
        self._vflown = np.zeros(n_c, dtype=bool)
        self._vgrounded = np.zeros(n_c, dtype=bool)
        self._external: Any = None
        self.ids: tuple[int, ...] = (*self.glider_ids, *self.vehicle_ids)
        #: the poses of the ``history_ids`` at every tick :meth:`states` computed
        self.history = PoseHistory(history_ids, tick_ns=tick_ns, history_s=history_s)

    # -- stepping ----------------------------------------------------------------------------
    @property
    def flies(self) -> bool:
        """Whether the flight model flies any vehicle (a swarm, or a commanded vehicle)."""
        return self.swarm is not None or self._vmodel is not None

    @property
    def t_ns(self) -> int:
        return self.tick * self.tick_ns

    def control_due(self) -> bool:
        """Whether the swarm's controller decides at the current tick."""
        return self.swarm is not None and self.tick % self.control_every == 0

    def _swarm_commands(self, commands: Mapping[int, tuple[float, float]]) -> Any:
        from sim_core.soaring import Commands

        n = len(self.glider_ids)
        bank, speed = np.zeros((1, n)), np.zeros((1, n))
        mask = np.zeros((1, n), dtype=bool)
        for gid, (b, v) in commands.items():
            i = self._gindex.get(gid)
            if i is not None:
                bank[0, i], speed[0, i], mask[0, i] = b, v, True
        return Commands(bank_cmd=bank, airspeed_cmd=speed, mask=mask) if mask.any() else None

    def decide(self, commands: Mapping[int, tuple[float, float]]) -> None:
        """The swarm's control step at the current tick (gliders with a command in
        ``commands`` are flown by their autopilot, not by the law)."""
        self._external = self._swarm_commands(commands)
        self.swarm.decide(self._external)

    @property
    def sixdof_ids(self) -> tuple[int, ...]:
        """The ids of the 6-DoF vehicles."""
        return tuple(self._sindex)

    def advance(self, commands: Mapping[int, tuple[float, float]],
                surfaces: Mapping[int, tuple[float, ...]] | None = None) -> None:
        """Fly every vehicle to the next tick on ``commands`` (id → (bank rad, airspeed m/s),
        within each vehicle's envelope) and the 6-DoF vehicles on ``surfaces`` (id →
        :data:`sim_core.sixdof.CONTROLS`; held from the last given). A commanded vehicle's first
        command takes it off its path at the pose the path has now."""
        dt = self.tick_ns / 1e9
        if self.sixdof is not None:
            for vid, u in (surfaces or {}).items():
                i = self._sindex.get(vid)
                if i is not None:
                    self._surfaces[i] = u
            # no swarm, no thermals: still air, and no positions to compute for it
            self.sixdof.step(dt, self._surfaces, None if self.swarm is None else self._updraft)
        if self.swarm is not None:
            self._external = self._swarm_commands(commands)
            self.swarm.advance(dt, substeps=self.substeps, external=self._external)
        if self._vmodel is not None:
            for vid, i in self._cindex.items():
                cmd = commands.get(vid)
                if cmd is None:
                    continue
                if not self._vflown[i]:
                    self._vy[:, i] = self._takeover_state(vid, self.t_ns)
                    self._vflown[i] = True
                self._vcmd[:, i] = cmd
            self._vy, grounded = self._vmodel.step(
                self._vy, self._vcmd, dt, substeps=self.substeps, updraft=self._updraft,
                active=self._vflown & ~self._vgrounded,
            )
            self._vgrounded |= grounded
        self.tick += 1

    def _takeover_state(self, vid: int, t_ns: int) -> F8:
        """The flight state (6,) a commanded vehicle starts from: its path's pose at ``t_ns``
        (airspeed at least the vehicle's minimum)."""
        ps = path_state(self._traj[vid], t_ns / 1e9)
        speed = max(ps.airspeed, self._commanded[self._cindex[vid]].speed_min_mps)
        return np.array([*ps.position, ps.heading, ps.bank, speed])

    def _updraft(self, xy: F8) -> F8:
        if self.swarm is None:
            return np.zeros(xy.shape[1:])
        return np.asarray(self.swarm.updraft(xy), dtype=np.float64)

    # -- states ------------------------------------------------------------------------------
    def states(self) -> FleetStates:
        """Every vehicle's state at the current tick (and the sonar carriers' history)."""
        parts: list[dict[str, Any]] = []
        if self.swarm is not None:
            y = self.swarm.flight_state[:, 0]
            out = self.swarm.outputs(self._external)
            parts.append(self._flown_part(y, _row(out, 0), self.swarm.alive[0],
                                          self.swarm.step_count))
        flown: dict[str, Any] = {}
        if self._vmodel is not None:
            y = self._vy
            out = self._vmodel.outputs(y, self._vcmd, self._updraft(y[X : Y + 1]))
            flown = self._flown_part(y, out, ~self._vgrounded, self.tick)
        on_path = [vid for vid in self.vehicle_ids if vid not in self._sindex and (
            vid not in self._cindex or not self._vflown[self._cindex[vid]])]
        blocks: list[tuple[list[int], dict[str, Any]]] = []
        if self.sixdof is not None:
            so = self._sixdof_out = self.sixdof.outputs()
            for i in np.flatnonzero(self._sixdof_up & ~so.alive):
                x, y, z = so.position[i]
                log.warning("vehicle %d came down at t = %.2f s, (%.1f, %.1f, %.1f) m: held at "
                            "rest there (alive false)", self._sixdof_specs[i].id,
                            self.t_ns / 1e9, x, y, z)
                self.vehicles_down += 1
            self._sixdof_up = so.alive.copy()
            blocks.append((list(self._sindex), {
                "position": so.position, "velocity": so.velocity, "heading": so.yaw,
                "bank": -so.roll, "airspeed": so.airspeed, "vz": so.velocity[:, 2],
                "roll": so.roll, "pitch": so.pitch, "yaw": so.yaw, "quat": so.quat,
                "rates": so.rates, "alive": so.alive,
                "step": np.full(len(self._sindex), self.tick, dtype=np.int64),
            }))
        if on_path:
            ps = path_states([self._traj[vid] for vid in on_path], self.t_ns / 1e9)
            o = ps.outputs
            blocks.append((on_path, {
                "position": ps.position, "velocity": ps.velocity, "heading": ps.heading,
                "bank": ps.bank, "airspeed": ps.airspeed, "vz": o.vz, "roll": o.roll,
                "pitch": o.pitch, "yaw": o.yaw, "quat": o.quat, "rates": o.rates,
                "alive": np.ones(len(on_path), dtype=bool),
                "step": np.full(len(on_path), self.tick, dtype=np.int64),
            }))
        taken = [vid for vid in self.vehicle_ids
                 if vid not in set(on_path) and vid not in self._sindex]
        if taken:
            rows = [self._cindex[vid] for vid in taken]
            blocks.append((taken, {k: v[rows] for k, v in flown.items()}))
        if len(blocks) == 1 and blocks[0][0] == list(self.vehicle_ids):
            parts.append(blocks[0][1])
        elif blocks:  # the vehicles in id order
            at = {vid: k for k, vid in enumerate(self.vehicle_ids)}
            places = [np.array([at[v] for v in vids], dtype=np.intp) for vids, _ in blocks]
            block: dict[str, Any] = {}
            for key, first in blocks[0][1].items():
                block[key] = np.empty((len(at), *first.shape[1:]), dtype=first.dtype)
                for (_, arrays), where in zip(blocks, places, strict=True):
                    block[key][where] = arrays[key]
            parts.append(block)
        merged = {k: np.concatenate([p[k] for p in parts]) for k in parts[0]} if parts else {}
        st = FleetStates(t_ns=self.t_ns, ids=self.ids, **merged) if parts else _empty(self.t_ns)
        self.history.record(st.t_ns, st.ids, st.position, st.velocity, st.quat, st.rates)
        return st

    def _flown_part(self, y: F8, out: FlightOutputs, alive: B8, step: int) -> dict[str, Any]:
        v, psi = y[SPEED], y[HEADING]
        n = y.shape[1]
        return {
            "position": np.stack([y[X], y[Y], y[Z]], axis=1),
            "velocity": np.stack([v * np.cos(psi), v * np.sin(psi), out.vz], axis=1),
            "heading": np.asarray(out.yaw), "bank": y[BANK].copy(), "airspeed": v.copy(),
            "vz": np.asarray(out.vz), "roll": np.asarray(out.roll),
            "pitch": np.asarray(out.pitch), "yaw": np.asarray(out.yaw), "quat": out.quat,
            "rates": out.rates, "alive": np.asarray(alive, dtype=bool),
            "step": np.full(n, step, dtype=np.int64),
        }

    def sixdof_outputs(self) -> Any:
        """The 6-DoF vehicles' outputs (:class:`sim_core.sixdof.SixDofOutputs`, rows in the
        order of :attr:`sixdof_ids`) at the last :meth:`states`, or None."""
        return self._sixdof_out


def _row(out: FlightOutputs, run: int) -> FlightOutputs:
    """The outputs of one run of a (B, N) batch."""
    return FlightOutputs(
        vz=out.vz[run], omega=out.omega[run], roll=out.roll[run], pitch=out.pitch[run],
        yaw=out.yaw[run], quat=out.quat[run], rates=out.rates[run],
    )


def _empty(t_ns: int) -> FleetStates:
    z1, z3 = np.zeros(0), np.zeros((0, 3))
    return FleetStates(
        t_ns=t_ns, ids=(), position=z3, velocity=z3, heading=z1, bank=z1, airspeed=z1, vz=z1,
        roll=z1, pitch=z1, yaw=z1, quat=np.zeros((0, 4)), rates=z3,
        alive=np.zeros(0, dtype=bool), step=np.zeros(0, dtype=np.int64),
    )
