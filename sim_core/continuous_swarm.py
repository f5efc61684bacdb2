"""The seed 002 law flown in continuous time: the controller at its own rate (``law.dt``), the
gliders flown by :mod:`sim_core.flight` in between.

:class:`ContinuousSwarm` composes a :class:`~sim_core.soaring.swarm.SwarmSim`, which keeps
everything the seed does at a control step (thermal fade, neighbour lists, collisions, the Boids
commands, deaths, metrics), with a :class:`~sim_core.flight.FlightModel` that flies the gliders
between steps. Time runs in two phases:

* :meth:`ContinuousSwarm.decide`, at a control instant t_k = k·dt: the SwarmSim takes the flown
  state (``set_state``) and takes its step from it. The step's metrics, collisions and
  neighbour lists are those of the flown state; the bank and airspeed it reaches are the
  law's commands after its limits, held until the next decision; its ground rule (the seed's
  step from here reaches z <= 0) kills the gliders about to land. The SwarmSim then takes the
  flown state back, so what it reports (neighbour lists, positions) is the flight's;
* :meth:`ContinuousSwarm.advance` flies every glider for any time (a server tick, or a control
  period in sub-steps) on the held commands, or, where an outside autopilot flies a glider, on
  that autopilot's latest command. A glider that reaches the ground in flight stops there and
  flies no more; the seed's ground rule kills it at the next decision.

The same code flies the server's swarm (one tick at a time) and ``echoloop swarm run --physics
continuous`` (:func:`run_continuous`, a control period at a time). What differs from the seed's
discrete step, by construction: bank and airspeed follow their commands through the flight
model's first-order, rate-limited response instead of jumping to them; gliders fly arcs while
turning instead of straight along the old heading; the updraft and the sink act along the
path, not at its start. docs/soaring.md compares the metrics.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numpy.typing import NDArray

from sim_core.flight import BANK, HEADING, SPEED, FlightModel, FlightOutputs, FlightParams, X, Y, Z
from sim_core.soaring.law import Law
from sim_core.soaring.swarm import Commands, Metrics, RunResult, SwarmSim, SwarmState
from sim_core.soaring.thermals import Thermals
from sim_core.soaring.trace import Trace

__all__ = ["ContinuousSwarm", "run_continuous"]

F8 = NDArray[np.float64]
B8 = NDArray[np.bool_]


@dataclass(slots=True)
class _Rows:
    """Trace rows recorded at the decisions."""

    t: list[float] = field(default_factory=list)
    rows: list[dict[str, NDArray[Any]]] = field(default_factory=list)


class ContinuousSwarm:
    """A seed 002 swarm whose controller decides every ``law.dt`` and whose gliders fly the
    continuous model in between (see the module docstring).

    ``ContinuousSwarm(law, *, seed=None, batch=1, flight=None, trace=False)``: ``batch`` runs
    with seeds ``seed, seed+1, ...`` (or ``seed`` a sequence, one per run), as
    :class:`~sim_core.soaring.swarm.SwarmSim`. ``flight``: the gliders' :class:`FlightParams`;
    the law's ``bankRateMax`` / ``speedRateMax``, when set, replace its rate limits. Arrays are
    (B, N) like the SwarmSim's. ``trace``: record the state at every decision (:meth:`trace`).
    """

    def __init__(
        self,
        law: Law,
        *,
        seed: int | Sequence[int] | None = None,
        batch: int = 1,
        flight: FlightParams | None = None,
        trace: bool = False,
    ) -> None:
        params = flight if flight is not None else FlightParams()
        if params.vertical == "hold":
            raise ValueError("flight.vertical: swarm gliders glide (the law's polar); got 'hold'")
        if seed is None or isinstance(seed, int):
            base = law.rngSeed if seed is None else seed
            seeds = [base + b for b in range(batch)]
        else:
            seeds = [int(s) for s in seed]
        self.law = law
        self.sim = SwarmSim([law] * len(seeds), seed=seeds)
        st = self.sim.state
        self._y: F8 = np.stack([st.x, st.y, st.z, st.heading, st.bank, st.speed])
        self._alive: B8 = st.alive
        self._grounded: B8 = np.zeros_like(st.alive)
        self._cmd: F8 | None = None  # (2, B, N) = (bank_cmd, airspeed_cmd), held
        self._lo = np.array([law.bankMin, law.forwardSpeedMin]).reshape(2, 1, 1)
        self._hi = np.array([law.bankMax, law.forwardSpeedMax]).reshape(2, 1, 1)
        self.model = FlightModel(
            bank_tau=params.bank_tau_s,
            bank_rate_max=params.bank_rate_max if law.bankRateMax is None else law.bankRateMax,
            speed_tau=params.speed_tau_s,
            speed_rate_max=(params.speed_rate_max if law.speedRateMax is None
                            else law.speedRateMax),
            glide=True, polar=(law.Sink_A, law.Sink_B, law.Sink_C), g=law.g,
            ceiling=law.agentCeiling, floor=law.agentFloor,
        )
        self._trace: _Rows | None = _Rows() if trace else None
        self.time_s = 0.0

    # -- the two phases ----------------------------------------------------------------------
    def decide(self, commands: Commands | None = None) -> None:
        """One control step of the law at the current instant, from the state flown so far.
        ``commands``: gliders flown from outside (their mask keeps them out of the Boids
        control; their values are flown by :meth:`advance`)."""
        flown = self.state
        sim = self.sim
        sim.set_state(flown)
        sim.step(commands)
        stepped = sim.state
        self._cmd = np.stack([stepped.bank, stepped.speed])
        self._alive = stepped.alive
        self._grounded &= self._alive
        sim.set_state(flown)
        if self._trace is not None:
            self._trace.t.append(self.time_s)
            self._trace.rows.append({
                "x": flown.x, "y": flown.y, "z": flown.z, "heading": flown.heading,
                "bank": flown.bank, "airspeed": flown.speed, "vz": flown.vz,
                "alive": self._alive.copy(), "cohesion": sim.cohesion_mag.copy(),
                "thermal_strength": sim.thermals.strength.copy(),
            })

    def commands_in_effect(self, external: Commands | None = None) -> F8:
        """(bank_cmd, airspeed_cmd) (2, B, N) the gliders fly now: the held law commands, or
        ``external`` ones where its mask is set (limited to the law's envelope)."""
        if self._cmd is None:
            raise ValueError("no commands yet: call decide() before flying")
        u = self._cmd.copy()
        if external is not None:
            shape = u.shape[1:]
            mask = np.broadcast_to(np.asarray(external.mask, dtype=bool), shape)
            np.copyto(u[0], np.broadcast_to(np.asarray(external.bank_cmd, float), shape),
                      where=mask)
            np.copyto(u[1], np.broadcast_to(np.asarray(external.airspeed_cmd, float), shape),
                      where=mask)
            u = np.clip(u, self._lo, self._hi)
        return u

    def advance(self, dt_s: float, *, substeps: int = 1,
                external: Commands | None = None) -> None:
        """Fly every living glider ``dt_s`` s in ``substeps`` RK4 sub-steps (at least as many
        as :class:`~sim_core.flight.FlightModel` needs) on :meth:`commands_in_effect`."""
        u = self.commands_in_effect(external)
        self._y, grounded = self.model.step(
            self._y, u, dt_s, substeps=substeps, updraft=self._updraft,
            active=self._alive & ~self._grounded,
        )
        self._grounded |= grounded
        self.time_s += dt_s

    def _updraft(self, xy: F8) -> F8:
        """w m/s at xy (2, B, N) → (B, N), the SwarmSim's thermals as they are now."""
        return self.sim.updraft_at(np.moveaxis(xy, 0, -1))

    # -- views -------------------------------------------------------------------------------
    @property
    def flight_state(self) -> F8:
        """The flight state (6, B, N) (rows of :mod:`sim_core.flight`), a copy."""
        return self._y.copy()

    @property
    def alive(self) -> B8:
        """(B, N) gliders alive (one grounded since the last decision still is, stopped)."""
        return self._alive.copy()

    @property
    def step_count(self) -> int:
        """Control steps taken."""
        return self.sim.step_count

    @property
    def thermals(self) -> Thermals:
        """The thermals as of the last decision (a copy)."""
        return self.sim.thermals

    def updraft(self, xy: F8) -> F8:
        """w m/s at horizontal points ``xy (2, M)`` of run 0 → (M,)."""
        pts = np.asarray(xy, dtype=np.float64)
        return self.sim.updraft_at(pts.T[None])[0]

    def outputs(self, external: Commands | None = None) -> FlightOutputs:
        """Vertical speed, turn rate and attitude of every glider now (arrays (B, N))."""
        u = self.commands_in_effect(external) if self._cmd is not None else np.stack(
            [self._y[BANK], self._y[SPEED]])
        return self.model.outputs(self._y, u, self._updraft(self._y[X : Y + 1]))

    @property
    def state(self) -> SwarmState:
        """The gliders now as a :class:`SwarmState` (copies, (B, N)); vz is the polar sink plus
        the updraft, omega the turn rate."""
        y = self._y
        u = np.stack([y[BANK], y[SPEED]])
        out = self.model.outputs(y, u, self._updraft(y[X : Y + 1]))
        return SwarmState(
            x=y[X].copy(), y=y[Y].copy(), z=y[Z].copy(), heading=y[HEADING].copy(),
            bank=y[BANK].copy(), speed=y[SPEED].copy(), omega=out.omega, vz=out.vz,
            alive=self._alive.copy(),
        )

    def neighbors(self, i: int, run: int = 0) -> list[int]:
        """The law's neighbour list of glider ``i`` (see :meth:`SwarmSim.neighbors`)."""
        return self.sim.neighbors(i, run)

    def metrics(self, run: int = 0) -> Metrics:
        return self.sim.metrics(run)

    def trace(self, run: int = 0, steps: int | None = None) -> Trace:
        """The states at the decision instants t = 0, dt, ... (``trace=True``), the first
        ``steps`` of them (default all)."""
        if self._trace is None:
            raise ValueError("this ContinuousSwarm was created with trace=False")
        rows = self._trace.rows[:steps]
        th = self.sim.thermals
        t_slots = int(th.valid[run].sum())

        def col(name: str) -> NDArray[Any]:
            return np.stack([r[name][run] for r in rows]) if rows else np.zeros((0, 0))

        return Trace(
            t=np.asarray(self._trace.t[:steps], dtype=np.float64), x=col("x"), y=col("y"),
            z=col("z"), heading=col("heading"), bank=col("bank"), airspeed=col("airspeed"),
            vz=col("vz"), alive=col("alive").astype(bool), cohesion=col("cohesion"),
            thermal_x=th.x[run, :t_slots].copy(), thermal_y=th.y[run, :t_slots].copy(),
            thermal_radius=th.radius[run, :t_slots].copy(),
            thermal_strength=col("thermal_strength")[:, :t_slots],
        )


def run_continuous(
    law: Law,
    *,
    seeds: Sequence[int] | None = None,
    flight: FlightParams | None = None,
    physics_rate_hz: float = 50.0,
    trace: bool = False,
) -> list[RunResult]:
    """Fly ``law`` once per seed (default ``[law.rngSeed]``), all runs in one batch, with the
    controller every ``law.dt`` and the continuous flight model integrated at
    ``physics_rate_hz`` in between. Results in seed order."""
    if not physics_rate_hz > 0:
        raise ValueError(f"physics_rate_hz: expected > 0, got {physics_rate_hz}")
    seed_list = [law.rngSeed] if seeds is None else [int(s) for s in seeds]
    if not seed_list:
        raise ValueError("seeds: expected at least one seed")
    swarm = ContinuousSwarm(law, seed=seed_list, flight=flight, trace=trace)
    sim = swarm.sim
    substeps = max(1, math.ceil(law.dt * physics_rate_hz - 1e-9))
    end = np.full(len(seed_list), -1, dtype=np.int64)
    while not sim.done:
        swarm.decide()
        fin = sim.finished
        end[fin & (end < 0)] = sim.step_count
        if sim.done:
            break
        swarm.advance(law.dt, substeps=substeps)
    return [
        RunResult(law=law, seed=s, metrics=sim.metrics(b),
                  steps=int(end[b]) if end[b] >= 0 else sim.step_count,
                  trace=swarm.trace(b, int(end[b]) if end[b] >= 0 else None) if trace else None)
        for b, s in enumerate(seed_list)
    ]

