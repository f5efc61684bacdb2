"""One glider's flight step in the seed's model (spec §3.3): the sink polar, the command from a
desired acceleration, and the rate-limited, clipped step of position, heading, speed and bank."""

from __future__ import annotations

import math

import numpy as np

from sim_core.soaring.kernels.arith import fma, jit, maximum, norm2, sign, spow
from sim_core.soaring.kernels.layout import (
    A_MAX,
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


@jit
def sink(v: float, bank: float, a: float, b: float, c: float) -> float:
    """Polar sink, m/s (< 0 = sinking): (A v² + B v + C) / sqrt(cos φ)."""
    return (a * spow(v, 2.0) + b * v + c) / math.sqrt(math.cos(bank))


@jit
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


@jit
def _slew(cmd: float, old: float, rate: float, dt: float) -> float:
    lim = rate * dt
    if math.isinf(lim):
        return cmd
    d = cmd - old
    if d == d:
        d = d if d > -lim else -lim
        d = d if d < lim else lim
    return old + d


@jit
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

