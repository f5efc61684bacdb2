"""The glider (``docs/spec/seed_models.md`` §3.3): polar sink, the command an acceleration asks
for, and one step of flight under rate and range limits; with their elementwise entry points.
"""

from __future__ import annotations

import math

import numpy as np

from sim_core.soaring.kernels import (
    P_B_MAX,
    P_B_MIN,
    P_BANK_RATE,
    P_CEIL,
    P_FLOOR,
    P_G,
    P_SINK_A,
    P_SINK_B,
    P_SINK_C,
    P_SPEED_RATE,
    P_V_MAX,
    P_V_MIN,
)
from sim_core.soaring.kernels.cache import kernel
from sim_core.soaring.kernels.octave import fma, maximum, norm2, sign, spow

__all__ = ["A_MAX", "command", "command_many", "fly", "fly_many", "sink", "sink_many"]

#: Acceleration components beyond ±A_MAX (m/s², or infinite, or NaN → 0) are clipped to it, so
#: ‖a‖² cannot overflow (never hit in the seed's runs, whose |a| stays below 1e6).
A_MAX = 1e100


@kernel
def sink(v: float, bank: float, a: float, b: float, c: float) -> float:
    """Polar sink, m/s (< 0 = sinking): (A v² + B v + C) / sqrt(cos φ)."""
    return (a * spow(v, 2.0) + b * v + c) / math.sqrt(math.cos(bank))


@kernel
def command(ax: float, ay: float, c: float, s: float, speed: float, dt: float, g: float,
            tbf: float, w: float) -> tuple[float, float]:
    """Desired planar acceleration → (airspeed_cmd m/s, bank_cmd rad), unclipped."""
    norm = norm2(ax, ay)
    if not norm <= A_MAX:
        ax = 0.0 if ax != ax else min(max(ax, -A_MAX), A_MAX)
        ay = 0.0 if ay != ay else min(max(ay, -A_MAX), A_MAX)
        norm = norm2(ax, ay)
    a_f = fma(ay, s, ax * c)
    a_c = math.sqrt(maximum(spow(norm, 2.0) - spow(a_f, 2.0), 0.0))
    if norm - abs(a_f) < 1e-6:
        a_c = 0.0
    a_c = a_c * sign(ay * c - ax * s)
    v_cmd = a_f * dt / 10.0 + speed
    bank = math.atan(a_c / g)
    return v_cmd, tbf * w * sign(bank) + bank


@kernel
def _slew(cmd: float, old: float, rate: float, dt: float) -> float:
    lim = rate * dt
    if math.isinf(lim):
        return cmd
    d = cmd - old
    if d == d:
        d = d if d > -lim else -lim
        d = d if d < lim else lim
    return old + d


@kernel
def fly(x: float, y: float, z: float, heading: float, bank: float, speed: float, v_cmd: float,
        b_cmd: float, w: float, c: float, s: float, dt: float, p: np.ndarray
        ) -> tuple[float, float, float, float, float, float, float, float, bool]:
    """One glider step of dt s from the commands (rate limits, then speed/bank limits), with
    (c, s) = (cos ψ, sin ψ) of the old heading. Returns (x, y, z, heading, omega, speed, bank,
    vz, ground); ``ground``: the new z reached the floor at z <= 0 (the seed's ground death)."""
    v_cmd = _slew(v_cmd, speed, p[P_SPEED_RATE], dt)
    b_cmd = _slew(b_cmd, bank, p[P_BANK_RATE], dt)
    v_max, v_min, b_max, b_min = p[P_V_MAX], p[P_V_MIN], p[P_B_MAX], p[P_B_MIN]
    nv = v_max if v_cmd > v_max else (v_min if v_cmd < v_min else v_cmd)
    nb = b_max if b_cmd > b_max else (b_min if b_cmd < b_min else b_cmd)
    omega = math.tan(nb) * p[P_G] / nv
    vz = sink(nv, nb, p[P_SINK_A], p[P_SINK_B], p[P_SINK_C]) + w
    nx = x + nv * c * dt
    ny = y + nv * s * dt
    nz = z + vz * dt
    floor = p[P_FLOOR]
    below = nz < floor
    ground = below and nz <= 0.0
    nz = p[P_CEIL] if nz > p[P_CEIL] else (floor if below else nz)
    return nx, ny, nz, heading + omega * dt, omega, nv, nb, vz, ground


# -- elementwise entry points of the public wrappers (flat float64 arrays) ----------------------
@kernel
def sink_many(v: np.ndarray, bank: np.ndarray, a: np.ndarray, b: np.ndarray,
              c: np.ndarray) -> np.ndarray:
    out = np.empty_like(v)
    for m in range(v.shape[0]):
        out[m] = sink(v[m], bank[m], a[m], b[m], c[m])
    return out


@kernel
def command_many(ax: np.ndarray, ay: np.ndarray, c: np.ndarray, s: np.ndarray,
                 speed: np.ndarray, dt: float, g: np.ndarray, tbf: np.ndarray,
                 w: np.ndarray) -> np.ndarray:
    out = np.empty((2, ax.shape[0]))
    for m in range(ax.shape[0]):
        out[0, m], out[1, m] = command(ax[m], ay[m], c[m], s[m], speed[m], dt, g[m], tbf[m],
                                       w[m])
    return out


@kernel
def fly_many(X: np.ndarray, dt: float, par: np.ndarray) -> np.ndarray:
    """X (11, M): x, y, z, heading, bank, speed, v_cmd, b_cmd, w, cos, sin; par (M, len(PAR)).
    Returns (9, M): x, y, z, heading, omega, speed, bank, vz, ground (1.0/0.0)."""
    out = np.empty((9, X.shape[1]))
    for m in range(X.shape[1]):
        x, y, z, h, om, v, bank, vz, ground = fly(
            X[0, m], X[1, m], X[2, m], X[3, m], X[4, m], X[5, m], X[6, m], X[7, m], X[8, m],
            X[9, m], X[10, m], dt, par[m])
        out[0, m], out[1, m], out[2, m], out[3, m], out[4, m] = x, y, z, h, om
        out[5, m], out[6, m], out[7, m], out[8, m] = v, bank, vz, 1.0 if ground else 0.0
    return out
