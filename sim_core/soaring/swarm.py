"""Swarm stepping, metrics and runs: many gliders of many runs at once, one physics.

State arrays are (B, N): B runs (the batch), N glider slots (runs with fewer gliders are padded
with slots that are never alive). One step follows the seed's order (spec §3.1):

1. thermals fade (``staticStep``);
2. the state is saved; every glider reads its neighbours' *saved* state;
3. on step 1 and every ``neighborFrameSkip``-th step the neighbour lists are rebuilt (§3.6);
4. each alive glider: collision check (dies, does not move), Boids acceleration → commands (or
   the external commands of gliders flown by an autopilot), then the glider step
   (:func:`~sim_core.soaring.glider.fly`, the core of :func:`glider_step`);
5. deaths take effect; metrics accumulate from the saved state of the gliders still alive.

Cost: at N = 40 a step is numpy call overhead, so the step keeps the state as one
(STATE_ROWS, B, N) block updated in place, computes everything that depends only on the laws
once per batch (:class:`~sim_core.soaring.boids.AccelKernel`,
:class:`~sim_core.soaring.thermals.UpdraftField`, :class:`~sim_core.soaring.thermals.Fader`;
parameters equal in every run as Python floats) and sums the flight, height and thermal
scores from a short history. Each element still sees the same float64 operations in the same
order: ``tests/sim_core/soaring/test_soaring_pinned.py`` pins results from before.

Randomness: run b with seed s draws thermals then gliders from ``derive_rng(s, "soaring",
"spawn")`` and waggle signs from ``derive_rng(s, "soaring", "waggle")``, so a run's result is
bit-identical whatever batch it is stepped in. Sums over gliders and neighbours are sequential
(``cumsum``) for the same reason.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numpy.typing import NDArray

from sim_core.rng import derive_rng
from sim_core.soaring.boids import (
    AccelKernel,
    LawParams,
    find_neighbors,
    law_params,
    neighbor_pairs,
)
from sim_core.soaring.glider import (
    ROW_BANK,
    ROW_HEADING,
    ROW_OMEGA,
    ROW_SPEED,
    ROW_VX,
    ROW_VY,
    ROW_VZ,
    ROW_X,
    ROW_Y,
    ROW_Z,
    STATE_ROWS,
    command,
    fly,
    limits,
)
from sim_core.soaring.law import Law
from sim_core.soaring.thermals import (
    Fader,
    Thermals,
    UpdraftField,
    spawn_thermals,
    stack_thermals,
)
from sim_core.soaring.trace import Trace

__all__ = [
    "METRIC_NAMES",
    "Commands",
    "Metrics",
    "RunResult",
    "SwarmSim",
    "SwarmState",
    "batch_key",
    "run",
    "run_batch",
]

F8 = NDArray[np.float64]
B8 = NDArray[np.bool_]

METRIC_NAMES: tuple[str, ...] = (
    "surviving",
    "survivingPercent",
    "flightTime",
    "heightScore",
    "thermalUseScore",
    "explorationPercent",
    "collisionDeaths",
    "groundDeaths",
    "finalHeightMax",
    "finalHeightMin",
    "finalHeightAvg",
)


@dataclass(slots=True)
class SwarmState:
    """Glider state, struct of arrays (B, N): x, y, z m; heading rad (from +x); bank rad;
    speed (airspeed) m/s; omega (turn rate) rad/s; vz m/s (> 0 climbing); alive."""

    x: F8
    y: F8
    z: F8
    heading: F8
    bank: F8
    speed: F8
    omega: F8
    vz: F8
    alive: B8

    def copy(self) -> SwarmState:
        return SwarmState(*(np.array(getattr(self, f)) for f in _STATE_FIELDS))

    def select(self, runs: NDArray[np.intp]) -> SwarmState:
        return SwarmState(*(getattr(self, f)[runs] for f in _STATE_FIELDS))


_STATE_FIELDS = ("x", "y", "z", "heading", "bank", "speed", "omega", "vz", "alive")


@dataclass(frozen=True, slots=True)
class Commands:
    """External commands for gliders flown by an outside autopilot.

    bank_cmd rad and airspeed_cmd m/s, and ``mask`` (True = use these commands), each
    broadcastable to (B, N). Unmasked gliders fly the law's Boids controller. Commands are
    limited like the Boids ones (speed/bank limits, optional rate limits).
    """

    bank_cmd: NDArray[np.floating]
    airspeed_cmd: NDArray[np.floating]
    mask: NDArray[np.bool_]


@dataclass(frozen=True, slots=True)
class Metrics:
    """Seed 002 output metrics of one run (§3.8); survivingPercent is 0–100.

    finalHeightAvg is NaN when no glider is alive (:meth:`to_json` gives null).
    """

    surviving: int
    survivingPercent: float
    flightTime: float
    heightScore: float
    thermalUseScore: float
    explorationPercent: float
    collisionDeaths: int
    groundDeaths: int
    finalHeightMax: float
    finalHeightMin: float
    finalHeightAvg: float

    def to_dict(self) -> dict[str, Any]:
        return {name: getattr(self, name) for name in METRIC_NAMES}

    def to_json(self) -> dict[str, Any]:
        """As :meth:`to_dict`, with NaN replaced by None."""
        return {
            k: (None if isinstance(v, float) and math.isnan(v) else v)
            for k, v in self.to_dict().items()
        }


@dataclass(frozen=True, slots=True)
class RunResult:
    """One finished run: its law, seed, metrics, steps flown, and the trace if asked for."""

    law: Law
    seed: int
    metrics: Metrics
    steps: int
    trace: Trace | None = None


#: Steps of metric history summed at once (see SwarmSim._flush).
_HISTORY = 64


def batch_key(law: Law) -> tuple[Any, ...]:
    """Laws with equal keys can share a batch (same dt, duration and frame skips)."""
    return (law.dt, law.steps, law.neighborFrameSkip, law.mapDivFrameSkip,
            law.mapDivResolution, law.stopWhenDead)


def _seqsum(a: NDArray[Any], axis: int) -> NDArray[Any]:
    """Sum along ``axis`` strictly in index order (independent of shape and padding)."""
    if a.shape[axis] == 0:
        return np.sum(a, axis=axis)
    return np.take(np.cumsum(a, axis=axis), -1, axis=axis)


def _spawn_agents(law: Law, rng: np.random.Generator) -> dict[str, F8]:
    """Initial glider state of one run (§3.5), arrays (N,)."""
    if law.agents is not None:
        a = np.array(
            [[p.x, p.y, p.z, p.heading, p.speed, 0.0] for p in law.agents], dtype=np.float64
        ).reshape(-1, 6)
    else:
        n = law.numAgents
        u = rng.random((n, 6))
        (x0, y0), (x1, y1) = law.agentSpawnPosRange
        z0, z1 = law.agentSpawnAltiRange
        (v0, w0), (v1, w1) = law.agentSpawnVelRange
        lo = np.array([x0, y0, z0, 0.0, v0, w0])
        hi = np.array([x1, y1, z1, 2 * math.pi, v1, w1])
        a = lo + (hi - lo) * u
    return {"x": a[:, 0], "y": a[:, 1], "z": a[:, 2], "heading": a[:, 3], "speed": a[:, 4],
            "omega": a[:, 5]}


@dataclass(slots=True)
class _Acc:
    """Metric accumulators, (B,) arrays (visited: (B, res*res)). flight, height and thermal
    lag behind by the steps held in SwarmSim's history until it is flushed; the final heights
    are computed on demand from the last step's saved altitudes and alive mask."""

    n_agents: NDArray[np.int64]
    living: NDArray[np.int64]
    flight: F8
    height: F8
    thermal: F8
    visited: B8
    coll: NDArray[np.int64]
    ground: NDArray[np.int64]

    def select(self, runs: NDArray[np.intp]) -> _Acc:
        return _Acc(*(getattr(self, f)[runs] for f in self.__slots__))


@dataclass(slots=True)
class _TraceBuf:
    t: list[float] = field(default_factory=list)
    rows: list[dict[str, NDArray[np.generic]]] = field(default_factory=list)


class SwarmSim:
    """Step B soaring runs of N gliders at once.

    ``SwarmSim(law, seed=s, batch=B)`` runs the law B times with seeds s, s+1, ..., s+B−1
    (``seed=None``: the law's ``rngSeed``). ``SwarmSim([law_0, law_1, ...], seed=[s0, s1, ...])``
    runs different laws (same :func:`batch_key`); seeds default to each law's ``rngSeed``.

    ``state`` (copies, (B, N)), ``step(commands=None)``, ``neighbors(i, run=0)``,
    ``metrics(run=0)``, ``done`` (every run finished: all steps flown, or all gliders dead with
    stopWhenDead), ``thermals`` (copy), ``updraft_at(xy)``.
    """

    def __init__(
        self,
        law: Law | Sequence[Law],
        *,
        seed: int | Sequence[int] | None = None,
        batch: int = 1,
        trace: bool = False,
    ) -> None:
        if isinstance(law, Law):
            if batch < 1:
                raise ValueError(f"batch must be >= 1, got {batch}")
            base = law.rngSeed if seed is None else seed
            if not isinstance(base, int):
                raise ValueError(f"seed must be an int with a single law, got {seed!r}")
            laws: list[Law] = [law] * batch
            seeds = [base + b for b in range(batch)]
        else:
            laws = list(law)
            if not laws:
                raise ValueError("SwarmSim needs at least one law")
            if seed is None:
                seeds = [lw.rngSeed for lw in laws]
            elif isinstance(seed, int):
                seeds = [seed + b for b in range(len(laws))]
            else:
                seeds = [int(s) for s in seed]
            if len(seeds) != len(laws):
                raise ValueError(f"{len(laws)} laws need {len(laws)} seeds, got {len(seeds)}")
        keys = {batch_key(lw) for lw in laws}
        if len(keys) != 1:
            raise ValueError(
                "laws of one batch must share dt, totalTime, neighborFrameSkip, "
                f"mapDivFrameSkip, mapDivResolution and stopWhenDead; got {sorted(keys)}"
            )
        self.laws = laws
        self.seeds = seeds
        self.run_ids = np.arange(len(laws))
        first = laws[0]
        self.dt = first.dt
        self.total_steps = first.steps
        self._nfs = first.neighborFrameSkip
        self._mfs = first.mapDivFrameSkip
        self._res = first.mapDivResolution
        self._stop_when_dead = first.stopWhenDead
        self.P: LawParams = law_params(laws)
        B = len(laws)
        n = max(lw.n_agents for lw in laws)
        self._width = max(0, min(max(lw.k for lw in laws), n - 1))
        ths: list[Thermals] = []
        st = {f: np.zeros((B, n)) for f in ("x", "y", "z", "heading", "speed", "omega")}
        alive = np.zeros((B, n), dtype=bool)
        for b, (lw, s) in enumerate(zip(laws, seeds, strict=True)):
            rng = derive_rng(s, "soaring", "spawn")
            ths.append(spawn_thermals(lw, rng))
            ag = _spawn_agents(lw, rng)
            m = lw.n_agents
            for f in st:
                st[f][b, :m] = ag[f]
            alive[b, :m] = True
        self._thermals = stack_thermals(ths)
        # glider state rows (STATE_ROWS, B, N), updated in place (layout: glider.ROW_*)
        self._S = np.zeros((STATE_ROWS, B, n))
        for f, row in (("x", ROW_X), ("y", ROW_Y), ("z", ROW_Z), ("heading", ROW_HEADING),
                       ("speed", ROW_SPEED), ("omega", ROW_OMEGA)):
            self._S[row] = st[f]
        self._alive = alive
        self._z_saved = self._S[ROW_Z].copy()
        self._waggle_rngs = [derive_rng(s, "soaring", "waggle") for s in seeds]
        self._waggle_sign = np.zeros((B, n))
        self._waggle_left = np.zeros((B, n))
        self._nb_idx = np.zeros((self._width, B, n), dtype=np.intp)
        self._nb_valid = np.zeros((self._width, B, n), dtype=bool)
        self._pending: tuple[NDArray[np.intp], B8] | None = None
        self._owner = np.zeros(0, dtype=np.intp)
        self._other = np.zeros(0, dtype=np.intp)
        self._setup()
        self.cohesion_mag = np.zeros((B, n))
        self.step_count = 0
        n_agents = np.array([lw.n_agents for lw in laws], dtype=np.int64)
        self._map_min = np.array([lw.mapSize[0] for lw in laws])[:, None]
        self._cell = np.array([(lw.mapSize[1] - lw.mapSize[0]) / self._res for lw in laws])[:, None]
        self._acc = _Acc(
            n_agents=n_agents,
            living=n_agents.copy(),
            flight=np.zeros(B),
            height=np.zeros(B),
            thermal=np.zeros(B),
            visited=np.zeros((B, self._res * self._res), dtype=bool),
            coll=np.zeros(B, dtype=np.int64),
            ground=np.zeros(B, dtype=np.int64),
        )
        self._end_step = np.full(B, -1, dtype=np.int64)
        self._update_finished()
        self._any_finished = bool(self._finished.any())
        self._trace: _TraceBuf | None = _TraceBuf() if trace else None
        if self._trace is not None:
            self._record()

    def _setup(self) -> None:
        """Everything the step needs that depends only on the laws, the thermal slots and
        the shapes: kernels, work buffers, flags (at construction and after :meth:`_keep`)."""
        P, (B, n) = self.P, self._alive.shape
        self._kernel = AccelKernel(P, B, n)
        self._kernel.set_pairs(self._owner, self._other)
        self._updraft = UpdraftField(self._thermals, n)
        self._fader = Fader(self._thermals, by_time=P["fade_by_time"], rate=P["fade_rate"],
                            top=P["fade_top"], bottom=P["fade_bottom"], dt=self.dt)
        self._new = np.zeros((STATE_ROWS, B, n))
        self._cs = np.empty((2, B, n))
        # per-step history of the saved (z, vz) and of the alive mask and count after the
        # step; flight, height and thermal scores are summed from it every _HISTORY steps
        self._zv_hist = np.empty((_HISTORY, 2, B, n))
        self._alive_hist: list[B8] = []
        self._living_hist: list[NDArray[np.int64]] = []
        self._waggle_runs = np.flatnonzero(P["waggle"][:, 0] != 0)
        sc = P.scalar
        self._cmd_kw: dict[str, Any] = {"dt": self.dt, "g": sc("g"),
                                        "thermal_bank_factor": sc("thermalBankFactor")}
        lo, hi = limits((sc("forwardSpeedMin"), sc("bankMin")),
                        (sc("forwardSpeedMax"), sc("bankMax")))
        self._fly_kw: dict[str, Any] = {
            "dt": self.dt, "g": sc("g"), "cmd_min": lo, "cmd_max": hi,
            "sink_abc": (sc("Sink_A"), sc("Sink_B"), sc("Sink_C")),
            "ceiling": sc("agentCeiling"), "floor": sc("agentFloor"),
        }
        self._cmd = np.empty((2, B, n))  # (airspeed_cmd, bank_cmd)
        for name in ("bank_rate_max", "speed_rate_max"):
            self._fly_kw[name] = None if np.isinf(P[name] * self.dt).all() else P[name]

    # -- read-only views ---------------------------------------------------------------------
    @property
    def batch(self) -> int:
        return len(self.laws)

    @property
    def _state(self) -> SwarmState:
        """The glider state as views of the internal rows (not copies)."""
        S = self._S
        return SwarmState(
            x=S[ROW_X], y=S[ROW_Y], z=S[ROW_Z], heading=S[ROW_HEADING], bank=S[ROW_BANK],
            speed=S[ROW_SPEED], omega=S[ROW_OMEGA], vz=S[ROW_VZ], alive=self._alive,
        )

    @property
    def state(self) -> SwarmState:
        """A copy of the glider state, arrays (B, N)."""
        return self._state.copy()

    @property
    def thermals(self) -> Thermals:
        """A copy of the thermal state, arrays (B, T)."""
        return self._thermals.copy()

    @property
    def time_s(self) -> float:
        """Simulated time flown, s."""
        return self.step_count * self.dt

    @property
    def finished(self) -> B8:
        """(B,) True for runs that have ended (all steps, or all dead with stopWhenDead)."""
        return self._finished.copy()

    def _update_finished(self) -> None:
        out = self.step_count >= self.total_steps
        if self._stop_when_dead:
            self._finished = np.asarray(out | ((self._acc.living == 0) & (self.step_count >= 1)))
        else:
            self._finished = np.full(self.batch, out)

    @property
    def done(self) -> bool:
        return bool(self._finished.all())

    def updraft_at(self, xy: NDArray[np.floating]) -> F8:
        """w m/s at points xy (B, M, 2) → (B, M) for the current thermals."""
        pts = np.asarray(xy, dtype=np.float64)
        return UpdraftField(self._thermals, pts.shape[1])(np.moveaxis(pts, -1, 0))

    def _refreshes(self, step: int) -> bool:
        return step == 1 or step % self._nfs == 0

    def _lists_for(self, step: int) -> tuple[NDArray[np.intp], B8]:
        """Neighbour lists (K, B, N) that step ``step`` (the next one) uses; a refresh is
        computed from the current state once and reused by :meth:`step`."""
        if not self._refreshes(step):
            return self._nb_idx, self._nb_valid
        if self._pending is None:
            s = self._state
            idx, valid = find_neighbors(s.x, s.y, s.z, s.heading, s.alive, self.P,
                                        width=self._width)
            # a dead glider flies no more: it needs no list (it can still be in others' lists)
            self._pending = (idx, valid & s.alive[None])
        return self._pending

    def neighbors(self, i: int, run: int = 0) -> list[int]:
        """Neighbour list of glider i (the seed's KNN in radius and FOV), nearest first: the
        list the *next* step will use, i.e. rebuilt from the current (to-be-saved) state when
        that step refreshes (step 1 and every neighborFrameSkip-th), else the stale list.
        A dead glider may stay in a list until the next refresh, as in the seed."""
        n = self._alive.shape[1]
        if not 0 <= i < n:
            raise ValueError(f"glider index {i} out of range 0..{n - 1}")
        if not 0 <= run < self.batch:
            raise ValueError(f"run index {run} out of range 0..{self.batch - 1}")
        idx, valid = self._lists_for(self.step_count + 1)
        return [int(j) for j, ok in zip(idx[:, run, i], valid[:, run, i], strict=True) if ok]

    def metrics(self, run: int = 0) -> Metrics:
        """Metrics of one run so far (final once the run is finished)."""
        self._flush()
        a = self._acc
        n_agents = int(a.n_agents[run])
        living = int(a.living[run])
        started = self.step_count >= 1
        hmax, hmin, havg = self._final_heights(run)
        return Metrics(
            surviving=living,
            survivingPercent=100.0 * living / n_agents if n_agents else 0.0,
            flightTime=float(a.flight[run]),
            heightScore=float(a.height[run]),
            thermalUseScore=float(a.thermal[run]),
            explorationPercent=100.0 * int(a.visited[run].sum()) / self._res**2,
            collisionDeaths=int(a.coll[run]),
            groundDeaths=int(a.ground[run]),
            finalHeightMax=hmax,
            finalHeightMin=hmin,
            finalHeightAvg=havg if started else math.nan,
        )

    def _final_heights(self, run: int) -> tuple[float, float, float]:
        """Max, min and mean altitude, m, of the gliders alive after the last step, at their
        saved (pre-step) altitudes; max/min start from the floor/ceiling (seed §3.8)."""
        floor = float(self.P["agentFloor"][run, 0])
        ceil = float(self.P["agentCeiling"][run, 0])
        if self.step_count < 1:
            return floor, ceil, math.nan
        alive, z = self._alive[run : run + 1], self._z_saved[run : run + 1]
        if alive.shape[1]:
            hmax = np.maximum(floor, np.max(np.where(alive, z, -np.inf), axis=1))
            hmin = np.minimum(ceil, np.min(np.where(alive, z, np.inf), axis=1))
        else:
            hmax, hmin = np.array([floor]), np.array([ceil])
        zsum = _seqsum(np.where(alive, z, 0.0), axis=1)
        with np.errstate(invalid="ignore", divide="ignore"):
            havg = zsum / alive.sum(axis=1)
        return float(hmax[0]), float(hmin[0]), float(havg[0])

    def all_metrics(self) -> list[Metrics]:
        return [self.metrics(b) for b in range(self.batch)]

    # -- stepping ----------------------------------------------------------------------------
    def step(self, commands: Commands | None = None) -> None:
        """Advance every run by one step of dt (see the module docstring for the order)."""
        self.step_count += 1
        step = self.step_count
        S, alive = self._S, self._alive
        self._fader.step()
        B, n = alive.shape
        if self._refreshes(step):
            idx, valid = self._lists_for(step)
            self._pending = None
            self._nb_idx, self._nb_valid = idx, valid
            self._owner, self._other = neighbor_pairs(idx, valid)
            self._kernel.set_pairs(self._owner, self._other)
        heading, speed, z = S[ROW_HEADING], S[ROW_SPEED], S[ROW_Z]
        cs = self._cs
        np.cos(heading, out=cs[0])
        np.sin(heading, out=cs[1])
        np.multiply(speed, cs, out=S[ROW_VX : ROW_VY + 1])
        xy = S[ROW_X : ROW_Y + 1]
        w_th = self._updraft(xy)
        external = (
            None if commands is None
            else (np.broadcast_to(np.asarray(commands.mask, dtype=bool), (B, n)), commands)
        )
        if self._waggle_runs.size:
            self._update_waggle(alive if external is None else alive & ~external[0])
        kern = self._kernel
        a, collision, self.cohesion_mag = kern.accel(
            kern.load(S[: ROW_VZ + 1].reshape(ROW_VZ + 1, B * n)), z, xy, cs, self._waggle_sign
        )
        cmd = self._cmd
        command(cmd, a, cs, speed, updraft=w_th, **self._cmd_kw)
        if external is not None:
            mask, ext = external
            np.copyto(cmd[0], np.asarray(ext.airspeed_cmd, dtype=np.float64), where=mask)
            np.copyto(cmd[1], np.asarray(ext.bank_cmd, dtype=np.float64), where=mask)
        new = self._new
        ground = fly(new, xy, z, heading, S[ROW_BANK], speed, cmd, w_th, cs, **self._fly_kw)
        deaths = bool(((collision | ground) & alive).any())
        if deaths:
            collided = alive & collision
            flew = alive & ~collided
            grounded = flew & ground
            self._alive = alive & ~collided & ~grounded
            self._update_metrics(step, collided, grounded, deaths)
            # the saved state is no longer needed: the gliders that moved take the new state
            np.copyto(S[ROW_X:ROW_BANK], new[ROW_X:ROW_BANK], where=flew & ~grounded)
            np.copyto(S[ROW_BANK], new[ROW_BANK], where=flew)
        else:  # every alive glider flew and moved
            self._update_metrics(step, alive, alive, deaths)
            np.copyto(S[ROW_X:], new[ROW_X:], where=alive)
        if deaths or step == 1 or step >= self.total_steps:
            self._update_finished()
            self._any_finished = bool(self._finished.any())
        if self._any_finished:
            self._end_step[self._finished & (self._end_step < 0)] = step
        if self._trace is not None:
            self._record()

    def _update_waggle(self, flying: B8) -> None:
        for b in self._waggle_runs:
            due = np.flatnonzero(flying[b] & (self._waggle_left[b] <= 0))
            if due.size:
                lo, hi = self.laws[b].waggleDurationRange
                u = self._waggle_rngs[b].random((due.size, 2))
                self._waggle_sign[b, due] = 2.0 * np.floor(u[:, 0] + 0.5) - 1.0
                self._waggle_left[b, due] = lo + (hi - lo) * u[:, 1]
            self._waggle_left[b] = np.where(flying[b], self._waggle_left[b] - self.dt,
                                            self._waggle_left[b])

    def _update_metrics(self, step: int, collided: B8, grounded: B8, deaths: bool) -> None:
        """Accumulate the metrics of a step from the saved state (still in ``_S``) of the
        gliders alive after it (``deaths``: whether any glider died in the step; without,
        ``collided`` and ``grounded`` are not read)."""
        a, alive, S = self._acc, self._alive, self._S
        if deaths:
            a.coll += collided.sum(axis=1)
            a.ground += grounded.sum(axis=1)
            a.living = alive.sum(axis=1)
        # alive masks and counts are replaced, never modified, so references suffice
        k = len(self._alive_hist)
        self._zv_hist[k] = S[ROW_Z : ROW_VZ + 1]
        self._alive_hist.append(alive)
        self._living_hist.append(a.living)
        if k + 1 == _HISTORY:
            self._flush()
        if step == 1 or step % self._mfs == 0:
            x, y = S[ROW_X], S[ROW_Y]
            ix = np.ceil((x - self._map_min) / self._cell).astype(np.int64)
            iy = np.ceil((y - self._map_min) / self._cell).astype(np.int64)
            res = self._res
            inside = alive & (ix > 0) & (ix <= res) & (iy > 0) & (iy <= res)
            rows, cols = np.nonzero(inside)
            a.visited[rows, (ix[rows, cols] - 1) * res + (iy[rows, cols] - 1)] = True

    def _flush(self) -> None:
        """Add the steps in the history to flightTime, heightScore and thermalUseScore, with
        the same sequential sums as step-by-step accumulation: each score is the running sum
        over steps (and, for heightScore, over the gliders within a step) of
        living·dt, alive·z·dt and (alive & vz > 0)·dt."""
        c = len(self._alive_hist)
        if c == 0:
            return
        a, dt = self._acc, self.dt
        zv = self._zv_hist[:c]
        alive = np.stack(self._alive_hist)  # (c, B, N)
        B, n = alive.shape[1:]
        seq = np.empty((c + 1, B))
        seq[0] = a.flight
        np.multiply(np.stack(self._living_hist), dt, out=seq[1:])
        a.flight = np.cumsum(seq, axis=0)[-1]
        seq[0] = a.thermal
        np.multiply((alive & (zv[:, 1] > 0)).sum(axis=2), dt, out=seq[1:])
        a.thermal = np.cumsum(seq, axis=0)[-1]
        zdt = zv[:, 0] * dt
        zdt[~alive] = 0.0
        h = np.empty((B, 1 + c * n))
        h[:, 0] = a.height
        h[:, 1:] = zdt.transpose(1, 0, 2).reshape(B, c * n)
        a.height = np.cumsum(h, axis=1)[:, -1]
        self._z_saved = zv[c - 1, 0].copy()
        self._alive_hist.clear()
        self._living_hist.clear()

    def _record(self) -> None:
        buf = self._trace
        if buf is None:
            return
        s = self._state
        buf.t.append(self.step_count * self.dt)
        # copies: the state and the thermal strengths are updated in place
        buf.rows.append({
            "x": s.x.copy(), "y": s.y.copy(), "z": s.z.copy(), "heading": s.heading.copy(),
            "bank": s.bank.copy(), "airspeed": s.speed.copy(), "vz": s.vz.copy(),
            "alive": s.alive, "cohesion": self.cohesion_mag,
            "thermal_strength": self._thermals.strength.copy(),
        })

    def trace(self, run: int = 0) -> Trace:
        """The recorded trace of one run (``trace=True``), up to the step it finished."""
        if self._trace is None:
            raise ValueError("this SwarmSim was created with trace=False")
        end = self._end_step[run]
        count = (end if end >= 0 else self.step_count) + 1
        m = self.laws[run].n_agents
        rows = self._trace.rows[:count]
        t_slots = int(self._thermals.valid[run].sum())

        def col(name: str, width: int) -> NDArray[Any]:
            return np.stack([r[name][run, :width] for r in rows]) if rows else np.zeros((0, width))

        return Trace(
            t=np.asarray(self._trace.t[:count], dtype=np.float64),
            x=col("x", m), y=col("y", m), z=col("z", m), heading=col("heading", m),
            bank=col("bank", m), airspeed=col("airspeed", m), vz=col("vz", m),
            alive=col("alive", m).astype(bool), cohesion=col("cohesion", m),
            thermal_x=self._thermals.x[run, :t_slots].copy(),
            thermal_y=self._thermals.y[run, :t_slots].copy(),
            thermal_radius=self._thermals.radius[run, :t_slots].copy(),
            thermal_strength=col("thermal_strength", t_slots),
        )

    def _keep(self, runs: NDArray[np.intp]) -> None:
        """Drop every run not in ``runs`` (used to stop stepping finished runs)."""
        self._flush()
        self.laws = [self.laws[r] for r in runs]
        self.seeds = [self.seeds[r] for r in runs]
        self.run_ids = self.run_ids[runs]
        self.P = self.P.select(runs)
        self._thermals = self._thermals.select(runs)
        self._S = self._S[:, runs]
        self._alive = self._alive[runs]
        self._z_saved = self._z_saved[runs]
        self._waggle_rngs = [self._waggle_rngs[r] for r in runs]
        self._waggle_sign = self._waggle_sign[runs]
        self._waggle_left = self._waggle_left[runs]
        self._pending = None
        self._nb_idx = self._nb_idx[:, runs]
        self._nb_valid = self._nb_valid[:, runs]
        self._owner, self._other = neighbor_pairs(self._nb_idx, self._nb_valid)
        self.cohesion_mag = self.cohesion_mag[runs]
        self._map_min = self._map_min[runs]
        self._cell = self._cell[runs]
        self._acc = self._acc.select(runs)
        self._end_step = self._end_step[runs]
        self._finished = self._finished[runs]
        self._any_finished = bool(self._finished.any())
        self._setup()


def run(law: Law, *, seed: int | None = None, trace: bool = False) -> RunResult:
    """Fly one run to the end (``seed=None``: ``law.rngSeed``)."""
    return run_batch([law], seeds=None if seed is None else [seed], trace=trace)[0]


def run_batch(
    laws: Sequence[Law],
    *,
    seeds: Sequence[int] | None = None,
    trace: bool = False,
    compact_every: int = 50,
) -> list[RunResult]:
    """Fly many runs at once, vectorised over (runs, gliders); results in input order.

    Laws are grouped by :func:`batch_key` (same dt, duration, frame skips); within a group,
    finished runs are dropped from the batch every ``compact_every`` steps. Each result is
    bit-identical to running that law alone.
    """
    laws = list(laws)
    seed_list = [lw.rngSeed for lw in laws] if seeds is None else [int(s) for s in seeds]
    if len(seed_list) != len(laws):
        raise ValueError(f"{len(laws)} laws need {len(laws)} seeds, got {len(seed_list)}")
    groups: dict[tuple[Any, ...], list[int]] = {}
    for i, lw in enumerate(laws):
        groups.setdefault(batch_key(lw), []).append(i)
    results: list[RunResult | None] = [None] * len(laws)
    for members in groups.values():
        sim = SwarmSim([laws[i] for i in members], seed=[seed_list[i] for i in members],
                       trace=trace)
        while not sim.done:
            sim.step()
            if not trace and sim.step_count % compact_every == 0:
                fin = sim.finished
                if fin.any() and not fin.all():
                    _collect(sim, np.flatnonzero(fin), members, seed_list, results, trace)
                    sim._keep(np.flatnonzero(~fin))
        _collect(sim, np.arange(sim.batch), members, seed_list, results, trace)
    return [r for r in results if r is not None]



def _collect(
    sim: SwarmSim,
    rows: NDArray[np.intp],
    members: list[int],
    seeds: list[int],
    results: list[RunResult | None],
    trace: bool,
) -> None:
    """Store the results of batch rows ``rows`` at their input positions."""
    for r in rows:
        ri = int(r)
        i = members[int(sim.run_ids[ri])]
        end = int(sim._end_step[ri])
        results[i] = RunResult(
            law=sim.laws[ri], seed=seeds[i], metrics=sim.metrics(ri),
            steps=end if end >= 0 else sim.step_count,
            trace=sim.trace(ri) if trace else None,
        )
