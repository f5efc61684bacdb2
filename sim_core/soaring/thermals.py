"""Thermals of seed 002: the "Mexican hat" updraft profile, random spawn, and the fade cycle.

Profile (``docs/spec/seed_models.md`` §3.2): for horizontal distance d to the centre and radius R,
u = (3d/R)², w = W·e^(−u)·(1 − u) if d < R, else 0; where several thermals contain a point
the first in list order wins. No altitude dependence, no sink outside thermals.

All arrays of a :class:`Thermals` have shape (B, T): B runs (the batch), T thermal slots;
slots with ``valid == False`` are padding and never contain a point. The profile and the fade
are computed by :mod:`sim_core.soaring.kernels` (the swarm's own code).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray

from sim_core.soaring import kernels
from sim_core.soaring.law import Law

__all__ = [
    "Thermals",
    "fade_step",
    "spawn_thermals",
    "stack_thermals",
    "updraft",
]

F8 = NDArray[np.float64]
B8 = NDArray[np.bool_]


@dataclass(slots=True)
class Thermals:
    """Thermal state, struct of arrays shaped (B, T).

    x, y: centre, m. radius: R, m. strength: current W, m/s. w_max: plateau top, m/s.
    direction: +1 ramping up, −1 ramping down. timer: plateau time spent, in steps
    (``thermalFadeMode: steps``) or seconds (``seconds``). fade: whether this thermal fades.
    valid: False for padding slots.
    """

    x: F8
    y: F8
    radius: F8
    strength: F8
    w_max: F8
    direction: F8
    timer: F8
    fade: B8
    valid: B8

    @property
    def radius2(self) -> F8:
        """R², m² (the containment test is d² < R²)."""
        return self.radius * self.radius

    @property
    def shape(self) -> tuple[int, int]:
        return (int(self.x.shape[0]), int(self.x.shape[1]))

    def copy(self) -> Thermals:
        return Thermals(*(np.array(getattr(self, f)) for f in self.__slots__))

    def select(self, runs: NDArray[np.intp]) -> Thermals:
        """The thermals of the given runs (batch rows)."""
        return Thermals(*(getattr(self, f)[runs] for f in self.__slots__))

    def block(self) -> tuple[F8, B8]:
        """The kernels' layout: floats (TH_ROWS, B, T) (rows ``kernels.TH_*``) and flags
        (2, B, T) (valid, fade), new arrays."""
        th = np.stack([self.x, self.y, self.radius, self.strength, self.w_max, self.direction,
                       self.timer]).astype(np.float64)
        return th, np.stack([self.valid, self.fade]).astype(bool)

    @classmethod
    def from_block(cls, th: F8, on: B8) -> Thermals:
        """Copies of the rows of a :meth:`block` layout."""
        k = kernels
        return cls(x=th[k.TH_X].copy(), y=th[k.TH_Y].copy(), radius=th[k.TH_R].copy(),
                   strength=th[k.TH_W].copy(), w_max=th[k.TH_WMAX].copy(),
                   direction=th[k.TH_DIR].copy(), timer=th[k.TH_TIMER].copy(),
                   fade=on[k.ON_FADE].copy(), valid=on[k.ON_VALID].copy())


def _rand_ir(rng: np.random.Generator, lo: float, hi: float) -> float:
    """The seed's ``Utility.randIR``: lo + (hi − lo)·U(0, 1)."""
    return lo + (hi - lo) * float(rng.random())


def _matlab_round(v: float) -> float:
    """MATLAB ``round``: half away from zero."""
    return float(np.sign(v) * np.floor(abs(v) + 0.5))


def spawn_thermals(law: Law, rng: np.random.Generator) -> Thermals:
    """Thermals of one run (B = 1): the pinned list, or random ones with the no-overlap rule.

    Random draw per thermal, in order (§3.2): R = round(U(Rmin, Rmax)); x0, y0 =
    round(U(s0 + R + 1, s1 − R − 1)); W_max = round(U(Smin + 1, Smax)); W(0) = round(U(1, W_max)).
    A thermal overlapping an earlier one (‖c_i − c_j‖ ≤ R_i + R_j) is re-drawn up to
    ``thermalSpawnAttempts`` times; if it still overlaps, creation stops there.
    """
    if law.thermals is not None:
        pinned = law.thermals
        arr = np.array([[t.x, t.y, t.radius, t.strength] for t in pinned], dtype=np.float64)
        arr = arr.reshape(len(pinned), 4)
        fade = np.array([t.fade for t in pinned], dtype=bool)
        return _make(arr[:, 0], arr[:, 1], arr[:, 2], arr[:, 3], arr[:, 3], fade)
    s0, s1 = law.thermalSpawnRange
    xs: list[float] = []
    ys: list[float] = []
    rs: list[float] = []
    ws: list[float] = []
    wm: list[float] = []
    for _ in range(law.numThermals):
        placed = False
        for _attempt in range(law.thermalSpawnAttempts):
            r = _matlab_round(_rand_ir(rng, law.thermalRadiusMin, law.thermalRadiusMax))
            x0 = _matlab_round(_rand_ir(rng, s0 + r + 1, s1 - r - 1))
            y0 = _matlab_round(_rand_ir(rng, s0 + r + 1, s1 - r - 1))
            w_max = _matlab_round(
                _rand_ir(rng, law.thermalStrengthMin + 1, law.thermalStrengthMax)
            )
            w0 = _matlab_round(_rand_ir(rng, 1.0, w_max))
            if all(np.hypot(x0 - x, y0 - y) > r + rr for x, y, rr in zip(xs, ys, rs, strict=True)):
                xs.append(x0)
                ys.append(y0)
                rs.append(r)
                ws.append(w0)
                wm.append(w_max)
                placed = True
                break
        if not placed:
            break
    n = len(xs)
    return _make(
        np.array(xs, dtype=np.float64),
        np.array(ys, dtype=np.float64),
        np.array(rs, dtype=np.float64),
        np.array(ws, dtype=np.float64),
        np.array(wm, dtype=np.float64),
        np.ones(n, dtype=bool),
    )


def _make(x: F8, y: F8, r: F8, w: F8, w_max: F8, fade: B8) -> Thermals:
    t = x.shape[0]
    return Thermals(
        x=x.reshape(1, t),
        y=y.reshape(1, t),
        radius=r.reshape(1, t),
        strength=w.reshape(1, t).copy(),
        w_max=w_max.reshape(1, t),
        direction=np.ones((1, t)),
        timer=np.zeros((1, t)),
        fade=fade.reshape(1, t),
        valid=np.ones((1, t), dtype=bool),
    )


def stack_thermals(items: Sequence[Thermals], width: int | None = None) -> Thermals:
    """Concatenate single-run thermals along the batch axis, padding to a common T."""
    t = max([it.shape[1] for it in items] + [width or 0])

    def pad(name: str, fill: float | bool) -> NDArray[Any]:
        rows = []
        for it in items:
            a = getattr(it, name)
            extra = t - a.shape[1]
            rows.append(np.concatenate([a, np.full((a.shape[0], extra), fill, a.dtype)], axis=1))
        return np.concatenate(rows, axis=0) if rows else np.zeros((0, t))

    return Thermals(
        x=pad("x", 0.0),
        y=pad("y", 0.0),
        radius=pad("radius", 1.0),
        strength=pad("strength", 0.0),
        w_max=pad("w_max", 0.0),
        direction=pad("direction", 1.0),
        timer=pad("timer", 0.0),
        fade=pad("fade", False),
        valid=pad("valid", False),
    )


def updraft(xy: NDArray[np.floating], thermals: Thermals) -> F8:
    """Vertical air speed w at horizontal positions ``xy``, m/s (> 0 up).

    xy : shape (B, M, 2) with thermals shaped (B, T); a single run may also pass xy (M, 2)
    with B == 1. Returns shape (B, M) (or (M,)). The first thermal in list order whose disc
    contains the point decides (seed ``findThermalIndex``).
    """
    pts = np.asarray(xy, dtype=np.float64)
    single = pts.ndim == 2
    if single:
        if thermals.shape[0] != 1:
            raise ValueError(
                f"xy of shape {pts.shape} needs one run of thermals, got B={thermals.shape[0]}"
            )
        pts = pts[None]
    if pts.ndim != 3 or pts.shape[-1] != 2 or pts.shape[0] != thermals.shape[0]:
        raise ValueError(
            f"xy must have shape (B, M, 2) or (M, 2) with B={thermals.shape[0]}, "
            f"got {np.shape(xy)}"
        )
    th, on = thermals.block()
    w = np.asarray(kernels.updraft_many(np.array(pts[..., 0]), np.array(pts[..., 1]), th, on))
    return w[0] if single else w


def fade_step(
    th: Thermals, *, by_time: NDArray[Any], rate: F8, top: F8, bottom: F8, dt: float
) -> None:
    """Advance the fade cycle by one step, in place (seed ``fadeThermals``, §3.2).

    Per run (arrays (B, 1)): ``rate`` is the change of W per step, m/s; ``top``/``bottom`` the
    plateau lengths, in steps (``by_time`` False: the timer counts steps) or seconds (True: the
    timer counts seconds, ``dt`` per step, so the cycle does not depend on dt).
    """
    b = th.shape[0]

    def col(v: NDArray[Any]) -> NDArray[Any]:
        return np.broadcast_to(v, (b, 1))[:, 0]

    seconds = col(by_time).astype(bool)
    tol = np.where(seconds, kernels.FADE_TOLERANCE, 0.0)
    par = np.zeros((b, len(kernels.PAR)))
    par[:, kernels.P_FADE_RATE] = col(rate)
    par[:, kernels.P_FADE_INCR] = np.where(seconds, dt, 1.0)
    par[:, kernels.P_FADE_TOP] = col(top) - tol
    par[:, kernels.P_FADE_BOTTOM] = col(bottom) - tol
    block, on = th.block()
    kernels.fade_many(block, on, par)
    th.strength[...] = block[kernels.TH_W]
    th.direction[...] = block[kernels.TH_DIR]
    th.timer[...] = block[kernels.TH_TIMER]
