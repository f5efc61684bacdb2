"""Hawk-inspired Boids of seed 002: neighbourhood search and the "Unified"/"Baseline" controllers.

Layout: own-glider arrays are (B, N) (B runs, N gliders); neighbour lists are (K, B, N) — K
neighbour slots of glider (b, i), with a ``valid`` mask (padding slots are False) — flattened
into V (owner, other) pairs sorted by owner then slot. Sums over a glider's neighbours are
``bincount`` sums in that order, so a run's result does not depend on the batch it is stepped
in. Per-run parameters are (B, 1) arrays in a :class:`LawParams` table built by
:func:`law_params`; :class:`AccelKernel` evaluates the controller for a batch.

:func:`controller_command` is the same controller for ONE glider from its own observations
(B = N = 1), for an autopilot on the far side of a bus.
"""

from __future__ import annotations

import dataclasses
import functools
import math
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any, Literal

import numpy as np
from numpy.typing import NDArray

from sim_core.soaring.glider import accel_to_command, scalar_if_uniform
from sim_core.soaring.law import Law

__all__ = [
    "CONTROLLERS",
    "AccelKernel",
    "BoidsAccel",
    "GliderObs",
    "LawParams",
    "boids_accel",
    "controller_command",
    "find_neighbors",
    "law_params",
    "neighbor_pairs",
    "power",
    "velocity_xy",
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


#: Cap of a neighbour's distance weight (d/R)^p, reached only as d → 0 with p < 0.
W_MAX = 1e100

#: Per-run parameters used per neighbour pair by :class:`AccelKernel`.
_PAIR_PARAMS = (
    "neighborRadius", "collisionKillDistance", "cohesionAscensionIgnore", "cohesionAscensionMax",
    "ascensionFactorPower", "cohPower", "separationHeightWidth", "sepPower",
    "alignmentHeightWidth", "aliPower", "unified",
)


@dataclass(frozen=True, slots=True)
class LawParams:
    """Per-run parameters of a batch: ``p[name]`` is a (B, 1) float64 array.

    Extra entries: ``unified`` (B, 1) bool, ``target_x``/``target_y``, ``bank_rate_max`` and
    ``speed_rate_max`` (``inf`` where the law has none), and the fade parameters
    ``fade_by_time`` (bool), ``fade_rate`` (per step), ``fade_top``/``fade_bottom``.
    """

    p: dict[str, NDArray[np.generic]]
    dt: float
    _distinct: dict[str, list[float]] = field(default_factory=dict)
    _scalars: dict[str, float | NDArray[np.float64]] = field(default_factory=dict)

    def __getitem__(self, name: str) -> NDArray[Any]:
        return self.p[name]

    @property
    def batch(self) -> int:
        return int(self.p["g"].shape[0])

    def select(self, runs: NDArray[np.intp]) -> LawParams:
        return LawParams({k: v[runs] for k, v in self.p.items()}, self.dt)

    def scalar(self, name: str) -> float | NDArray[np.float64]:
        """A float parameter as a Python float when all runs share it, else (B, 1) (cached)."""
        if name not in self._scalars:
            self._scalars[name] = scalar_if_uniform(self.p[name])
        return self._scalars[name]

    def values(self, name: str) -> list[float]:
        """Distinct values of a per-run parameter in this batch (cached)."""
        vals = self._distinct.get(name)
        if vals is None:
            vals = [float(v) for v in np.unique(self.p[name])]
            self._distinct[name] = vals
        return vals



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
    return LawParams(p, dt)


def power(base: F8, exponent: F8 | float, values: Sequence[float] | None = None) -> F8:
    """base ** exponent, evaluated the same way for an element whatever else is in the array
    (the method depends only on the exponent's value), so a run's result does not depend on
    its batch.

    ``exponent`` is broadcastable to ``base``; ``values`` lists its distinct values (computed
    if omitted). Exponents 0, 1, 2, −1, −2, 0.5 take exact or correctly rounded paths
    (0 ** 0 = 1, as in MATLAB); others use ``np.power``.
    """
    e = np.asarray(exponent, dtype=np.float64)
    vals = np.unique(e) if values is None else values
    if len(vals) == 1:
        return _pow1(np.asarray(base, dtype=np.float64), float(vals[0]))
    x, ee = np.broadcast_arrays(np.asarray(base, dtype=np.float64), e)
    out = np.empty(x.shape)
    for val in vals:
        m = ee == val
        out[m] = _pow1(x[m], float(val))
    return out


def _pow_into(out: F8, x: F8, val: float) -> None:
    """out[...] = x ** val by the same operations as :func:`_pow1`."""
    if val == 0:
        out.fill(1.0)
    elif val == 1:
        np.copyto(out, x)
    elif val == 2:
        np.multiply(x, x, out=out)
    elif val == -1:
        np.divide(1.0, x, out=out)
    elif val == -2:
        np.multiply(x, x, out=out)
        np.divide(1.0, out, out=out)
    elif val == 0.5:
        np.sqrt(x, out=out)
    else:
        np.power(x, val, out=out)


def _pow1(x: F8, val: float) -> F8:
    if val == 0:
        return np.ones_like(x)
    if val == 1:
        return x.copy()
    if val == 2:
        return x * x
    if val == -1:
        return 1.0 / x
    if val == -2:
        return 1.0 / (x * x)
    if val == 0.5:
        return np.sqrt(x)
    return np.power(x, val)


def find_neighbors(
    x: F8,
    y: F8,
    z: F8,
    heading: F8,
    alive: B8,
    P: LawParams,
    *,
    width: int,
    chunk_elems: int = 4_000_000,
) -> tuple[NDArray[np.intp], B8]:
    """KNN within radius and field of view (``findNeighborhood_KNNInFixedRadius``, spec §3.6).

    Inputs (B, N) are the *saved* state. Candidates of i: alive j ≠ i with |Δx| ≤ R, |Δy| ≤ R,
    d3 ≤ R and (if fov < 2π) acos((Δx cos ψ_i + Δy sin ψ_i)/d3) ≤ fov/2 (d3 = 0 is kept, as
    the seed's NaN comparison does). The nearest k by d3 (stable for ties) fill the first slots.
    Returns idx (K, B, N) int and valid (K, B, N) bool with K = ``width``. Pairwise distances
    are computed in chunks of rows so B·N·N never exceeds ``chunk_elems`` at once.
    """
    b, n = x.shape
    idx = np.zeros((width, b, n), dtype=np.intp)
    valid = np.zeros((width, b, n), dtype=bool)
    if width == 0 or n == 0:
        return idx, valid
    R = P["neighborRadius"][:, :, None]
    cos_half = np.cos(P["fov"][:, :, None] / 2.0)
    limited_fov = P["fov"][:, :, None] < 2 * math.pi
    any_limited, all_limited = bool(limited_fov.any()), bool(limited_fov.all())
    kk = P["k"][:, 0].astype(np.intp)
    rows_per = max(1, chunk_elems // max(1, b * n))
    for start in range(0, n, rows_per):
        sl = slice(start, min(n, start + rows_per))
        dx = x[:, None, :] - x[:, sl, None]
        dy = y[:, None, :] - y[:, sl, None]
        dz = z[:, None, :] - z[:, sl, None]
        d3 = dx * dx
        d3 += dy * dy
        d3 += dz * dz
        np.sqrt(d3, out=d3)
        # |dx| <= R and |dy| <= R (a NaN fails both forms)
        box = np.abs(dx)
        np.maximum(box, np.abs(dy), out=box)
        cand = box <= R
        cand &= d3 <= R
        cand &= alive[:, None, :]
        cand[:, np.arange(sl.stop - sl.start), np.arange(sl.start, sl.stop)] = False  # j ≠ i
        if any_limited:
            # cos of the bearing, (dx cos ψ + dy sin ψ) / d3, in place (dx, dy are done)
            dx *= np.cos(heading[:, sl, None])
            dy *= np.sin(heading[:, sl, None])
            dx += dy
            with np.errstate(invalid="ignore", divide="ignore"):
                dx /= d3
            # acos(c) > fov/2  <=>  c < cos(fov/2); NaN (d3 = 0) compares False and is kept
            behind = dx < cos_half
            if not all_limited:
                behind &= limited_fov
            np.greater(cand, behind, out=cand)  # cand & ~behind
        key = np.where(cand, d3, np.inf)
        order = np.argsort(key, axis=2, kind="stable")[:, :, :width]
        ok = np.take_along_axis(cand, order, axis=2)
        rank = np.arange(order.shape[2])[None, None, :]
        ok &= rank < kk[:, None, None]
        pad = width - order.shape[2]
        if pad > 0:
            order = np.concatenate([order, np.zeros((*order.shape[:2], pad), np.intp)], axis=2)
            ok = np.concatenate([ok, np.zeros((*ok.shape[:2], pad), bool)], axis=2)
        idx[:, :, sl] = order.transpose(2, 0, 1)
        valid[:, :, sl] = ok.transpose(2, 0, 1)
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


def velocity_xy(speed: F8, heading: F8) -> tuple[F8, F8]:
    """Horizontal velocity (v cos ψ, v sin ψ), m/s, of arrays of any shape."""
    return speed * np.cos(heading), speed * np.sin(heading)


#: Rows of the pair-difference array ``D`` (6, V) the kernel reads: neighbour minus owner
#: (the order of the glider state rows ROW_VX..ROW_VZ of :mod:`sim_core.soaring.glider`).
PAIR_ROWS = ("vx", "vy", "x", "y", "z", "vz")


class AccelKernel:
    """The Boids controller of one batch (``agentControl_Unified``/``_Baseline``, §3.4), with
    everything that depends only on the laws computed once.

    :meth:`set_pairs` takes the neighbour pairs of a list refresh; :meth:`accel` then evaluates
    the controller from the pair differences. Per-run parameters that are equal in every run
    of the batch are used as scalars, the others per pair; either way each element sees the
    same float64 operations, so a run's result does not depend on its batch. Work buffers are
    reused between calls: the arrays :meth:`accel` returns are valid until its next call.
    """

    def __init__(self, P: LawParams, B: int, N: int) -> None:
        self.P = P
        self.B, self.N, self.M = B, N, B * N
        uni = np.asarray(P["unified"], dtype=bool)
        self._all_unified = bool(uni.all())
        self._uniform = {name: P.scalar(name) for name in _PAIR_PARAMS if name != "unified"}
        self._ceiling = P.scalar("agentCeiling")
        self._hfp = P.values("heightFactorPower")
        self._afp = P.values("ascensionFactorPower")
        self._coh_p = P.values("cohPower")
        self._sep_p = P.values("sepPower")
        self._ali_p = P.values("aliPower")
        self._mig_p = P.values("migPower")
        self._target = np.stack([P["target_x"], P["target_y"]])  # (2, B, 1)
        self._neg_ks = -P.scalar("separation")
        self._kc, self._ka = P.scalar("cohesion"), P.scalar("alignment")
        self._km, self._kw = P.scalar("migration"), P.scalar("waggle")
        self._waggle = bool(np.any(self._kw != 0))  # a zero gain adds only ±0
        ali_w, sep_w = self._uniform["alignmentHeightWidth"], self._uniform["separationHeightWidth"]
        self._half_const = (
            np.array([[ali_w / 2], [sep_w / 2]])
            if isinstance(ali_w, float) and isinstance(sep_w, float) else None
        )
        self.set_pairs(np.zeros(0, dtype=np.intp), np.zeros(0, dtype=np.intp))

    def set_pairs(self, owner: NDArray[np.intp], other: NDArray[np.intp]) -> None:
        """Pairs (V,) of flat glider indices b·N + i, sorted by owner then list slot."""
        V, M = owner.shape[0], self.M
        self.owner, self.V = owner, V
        self.gather = np.concatenate([other, owner])
        # one bincount sums all seven per-pair rows: row r of glider m goes to bin r·M + m
        self._bins = (owner[None, :] + M * np.arange(7)[:, None]).ravel()
        # 1/n of each glider's n neighbours; 1 without any, where every sum is +0.0 and
        # +0.0·1 == +0.0·0, the seed's 0 factor
        count = np.bincount(owner, minlength=M).reshape(self.B, self.N)
        self._inv_n = 1.0 / np.maximum(count, 1)
        run = owner // max(self.N, 1)
        pp: dict[str, float | NDArray[Any]] = {}
        for name, val in self._uniform.items():
            pp[name] = val if isinstance(val, float) else self.P[name][run, 0]
        self._unified_pp = self.P["unified"][run, 0]
        ign, wmax = pp["cohesionAscensionIgnore"], pp["cohesionAscensionMax"]
        pp["asc_range"] = wmax - ign
        # |Δz| limits of alignment and separation (unified), rows (2, V) or (2, 1)
        if self._half_const is not None:
            self._half = self._half_const
        else:
            half = np.broadcast_arrays(np.asarray(pp["alignmentHeightWidth"] / 2),
                                       np.asarray(pp["separationHeightWidth"] / 2))
            self._half = np.stack(half).reshape(2, -1)
        self.pp = pp
        # (row, exponent) of the alignment and separation weights when uniform in the batch
        ali_p, sep_p = pp["aliPower"], pp["sepPower"]
        self._same_pw = isinstance(ali_p, float) and isinstance(sep_p, float) and ali_p == sep_p
        self.D = np.empty((6, V))
        self._gg = np.empty((6, 2 * V))
        self._sq = np.empty((3, V))
        self._dd = np.empty((2, V))
        self._nd = np.empty((2, V))
        self._inv = np.zeros(V)
        self._e = np.empty((2, V))
        self._seen = np.empty((3, V), dtype=bool)
        self._pw = np.empty((3, V))
        self._wt = np.empty((7, V))

    def load(self, G: F8) -> F8:
        """Pair differences D (6, V) (neighbour − owner of the rows :data:`PAIR_ROWS`) from
        glider rows G (6, B·N) in the same order."""
        if self.V:
            np.take(G, self.gather, axis=1, out=self._gg)
            np.subtract(self._gg[:, : self.V], self._gg[:, self.V :], out=self.D)
        return self.D

    def accel(
        self, D: F8, own_z: F8, own_xy: F8, cs: F8, waggle_sign: F8
    ) -> tuple[F8, B8, F8]:
        """Desired acceleration A (2, B, N) (ax, ay m/s²), collision (B, N) and the cohesion
        magnitude ‖K_c·c‖ (B, N), from pair differences D (6, V) (see :meth:`load`), own
        altitude z (B, N) m, own (x, y) (2, B, N) m, (cos ψ, sin ψ) (2, B, N) and the waggle
        signs (B, N)."""
        P, pp, M, B, N = self.P, self.pp, self.M, self.B, self.N
        sq, dd, nd, seen, pw = self._sq, self._dd, self._nd, self._seen, self._pw
        np.multiply(D[2:5], D[2:5], out=sq)
        np.add(sq[0], sq[1], out=dd[0])  # dxy²
        np.add(dd[0], sq[2], out=dd[1])  # d3²
        np.sqrt(dd, out=dd)  # dxy, d3
        dxy, d3 = dd[0], dd[1]
        flat = seen[0]
        np.greater(dxy, 0.0, out=flat)
        inv = self._inv
        inv.fill(0.0)
        np.divide(1.0, dxy, out=inv, where=flat)
        e = self._e
        np.multiply(D[2:4], inv, out=e)
        wt = self._wt
        np.less(d3, pp["collisionKillDistance"], out=wt[6])

        # cohesion weight: height factor × relative ascension (unified), 1 (baseline)
        ign, wmax = pp["cohesionAscensionIgnore"], pp["cohesionAscensionMax"]
        dwc = np.maximum(np.minimum(D[5], wmax), ign)
        height = power(np.maximum(1.0 - own_z / self._ceiling, 0.0), P["heightFactorPower"],
                       self._hfp)
        asc = power((dwc - ign) / pp["asc_range"], pp["ascensionFactorPower"], self._afp)
        weight = np.take(height.ravel(), self.owner) * asc
        if not self._all_unified:
            weight = np.where(self._unified_pp, weight, 1.0)
        rzabs = np.abs(D[4])
        with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
            np.divide(dd, pp["neighborRadius"], out=nd)  # dxy/R, d3/R
            if self._coh_p == [0.0]:
                pw[0] = weight  # weight · 0 ** 0 == weight
            else:
                np.multiply(weight, power(nd[0], pp["cohPower"], self._coh_p), out=pw[0])
            if self._same_pw:
                _pow_into(pw[1:], nd, self._ali_p[0])
            else:
                pw[1] = power(nd[0], pp["aliPower"], self._ali_p)
                pw[2] = power(nd[1], pp["sepPower"], self._sep_p)
        np.less(rzabs, self._half, out=seen[1:])
        if not self._all_unified:
            np.logical_or(seen[1:], ~self._unified_pp, out=seen[1:])
        np.logical_and(seen[1:], flat, out=seen[1:])
        w = np.where(seen, pw, 0.0)  # rows: cohesion, alignment, separation weights
        # a distance → 0 under a negative power: cap the weight (4 m at R = 1000 gives 6e4)
        np.minimum(w, W_MAX, out=w)
        np.multiply(e, w[0], out=wt[0:2])
        np.multiply(e, w[2], out=wt[2:4])
        np.multiply(D[0:2], w[1], out=wt[4:6])
        sums = np.bincount(self._bins, weights=wt.ravel(), minlength=7 * M).reshape(7, B, N)
        c = sums[:6] * self._inv_n  # cohesion, separation (sign flipped below), alignment
        collision = sums[6] > 0

        t = self._target - own_xy
        t2 = t * t
        dist = np.sqrt(t2[0] + t2[1])
        pos = dist > 0
        if pos.all():
            mscale = power(dist, P["migPower"], self._mig_p)
        else:
            mscale = np.where(pos, power(np.where(pos, dist, 1.0), P["migPower"], self._mig_p),
                              0.0)
        a = c[2:4] * self._neg_ks
        kcc = c[0:2] * self._kc
        a += kcc
        a += c[4:6] * self._ka
        a += (t * mscale) * self._km
        if self._waggle:
            a[0] += (-cs[1] * waggle_sign) * self._kw
            a[1] += (cs[0] * waggle_sign) * self._kw
        kcc *= kcc
        coh_mag = np.sqrt(kcc[0] + kcc[1])
        return a, collision, coh_mag


def boids_accel(
    own: dict[str, F8],
    nb: dict[str, F8],
    owner: NDArray[np.intp],
    P: LawParams,
    waggle_sign: F8,
) -> BoidsAccel:
    """Desired acceleration of every glider (``agentControl_Unified``/``_Baseline``, §3.4).

    own: x, y, z, heading, speed, vz, each (B, N) (the saved state; optional cos, sin of the
    heading, if the caller has them). Neighbour pairs, V of
    them, sorted by owner and then by list slot: nb holds the neighbour's x, y, z, vx, vy, vz
    (velocities from :func:`velocity_xy`), each (V,); ``owner`` (V,) is the owning glider's flat
    index b·N + i. Evaluated by :class:`AccelKernel` (the swarm's kernel).
    Sums over a glider's neighbours run in slot order (``bincount``), whatever the batch.
    Hazards guarded without changing other results: a neighbour straight above or below
    (dxy = 0) has ê = 0 and adds no cohesion, separation or alignment; a target at distance 0
    adds no migration; a distance of 0 never reaches a negative power.
    """
    B, N = own["x"].shape
    kern = AccelKernel(P, B, N)
    kern.set_pairs(owner, owner)
    if "cos" in own:
        ch, sh = own["cos"], own["sin"]
    else:
        ch, sh = np.cos(own["heading"]), np.sin(own["heading"])
    rows = (own["speed"] * ch, own["speed"] * sh, own["x"], own["y"], own["z"], own["vz"])
    D = np.stack([nb[k] - o.ravel()[owner] for k, o in zip(PAIR_ROWS, rows, strict=True)])
    D = D.reshape(6, owner.shape[0])
    a, collision, coh_mag = kern.accel(
        D, own["z"], np.stack([own["x"], own["y"]]), np.stack([ch, sh]), waggle_sign
    )
    return BoidsAccel(ax=a[0].copy(), ay=a[1].copy(), collision=collision, cohesion_mag=coh_mag)


def neighbor_pairs(
    idx: NDArray[np.intp], valid: B8
) -> tuple[NDArray[np.intp], NDArray[np.intp]]:
    """(owner, other) flat glider indices b·N + i of every valid list slot (K, B, N), sorted by
    owner then slot, as :func:`boids_accel` wants them."""
    _, _, n = valid.shape
    b, i, k = np.nonzero(np.moveaxis(valid, 0, 2))
    owner = b * n + i
    other = b * n + idx[k, b, i]
    return owner.astype(np.intp), other.astype(np.intp)


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
    own_d = {k: np.array([[float(getattr(own, k))]]) for k in _OBS_KEYS}
    K = arr.shape[0]
    cols = {k: arr[:, j].reshape(K, 1, 1).copy() for j, k in enumerate(_OBS_KEYS)}
    vx, vy = velocity_xy(cols["speed"], cols["heading"])
    nb = {"x": cols["x"], "y": cols["y"], "z": cols["z"], "vx": vx, "vy": vy, "vz": cols["vz"]}
    owner = np.zeros(K, dtype=np.intp)
    acc = boids_accel(own_d, {k: v.ravel() for k, v in nb.items()}, owner, P,
                      np.array([[float(waggle_sign)]]))
    bank, speed = accel_to_command(
        acc.ax,
        acc.ay,
        own_d["heading"],
        own_d["speed"],
        dt=law.dt,
        g=P["g"],
        thermal_bank_factor=P["thermalBankFactor"],
        updraft=np.array([[float(own.updraft)]]),
    )
    return float(bank[0, 0]), float(speed[0, 0])
