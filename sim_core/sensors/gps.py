"""A GNSS receiver: fixes at its own rate, late by its latency, with white and slowly
wandering position errors.

A fix due at sim time t (every ``1 / rate_hz`` s on the sim clock's grid) reports where the
vehicle was at ``t - latency_s`` (linear between the two truth samples around it), plus
errors: per axis east, north, up a first-order Gauss-Markov wander (standard deviation
``drift_sigma_m``, correlation time ``drift_tau_s``: a receiver's slowly moving bias) and white
noise (``horizontal_sigma_m``, ``vertical_sigma_m``); velocity has white noise
``velocity_sigma_mps``. ``eph_m`` and ``epv_m`` are what the receiver says of its accuracy
(standard deviations, as an autopilot reads them). Heights above the WGS-84 ellipsoid are
reported as heights above mean sea level (geoid undulation taken as 0).
"""

from __future__ import annotations

import math
from collections import deque
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

__all__ = ["GpsFix", "GpsReceiver", "GpsSpec"]

F8 = NDArray[np.float64]
_WGS84_A = 6378137.0
_WGS84_E2 = 6.69437999014e-3


@dataclass(frozen=True, slots=True)
class GpsSpec:
    """A receiver's rate, latency and errors (module docstring); ``satellites`` it reports."""

    rate_hz: float = 10.0
    latency_s: float = 0.1
    horizontal_sigma_m: float = 0.3
    vertical_sigma_m: float = 0.5
    drift_sigma_m: float = 0.7
    drift_tau_s: float = 60.0
    velocity_sigma_mps: float = 0.05
    eph_m: float = 1.0
    epv_m: float = 1.5
    satellites: int = 12

    def __post_init__(self) -> None:
        if not 0 < self.rate_hz <= 50:
            raise ValueError(f"rate_hz: expected 0 < rate <= 50, got {self.rate_hz}")
        if not 0 <= self.latency_s <= 1.0:
            raise ValueError(f"latency_s: expected 0 <= latency <= 1 s, got {self.latency_s}")
        for name in ("horizontal_sigma_m", "vertical_sigma_m", "drift_sigma_m",
                     "velocity_sigma_mps"):
            v = getattr(self, name)
            if not (math.isfinite(v) and v >= 0):
                raise ValueError(f"{name}: expected a finite value >= 0, got {v}")
        if not self.drift_tau_s > 0:
            raise ValueError(f"drift_tau_s: expected > 0, got {self.drift_tau_s}")
        if not (self.eph_m > 0 and self.epv_m > 0):
            raise ValueError(f"eph_m, epv_m: expected > 0, got {self.eph_m}, {self.epv_m}")
        if not 0 <= self.satellites <= 60:
            raise ValueError(f"satellites: expected 0..60, got {self.satellites}")

    @property
    def period_ns(self) -> int:
        return round(1e9 / self.rate_hz)


@dataclass(frozen=True, slots=True)
class GpsFix:
    """One fix of N receivers: ``t_ns`` when it is reported (sim time), ``measured_ns`` the
    instant it describes (``t_ns`` minus the latency); ``lat_deg``, ``lon_deg`` (N,),
    ``alt_m`` (N,) m above mean sea level, ``velocity`` (N, 3) m/s world ENU, and the
    receiver's ``eph_m``, ``epv_m``, ``satellites``; a 3-D fix."""

    t_ns: int
    measured_ns: int
    lat_deg: F8
    lon_deg: F8
    alt_m: F8
    velocity: F8
    eph_m: float
    epv_m: float
    satellites: int


class GpsReceiver:
    """N receivers of one :class:`GpsSpec`: :meth:`record` every truth sample, :meth:`fix`
    when one is due. ``rng``: None for no noise (the truth, late by the latency)."""

    def __init__(self, spec: GpsSpec, n: int, rng: np.random.Generator | None) -> None:
        self.spec = spec
        self.n = int(n)
        self._rng = rng
        keep = max(4, math.ceil(spec.latency_s * 1000.0) + 4)  # samples at up to 1 kHz
        self._hist: deque[tuple[int, F8, F8]] = deque(maxlen=keep)
        self._drift = np.zeros((self.n, 3))
        if rng is not None and spec.drift_sigma_m > 0:
            self._drift = rng.standard_normal((self.n, 3)) * spec.drift_sigma_m
        self._next_ns: int | None = None
        self._last_fix_ns: int | None = None

    def record(self, t_ns: int, truth: F8) -> None:
        """The truth at ``t_ns``: (N, 6+) rows of [lat deg, lon deg, height m, velocity m/s
        ENU, ...] (a truth table's first columns). Times must not go back (a repeated time
        replaces nothing)."""
        if self._hist and t_ns <= self._hist[-1][0]:
            return
        rows = np.array(truth[:, :6], dtype=np.float64)
        self._hist.append((int(t_ns), rows[:, :3], rows[:, 3:6]))
        if self._next_ns is None:
            period = self.spec.period_ns
            self._next_ns = -(-int(t_ns) // period) * period

    def due(self, t_ns: int) -> bool:
        """Whether a fix is due at ``t_ns`` (the first sample at or after each grid time)."""
        return self._next_ns is not None and t_ns >= self._next_ns

    def fix(self, t_ns: int) -> GpsFix:
        """The fix reported at ``t_ns`` (call when :meth:`due`); the schedule moves on to the
        next grid time after ``t_ns``."""
        spec = self.spec
        period = spec.period_ns
        self._next_ns = (int(t_ns) // period + 1) * period
        measured = int(t_ns) - round(spec.latency_s * 1e9)
        geo, vel = self._at(measured)
        if self._rng is not None:
            dt = 0.0 if self._last_fix_ns is None else (t_ns - self._last_fix_ns) / 1e9
            a = math.exp(-dt / spec.drift_tau_s)
            z = self._rng.standard_normal((self.n, 9))
            self._drift = self._drift * a + spec.drift_sigma_m * math.sqrt(1.0 - a * a) * z[:, :3]
            white = z[:, 3:6] * np.array([spec.horizontal_sigma_m, spec.horizontal_sigma_m,
                                          spec.vertical_sigma_m])
            geo = _offset(geo, self._drift + white)
            vel = vel + spec.velocity_sigma_mps * z[:, 6:9]
        self._last_fix_ns = int(t_ns)
        return GpsFix(t_ns=int(t_ns), measured_ns=measured, lat_deg=geo[:, 0],
                      lon_deg=geo[:, 1], alt_m=geo[:, 2], velocity=vel, eph_m=spec.eph_m,
                      epv_m=spec.epv_m, satellites=spec.satellites)

    def _at(self, t_ns: int) -> tuple[F8, F8]:
        """The truth at ``t_ns``, linear between the samples around it (the oldest before the
        history, the newest after it)."""
        hist = self._hist
        if not hist:
            raise ValueError("GpsReceiver.fix before any record()")
        if t_ns <= hist[0][0]:
            return hist[0][1].copy(), hist[0][2].copy()
        items = list(hist)
        for k in range(len(items) - 1, 0, -1):
            (t0, g0, v0), (t1, g1, v1) = items[k - 1], items[k]
            if t0 <= t_ns <= t1:
                w = (t_ns - t0) / (t1 - t0)
                return g0 + w * (g1 - g0), v0 + w * (v1 - v0)
        return hist[-1][1].copy(), hist[-1][2].copy()


def _offset(geo: F8, enu: F8) -> F8:
    """Geodetic (N, 3) [lat deg, lon deg, h m] moved by small ENU offsets (N, 3) m (local
    radii of curvature of WGS-84)."""
    lat = np.radians(geo[:, 0])
    s = np.sin(lat)
    w = np.sqrt(1.0 - _WGS84_E2 * s * s)
    n_rad = _WGS84_A / w
    m_rad = n_rad * (1.0 - _WGS84_E2) / (w * w)
    out = geo.copy()
    out[:, 0] += np.degrees(enu[:, 1] / (m_rad + geo[:, 2]))
    out[:, 1] += np.degrees(enu[:, 0] / ((n_rad + geo[:, 2]) * np.cos(lat)))
    out[:, 2] += enu[:, 2]
    return out
