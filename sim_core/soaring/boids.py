"""Hawk-inspired Boids of seed 002: neighbourhood search and the "Unified"/"Baseline" controllers.

Layout: own-glider arrays are (B, N) (B runs, N gliders); neighbour lists are (K, B, N) — K
neighbour slots of glider (b, i), with a ``valid`` mask (padding slots are False). Per-run
parameters are (B, 1) arrays in a :class:`LawParams` table built by :func:`law_params`, which also
holds them as the kernels' table (B, len(kernels.PAR)). The controller and the search themselves
are :func:`sim_core.soaring.kernels.accel` and :func:`~sim_core.soaring.kernels.find_lists`, the
swarm's own code; sums over a glider's neighbours run in list order, whatever the batch.

:func:`controller_command` is the same controller for ONE glider from its own observations, for
an autopilot on the far side of a bus.
"""

from __future__ import annotations

import dataclasses
import functools
import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any, Literal

import numpy as np
from numpy.typing import NDArray

from sim_core.soaring import kernels
from sim_core.soaring.law import Law

__all__ = [
    "CONTROLLERS",
    "BoidsAccel",
    "GliderObs",
    "LawParams",
    "boids_accel",
    "controller_command",
    "find_neighbors",
    "law_params",
]

F8 = NDArray[np.float64]
B8 = NDArray[np.bool_]

CONTROLLERS: tuple[str, ...] = ("unified", "baseline")

#: Law fields that become per-run (B, 1) float arrays.
_PER_RUN = (
    "g", "cohesion", "heightFactorPower", "cohesionAscensionIgnore", "cohesionAscensionMax",
    "ascensionFactorPower", "cohPower", "separation", "separationHeightWidth", "sepPower",
    "alignment", "alignmentHeightWidth", "aliPower", "migration", "migPower", "waggle",
    "thermalBankFactor", "neighborRadius", "fov", "forwardSpeedMin", "forwardSpeedMax",
    "bankMin", "bankMax", "Sink_A", "Sink_B", "Sink_C", "collisionKillDistance", "agentCeiling",
    "agentFloor", "k",
)


@dataclass(frozen=True, slots=True)
class LawParams:
    """Per-run parameters of a batch: ``p[name]`` is a (B, 1) array; ``table`` (B, len(PAR))
    is the same as the kernels read it (columns :data:`sim_core.soaring.kernels.PAR`).

    Extra entries: ``unified`` (B, 1) bool, ``target_x``/``target_y``, ``bank_rate_max`` and
    ``speed_rate_max`` (``inf`` where the law has none), and the fade parameters
    ``fade_by_time`` (bool), ``fade_rate`` (per step), ``fade_top``/``fade_bottom`` (plateau
    lengths, steps or s).
    """

    p: dict[str, NDArray[np.generic]]
    dt: float
    table: F8

    def __getitem__(self, name: str) -> NDArray[Any]:
        return self.p[name]

    @property
    def batch(self) -> int:
        return int(self.table.shape[0])


def law_params(laws: Sequence[Law]) -> LawParams:
    """Stack the per-run parameters of ``laws`` (all with the same dt) into (B, 1) arrays."""
    if not laws:
        raise ValueError("law_params needs at least one law")
    dts = {law.dt for law in laws}
    if len(dts) != 1:
        raise ValueError(f"laws of one batch must share dt, got {sorted(dts)}")
    dt = laws[0].dt

    def col(values: Sequence[float | bool]) -> NDArray[np.generic]:
        return np.asarray(values).reshape(len(laws), 1)

    p: dict[str, NDArray[np.generic]] = {
        name: col([float(getattr(law, name)) for law in laws]) for name in _PER_RUN
    }
    p["unified"] = col([law.controller == "unified" for law in laws]).astype(bool)
    p["target_x"] = col([law.migrationTarget[0] for law in laws]).astype(np.float64)
    p["target_y"] = col([law.migrationTarget[1] for law in laws]).astype(np.float64)
    inf = math.inf
    p["bank_rate_max"] = col([law.bankRateMax or inf for law in laws]).astype(np.float64)
    p["speed_rate_max"] = col([law.speedRateMax or inf for law in laws]).astype(np.float64)
    by_time = [law.thermalFadeMode == "seconds" for law in laws]
    p["fade_by_time"] = col(by_time).astype(bool)
    secs = [(law.thermalFadeRatePerSecond * dt, law.thermalMaxPlateauSeconds,
             law.thermalMinPlateauSeconds) for law in laws]
    steps = [(law.thermalFadeRate, float(law.thermalMaxPlateauTime),
              float(law.thermalMinPlateauTime)) for law in laws]
    chosen = [s if t else st for s, st, t in zip(secs, steps, by_time, strict=True)]
    p["fade_rate"] = col([c[0] for c in chosen]).astype(np.float64)
    p["fade_top"] = col([c[1] for c in chosen]).astype(np.float64)
    p["fade_bottom"] = col([c[2] for c in chosen]).astype(np.float64)
    tol = [kernels.FADE_TOLERANCE if t else 0.0 for t in by_time]
    derived: dict[str, list[float]] = {
        "unified": [float(law.controller == "unified") for law in laws],
        "fov_limited": [float(law.fov < 2 * math.pi) for law in laws],
        "half_fov": [law.fov / 2 for law in laws],
        "fade_incr": [dt if t else 1.0 for t in by_time],
        "fade_top": [c[1] - e for c, e in zip(chosen, tol, strict=True)],
        "fade_bottom": [c[2] - e for c, e in zip(chosen, tol, strict=True)],
        "map_min": [float(law.mapSize[0]) for law in laws],
        "map_cell": [(law.mapSize[1] - law.mapSize[0]) / law.mapDivResolution for law in laws],
    }
    table = np.empty((len(laws), len(kernels.PAR)))
    for j, name in enumerate(kernels.PAR):
        table[:, j] = derived[name] if name in derived else p[name][:, 0]
    return LawParams(p, dt, table)


def find_neighbors(
    x: F8, y: F8, z: F8, heading: F8, alive: B8, P: LawParams, *, width: int
) -> tuple[NDArray[np.intp], B8]:
    """KNN within radius and field of view (``findNeighborhood_KNNInFixedRadius``, spec §3.6).

    Inputs (B, N) are the *saved* state. Candidates of i: alive j ≠ i with |Δx| ≤ R, |Δy| ≤ R,
    d3 ≤ R and (if fov < 2π) acos((Δx cos ψ_i + Δy sin ψ_i)/d3) ≤ fov/2 (d3 = 0 is kept, as
    the seed's NaN comparison does). The nearest k by d3 (stable for ties) fill the first slots.
    Returns idx (K, B, N) int and valid (K, B, N) bool with K = ``width`` (idx 0 where invalid).
    """
    b, n = np.shape(x)
    S = np.zeros((kernels.STATE_ROWS, b, n))
    for row, v in ((kernels.ROW_X, x), (kernels.ROW_Y, y), (kernels.ROW_Z, z),
                   (kernels.ROW_HEADING, heading)):
        S[row] = v
    nb = np.zeros((b, n, width), dtype=np.int64)
    cnt = np.zeros((b, n), dtype=np.int64)
    kernels.lists_many(S, np.array(alive, dtype=bool), P.table, nb, cnt, False)
    valid = np.arange(width)[:, None, None] < cnt[None]
    idx = np.where(valid, nb.transpose(2, 0, 1), 0).astype(np.intp)
    return idx, valid


@dataclass(slots=True)
class BoidsAccel:
    """Controller output per glider, (B, N): desired planar acceleration (ax, ay) m/s² (seed
    units), ``collision`` (a valid neighbour closer than collisionKillDistance) and the
    cohesion magnitude ‖K_c·c‖ (seed Figs 6–10)."""

    ax: F8
    ay: F8
    collision: B8
    cohesion_mag: F8


#: Rows of a neighbour as the controller reads them (kernels.ROW_VX .. ROW_VZ).
_PAIR_ROWS = ("vx", "vy", "x", "y", "z", "vz")


def boids_accel(
    own: dict[str, F8],
    nb: dict[str, F8],
    owner: NDArray[np.intp],
    P: LawParams,
    waggle_sign: F8,
) -> BoidsAccel:
    """Desired acceleration of every glider (``agentControl_Unified``/``_Baseline``, §3.4).

    own: x, y, z, heading, speed, vz, each (B, N) (the saved state; optional cos, sin of the
    heading, if the caller has them). Neighbour pairs, V of them, sorted by owner and then by
    list slot: nb holds the neighbour's x, y, z, vx, vy, vz, each (V,) (vx, vy = v cos ψ,
    v sin ψ); ``owner`` (V,) is the owning glider's flat index b·N + i. Sums over a glider's
    neighbours run in slot order. Hazards guarded without changing other results: a neighbour
    straight above or below (dxy = 0) has ê = 0 and adds no cohesion, separation or alignment;
    a target at distance 0 adds no migration; a distance of 0 never reaches a negative power.
    """
    B, N = np.shape(own["x"])
    M = B * N
    heading = np.array(own["heading"], dtype=np.float64).ravel()
    if "cos" in own:
        c = np.array(own["cos"], dtype=np.float64).ravel()
        s = np.array(own["sin"], dtype=np.float64).ravel()
    else:
        c, s = kernels.cos_sin(heading)
    speed = np.asarray(own["speed"], dtype=np.float64).ravel()
    rows = (speed * c, speed * s, *(np.asarray(own[k], dtype=np.float64).ravel()
                                    for k in ("x", "y", "z", "vz")))
    own_rows = np.stack(rows)
    G = np.stack([np.asarray(nb[k], dtype=np.float64).reshape(-1) for k in _PAIR_ROWS])
    owner = np.asarray(owner, dtype=np.int64)
    if owner.size and np.any(np.diff(owner) < 0):
        raise ValueError("boids_accel: pairs must be sorted by owner")
    start = np.zeros(M + 1, dtype=np.int64)
    np.cumsum(np.bincount(owner, minlength=M), out=start[1:])
    out = np.asarray(kernels.accel_many(
        G, np.arange(owner.size, dtype=np.int64), start, own_rows, heading,
        np.broadcast_to(np.asarray(waggle_sign, dtype=np.float64), (B, N)).ravel().copy(),
        np.repeat(P.table, N, axis=0),
    ))
    return BoidsAccel(ax=out[0].reshape(B, N), ay=out[1].reshape(B, N),
                      collision=(out[2] != 0.0).reshape(B, N), cohesion_mag=out[3].reshape(B, N))


@dataclass(frozen=True, slots=True)
class GliderObs:
    """What one glider knows of itself or of a neighbour.

    x, y, z: position m (ENU); heading rad from +x; speed: airspeed m/s; vz: vertical speed m/s
    (> 0 climbing); updraft: the air's vertical speed at the glider, m/s (used only by a law
    with thermalBankFactor ≠ 0).
    """

    x: float
    y: float
    z: float
    heading: float
    speed: float
    vz: float
    updraft: float = 0.0


_OBS_KEYS = ("x", "y", "z", "heading", "speed", "vz")


@functools.lru_cache(maxsize=32)
def _single_params(law: Law, controller: str) -> LawParams:
    """B = 1 parameters of ``law`` flown with ``controller`` (cached: an autopilot calls
    :func:`controller_command` every control period with the same law)."""
    if controller not in CONTROLLERS:
        raise ValueError(f"controller must be one of {list(CONTROLLERS)}, got {controller!r}")
    if controller != law.controller:
        law = dataclasses.replace(law, controller=controller)  # type: ignore[arg-type]
    return law_params([law])


def controller_command(
    own: GliderObs,
    neighbours: Sequence[GliderObs] | NDArray[np.floating],
    law: Law,
    *,
    controller: Literal["unified", "baseline"] | None = None,
    waggle_sign: float = 0.0,
) -> tuple[float, float]:
    """(bank_cmd rad, airspeed_cmd m/s) of one glider, from its own state and its neighbours.

    ``neighbours``: GliderObs items or an array (n, 6) of columns x, y, z, heading, speed, vz,
    already selected by the seed's neighbourhood rule (the server's ``/glider/i/neighbors``).
    ``controller`` defaults to ``law.controller``. The commands are unclipped: the glider
    applies its speed and bank limits (and rate limits) when it flies them, exactly as the
    swarm does for Boids-flown gliders, so flying these commands reproduces the swarm.
    A neighbour within collisionKillDistance would kill the glider in the swarm; here it is
    only part of the sum.
    """
    if isinstance(neighbours, np.ndarray):
        arr = np.asarray(neighbours, dtype=np.float64)
        if arr.size == 0:
            arr = arr.reshape(0, 6)
        if arr.ndim != 2 or arr.shape[1] != 6:
            raise ValueError(f"neighbours array must have shape (n, 6), got {arr.shape}")
    else:
        arr = np.array(
            [[getattr(o, k) for k in _OBS_KEYS] for o in neighbours], dtype=np.float64
        ).reshape(-1, 6)
    P = _single_params(law, law.controller if controller is None else controller)
    me = np.array([float(getattr(own, k)) for k in _OBS_KEYS])
    bank, speed = kernels.controller(me, np.array(arr, dtype=np.float64), P.table[0], float(law.dt),
                               float(waggle_sign), float(own.updraft))
    return float(bank), float(speed)
