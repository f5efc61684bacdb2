"""Thermals of seed 002: the "Mexican hat" updraft profile, random spawn, and the fade cycle.

Profile (``docs/spec/seed_models.md`` §3.2): for horizontal distance d to the centre and radius R,
u = (3d/R)², w = W·e^(−u)·(1 − u) if d < R, else 0; where several thermals contain a point
the first in list order wins. No altitude dependence, no sink outside thermals.

All arrays of a :class:`Thermals` have shape (B, T): B runs (the batch), T thermal slots;
slots with ``valid == False`` are padding and never contain a point.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray

from sim_core.soaring.glider import scalar_if_uniform
from sim_core.soaring.law import Law

__all__ = [
    "Fader",
    "Thermals",
    "UpdraftField",
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
    if pts.ndim != 3 or pts.shape[-1] != 2:
        raise ValueError(f"xy must have shape (B, M, 2) or (M, 2), got {np.shape(xy)}")
    w = _updraft_xy(pts[..., 0], pts[..., 1], thermals)
    return w[0] if single else w


def _updraft_xy(x: F8, y: F8, th: Thermals) -> F8:
    """w at points (B, M) for thermals (B, T)."""
    return UpdraftField(th, x.shape[1])(np.stack([x, y]))


class UpdraftField:
    """The updraft profile of a batch's thermals at M points per run, with the parts that do
    not change while the thermals only fade (centres, radii, slots) computed once.

    ``field(xy)`` with xy (2, B, M) m → w (B, M) m/s, from the thermals' current strength.
    """

    def __init__(self, th: Thermals, m: int) -> None:
        self.th = th
        b, t = th.shape
        self.b, self.m, self.t = b, m, t
        self._txy = np.stack([th.x, th.y])[:, :, None, :]  # (2, B, 1, T)
        # padding slots never contain a point: d² < −inf is False, as d² < R² & valid was
        self._r2 = np.where(th.valid, th.radius2, -np.inf)[:, None, :]
        self._radius = th.radius.ravel()
        self._dxy = np.empty((2, b, m, t))
        self._d2 = np.empty((b, m, t))
        self._inside = np.empty((b, m, t), dtype=bool)
        self._base = (np.arange(b * m) * t).reshape(b, m)
        self._run_base = np.arange(b)[:, None] * t

    def __call__(self, xy: F8) -> F8:
        b, m, t = self.b, self.m, self.t
        if t == 0 or m == 0:
            return np.zeros((b, m))
        dxy, d2, inside = self._dxy, self._d2, self._inside
        np.subtract(xy[:, :, :, None], self._txy, out=dxy)
        np.multiply(dxy, dxy, out=dxy)
        np.add(dxy[0], dxy[1], out=d2)
        np.less(d2, self._r2, out=inside)
        first = np.argmax(inside, axis=2)
        flat = self._base + first
        hit = np.take(inside.ravel(), flat)
        dsel = np.sqrt(np.take(d2.ravel(), flat))
        run_t = self._run_base + first
        rsel = np.take(self._radius, run_t)
        wsel = np.take(self.th.strength.ravel(), run_t)
        q = 3.0 * dsel / rsel
        u = q * q
        w = wsel * np.exp(-u) * (1.0 - u)
        return np.where(hit, w, 0.0)


class Fader:
    """The fade cycle of a batch's thermals (seed ``fadeThermals``, §3.2), advanced in place
    by :meth:`step`; per-run parameters (B, 1) as in :func:`fade_step`."""

    def __init__(
        self, th: Thermals, *, by_time: NDArray[Any], rate: F8, top: F8, bottom: F8, dt: float
    ) -> None:
        self.th = th
        self.active = th.fade & th.valid
        self.any_active = bool(self.active.any())
        self.all_active = bool(self.active.all())
        self.rate = scalar_if_uniform(rate)
        self.incr = scalar_if_uniform(np.where(by_time, dt, 1.0))
        tol = np.where(by_time, 1e-9, 0.0)
        self.top_lim = scalar_if_uniform(top - tol)
        self.bottom_lim = scalar_if_uniform(bottom - tol)
        self.w_top = th.w_max - 1e-5

    def step(self) -> None:
        """Advance every active thermal by one step."""
        if not self.any_active:
            return
        th, act = self.th, self.active
        w, timer, direction = th.strength, th.timer, th.direction
        at_top = w >= self.w_top
        # round(w, 1) <= 1e-5 (half away from zero) <=> 10·w + 0.5 < 1: w < 0.05, or w < 0
        low = w * 10.0
        low += 0.5
        # on booleans, a > b is a & ~b and a >= b is a | ~b
        at_bottom = (low < 1.0) > at_top
        if self.all_active:
            top_done = at_top & (timer >= self.top_lim)
            bottom_done = at_bottom & (timer >= self.bottom_lim)
            np.copyto(direction, -1.0, where=top_done)
            np.copyto(direction, 1.0, where=bottom_done)
            done = top_done | bottom_done
            edge = at_top | at_bottom
            np.copyto(w, w + direction * self.rate, where=done >= edge)
            np.add(timer, self.incr, out=timer, where=edge > done)
            np.copyto(timer, 0.0, where=done)
            return
        top_done = at_top & (timer >= self.top_lim) & act
        bottom_done = at_bottom & (timer >= self.bottom_lim) & act
        np.copyto(direction, -1.0, where=top_done)
        np.copyto(direction, 1.0, where=bottom_done)
        done = top_done | bottom_done
        edge = at_top | at_bottom
        moving = (act & ~edge) | done
        np.copyto(w, w + direction * self.rate, where=moving)
        np.add(timer, self.incr, out=timer, where=edge & act & ~done)
        np.copyto(timer, 0.0, where=done)


def fade_step(
    th: Thermals, *, by_time: NDArray[Any], rate: F8, top: F8, bottom: F8, dt: float
) -> None:
    """Advance the fade cycle by one step, in place (seed ``fadeThermals``, §3.2).

    Per run (arrays (B, 1)): ``rate`` is the change of W per step, m/s; ``top``/``bottom`` the
    plateau lengths, in steps (``by_time`` False: the timer counts steps) or seconds (True: the
    timer counts seconds, ``dt`` per step, so the cycle does not depend on dt).
    """
    Fader(th, by_time=by_time, rate=rate, top=top, bottom=bottom, dt=dt).step()
