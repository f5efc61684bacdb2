"""Swarm stepping, metrics and runs: many gliders of many runs at once, one physics.

State arrays are (B, N): B runs (the batch), N glider slots (runs with fewer gliders are padded
with slots that are never alive). One step follows the seed's order (spec §3.1):

1. thermals fade (``staticStep``);
2. the state is saved; every glider reads its neighbours' *saved* state;
3. on step 1 and every ``neighborFrameSkip``-th step the neighbour lists are rebuilt (§3.6);
4. each alive glider: collision check (dies, does not move), Boids acceleration → commands (or
   the external commands of gliders flown by an autopilot), then the glider step;
5. deaths take effect; metrics accumulate from the saved state of the gliders still alive.

The step is :func:`sim_core.soaring.kernels.advance` (compiled); this module holds the state
between calls, draws the randomness, and turns accumulators into :class:`Metrics`. A run
without trace, waggle or external commands is flown to its end in one kernel call.

Randomness: run b with seed s draws thermals then gliders from ``derive_rng(s, "soaring",
"spawn")`` and waggle signs from ``derive_rng(s, "soaring", "waggle")``, so a run's result is
bit-identical whatever batch it is stepped in (the kernels sum in index order for the same
reason).
"""
from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numpy.typing import NDArray

from sim_core.rng import derive_rng
from sim_core.soaring import kernels
from sim_core.soaring.boids import LawParams, law_params
from sim_core.soaring.law import Law
from sim_core.soaring.thermals import Thermals, spawn_thermals, stack_thermals
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
    stopWhenDead), ``thermals`` (copy), ``updraft_at(xy)``, ``cohesion_mag`` (B, N) ‖K_c·c‖
    of the last step.
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
        width = max(0, min(max(lw.k for lw in laws), n - 1))
        ths: list[Thermals] = []
        # glider state rows (STATE_ROWS, B, N), updated in place (layout: kernels.ROW_*)
        self._S = np.zeros((kernels.STATE_ROWS, B, n))
        self._alive = np.zeros((B, n), dtype=bool)
        for b, (lw, s) in enumerate(zip(laws, seeds, strict=True)):
            rng = derive_rng(s, "soaring", "spawn")
            ths.append(spawn_thermals(lw, rng))
            ag = _spawn_agents(lw, rng)
            m = lw.n_agents
            for f, row in (("x", kernels.ROW_X), ("y", kernels.ROW_Y), ("z", kernels.ROW_Z),
                           ("heading", kernels.ROW_HEADING), ("speed", kernels.ROW_SPEED),
                           ("omega", kernels.ROW_OMEGA)):
                self._S[row, b, :m] = ag[f]
            self._alive[b, :m] = True
        self._th, self._th_on = stack_thermals(ths).block()
        self._z_saved = self._S[kernels.ROW_Z].copy()
        self._waggle_rngs = [derive_rng(s, "soaring", "waggle") for s in seeds]
        self._waggle_sign = np.zeros((B, n))
        self._waggle_left = np.zeros((B, n))
        self._waggle_runs = np.flatnonzero(self.P["waggle"][:, 0] != 0)
        self._nb = np.zeros((B, n, width), dtype=np.int64)
        self._cnt = np.zeros((B, n), dtype=np.int64)
        self._peek: tuple[int, NDArray[np.int64], NDArray[np.int64]] | None = None
        self._ext_on = np.zeros((B, n), dtype=bool)
        self._ext_cmd = np.zeros((2, B, n))
        self._coh = np.zeros((B, n))
        self._scratch = np.zeros((5, B, n))
        self.step_count = 0
        self._accf = np.zeros((3, B))
        self._acci = np.zeros((4, B), dtype=np.int64)
        self._acci[kernels.CNT_AGENTS] = [lw.n_agents for lw in laws]
        self._acci[kernels.CNT_LIVING] = self._acci[kernels.CNT_AGENTS]
        self._visited = np.zeros((B, self._res * self._res), dtype=bool)
        self._finished = np.zeros(B, dtype=bool)
        self._end_step = np.full(B, -1, dtype=np.int64)
        if self.total_steps <= 0:
            self._finished[:] = True
        self._trace: _TraceBuf | None = _TraceBuf() if trace else None
        if self._trace is not None:
            self._record()
        # load the compiled step and search now (compile them, the first time on a machine),
        # not in the first step of a realtime run
        self._kernel(0, skip_finished=False)
        self._next_lists()

    # -- read-only views ---------------------------------------------------------------------
    @property
    def batch(self) -> int:
        return len(self.laws)

    @property
    def _state(self) -> SwarmState:
        """The glider state as views of the internal rows (not copies)."""
        S, k = self._S, kernels
        return SwarmState(
            x=S[k.ROW_X], y=S[k.ROW_Y], z=S[k.ROW_Z], heading=S[k.ROW_HEADING], bank=S[k.ROW_BANK],
            speed=S[k.ROW_SPEED], omega=S[k.ROW_OMEGA], vz=S[k.ROW_VZ], alive=self._alive,
        )

    @property
    def state(self) -> SwarmState:
        """A copy of the glider state, arrays (B, N)."""
        return self._state.copy()

    @property
    def thermals(self) -> Thermals:
        """A copy of the thermal state, arrays (B, T)."""
        return Thermals.from_block(self._th, self._th_on)

    @property
    def cohesion_mag(self) -> F8:
        """‖K_c·c‖ of every glider in the last step, (B, N) (a view, updated by each step)."""
        return self._coh

    @property
    def time_s(self) -> float:
        """Simulated time flown, s."""
        return self.step_count * self.dt

    @property
    def finished(self) -> B8:
        """(B,) True for runs that have ended (all steps, or all dead with stopWhenDead)."""
        return self._finished.copy()

    @property
    def done(self) -> bool:
        return bool(self._finished.all())

    def updraft_at(self, xy: NDArray[np.floating]) -> F8:
        """w m/s at points xy (B, M, 2) → (B, M) for the current thermals."""
        pts = np.asarray(xy, dtype=np.float64)
        return np.asarray(kernels.updraft_many(np.array(pts[..., 0]), np.array(pts[..., 1]),
                                         self._th, self._th_on))

    def _refreshes(self, step: int) -> bool:
        return step == 1 or step % self._nfs == 0

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
        nb, cnt = self._next_lists()
        return [int(j) for j in nb[run, i, : cnt[run, i]]]

    def _next_lists(self) -> tuple[NDArray[np.int64], NDArray[np.int64]]:
        """The lists (B, N, K) and counts (B, N) the next step uses (computed once per step)."""
        if not self._refreshes(self.step_count + 1):
            return self._nb, self._cnt
        if self._peek is None or self._peek[0] != self.step_count:
            nb, cnt = np.zeros_like(self._nb), np.zeros_like(self._cnt)
            kernels.lists_many(self._S.copy(), self._alive, self.P.table, nb, cnt, True)
            self._peek = (self.step_count, nb, cnt)
        return self._peek[1], self._peek[2]

    def metrics(self, run: int = 0) -> Metrics:
        """Metrics of one run so far (final once the run is finished)."""
        n_agents = int(self._acci[kernels.CNT_AGENTS, run])
        living = int(self._acci[kernels.CNT_LIVING, run])
        started = self.step_count >= 1
        hmax, hmin, havg = self._final_heights(run)
        return Metrics(
            surviving=living,
            survivingPercent=100.0 * living / n_agents if n_agents else 0.0,
            flightTime=float(self._accf[kernels.ACC_FLIGHT, run]),
            heightScore=float(self._accf[kernels.ACC_HEIGHT, run]),
            thermalUseScore=float(self._accf[kernels.ACC_THERMAL, run]),
            explorationPercent=100.0 * int(self._visited[run].sum()) / self._res**2,
            collisionDeaths=int(self._acci[kernels.CNT_COLL, run]),
            groundDeaths=int(self._acci[kernels.CNT_GROUND, run]),
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
        """Advance every run by one step of dt (see the module docstring for the order).

        Finished runs are stepped too (a run past its last step keeps flying)."""
        self._ext_on[...] = False
        if commands is not None:
            shape = self._ext_on.shape
            np.copyto(self._ext_on, np.broadcast_to(np.asarray(commands.mask, dtype=bool),
                                                    shape))
            np.copyto(self._ext_cmd[0], np.broadcast_to(
                np.asarray(commands.airspeed_cmd, dtype=np.float64), shape))
            np.copyto(self._ext_cmd[1], np.broadcast_to(
                np.asarray(commands.bank_cmd, dtype=np.float64), shape))
        self._advance(1, skip_finished=False)
        if self._trace is not None:
            self._record()

    def _advance(self, steps: int, *, skip_finished: bool) -> int:
        """Up to ``steps`` steps of the kernel (waggle signs drawn before each step)."""
        if self._waggle_runs.size:
            flown = 0
            for _ in range(steps):
                if skip_finished and self._finished.all():
                    break
                self._update_waggle(self._alive & ~self._ext_on)
                flown += self._kernel(1, skip_finished)
            return flown
        return self._kernel(steps, skip_finished)

    def _kernel(self, steps: int, skip_finished: bool) -> int:
        flown = int(kernels.advance(
            steps, self.step_count, self.total_steps, self._nfs, self._mfs, self._res, self.dt,
            self._stop_when_dead, skip_finished, self._S, self._alive, self._nb, self._cnt,
            self._th, self._th_on, self.P.table, self._ext_on, self._ext_cmd,
            self._waggle_sign, self._accf, self._acci, self._visited, self._z_saved, self._coh,
            self._finished, self._end_step, self._scratch,
        ))
        self.step_count += flown
        self._peek = None
        return flown

    def set_state(self, state: SwarmState) -> None:
        """Take the gliders' position, heading, bank, speed, omega and vz (arrays (B, N)) from
        a flight flown outside the step (:mod:`sim_core.continuous_swarm` flies the gliders
        between steps); ``state.alive`` is ignored (deaths are the step's)."""
        k = kernels
        for name, row in (("x", k.ROW_X), ("y", k.ROW_Y), ("z", k.ROW_Z),
                          ("heading", k.ROW_HEADING), ("bank", k.ROW_BANK),
                          ("speed", k.ROW_SPEED), ("omega", k.ROW_OMEGA), ("vz", k.ROW_VZ)):
            self._S[row] = getattr(state, name)
        self._peek = None  # neighbour lists looked up ahead came from the old state

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
            "alive": s.alive.copy(), "cohesion": self._coh.copy(),
            "thermal_strength": self._th[kernels.TH_W].copy(),
        })

    def trace(self, run: int = 0) -> Trace:
        """The recorded trace of one run (``trace=True``), up to the step it finished."""
        if self._trace is None:
            raise ValueError("this SwarmSim was created with trace=False")
        end = self._end_step[run]
        count = (end if end >= 0 else self.step_count) + 1
        m = self.laws[run].n_agents
        rows = self._trace.rows[:count]
        t_slots = int(self._th_on[kernels.ON_VALID, run].sum())

        def col(name: str, width: int) -> NDArray[Any]:
            return np.stack([r[name][run, :width] for r in rows]) if rows else np.zeros((0, width))

        return Trace(
            t=np.asarray(self._trace.t[:count], dtype=np.float64),
            x=col("x", m), y=col("y", m), z=col("z", m), heading=col("heading", m),
            bank=col("bank", m), airspeed=col("airspeed", m), vz=col("vz", m),
            alive=col("alive", m).astype(bool), cohesion=col("cohesion", m),
            thermal_x=self._th[kernels.TH_X, run, :t_slots].copy(),
            thermal_y=self._th[kernels.TH_Y, run, :t_slots].copy(),
            thermal_radius=self._th[kernels.TH_R, run, :t_slots].copy(),
            thermal_strength=col("thermal_strength", t_slots),
        )


def run(law: Law, *, seed: int | None = None, trace: bool = False) -> RunResult:
    """Fly one run to the end (``seed=None``: ``law.rngSeed``)."""
    return run_batch([law], seeds=None if seed is None else [seed], trace=trace)[0]


def run_batch(
    laws: Sequence[Law],
    *,
    seeds: Sequence[int] | None = None,
    trace: bool = False,
) -> list[RunResult]:
    """Fly many runs, grouped by :func:`batch_key` (same dt, duration, frame skips) into one
    :class:`SwarmSim` each; results in input order, each bit-identical to running that law
    alone. A finished run is no longer stepped; without ``trace`` (and without waggle) a
    group is flown to its end in one kernel call."""
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
        if trace:
            while not sim.done:
                sim._advance(1, skip_finished=True)
                sim._record()
        else:
            sim._advance(sim.total_steps, skip_finished=True)
        for r, i in enumerate(members):
            end = int(sim._end_step[r])
            results[i] = RunResult(
                law=laws[i], seed=seed_list[i], metrics=sim.metrics(r),
                steps=end if end >= 0 else sim.step_count,
                trace=sim.trace(r) if trace else None,
            )
    return [r for r in results if r is not None]
