"""The continuous flight model's kernels (:class:`sim_core.flight.FlightModel`), on flat
(row, M) arrays: its right-hand side (with the seed's polar
:func:`~sim_core.soaring.kernels.kinematics.sink`) and the stages and end of an RK4 sub-step."""

from __future__ import annotations

import math

import numpy as np

from sim_core.soaring.kernels.arith import jit
from sim_core.soaring.kernels.kinematics import sink

#: rows of its per-vehicle table ``fp`` (FP_ROWS, M): bank τ s, bank rate limit rad/s, airspeed
#: τ s, airspeed rate limit m/s², polar A, B, C, g m/s², floor m, ceiling m
(FP_BANK_TAU, FP_BANK_RATE, FP_SPEED_TAU, FP_SPEED_RATE, FP_A, FP_B, FP_C, FP_G, FP_FLOOR,
 FP_CEIL) = range(10)
FP_ROWS = 10


@jit
def _clip(x: float, lo: float, hi: float) -> float:
    """np.clip of a scalar (NaN stays NaN)."""
    if x < lo:
        return lo
    if x > hi:
        return hi
    return x


@jit
def flight_rhs(y: np.ndarray, u: np.ndarray, w: np.ndarray, fp: np.ndarray,
               glide: np.ndarray, out: np.ndarray) -> None:
    """out (6, M) = dy/dt of states y (6, M) under commands u (2, M) in updrafts w (M,) m/s
    (the right-hand side of sim_core.flight, its module docstring)."""
    for m in range(y.shape[1]):
        psi, bank, v = y[3, m], y[4, m], y[5, m]
        out[0, m] = v * math.cos(psi)
        out[1, m] = v * math.sin(psi)
        out[2, m] = (sink(v, bank, fp[FP_A, m], fp[FP_B, m], fp[FP_C, m]) + w[m]
                     if glide[m] else 0.0)
        out[3, m] = fp[FP_G, m] * math.tan(bank) / v
        out[4, m] = _clip((u[0, m] - bank) / fp[FP_BANK_TAU, m], -fp[FP_BANK_RATE, m],
                          fp[FP_BANK_RATE, m])
        out[5, m] = _clip((u[1, m] - v) / fp[FP_SPEED_TAU, m], -fp[FP_SPEED_RATE, m],
                          fp[FP_SPEED_RATE, m])


@jit
def flight_stage(cur: np.ndarray, a: float, k: np.ndarray, out: np.ndarray) -> None:
    """out = cur + a·k (an RK4 stage's state), (6, M)."""
    for r in range(cur.shape[0]):
        for m in range(cur.shape[1]):
            out[r, m] = cur[r, m] + a * k[r, m]


@jit
def flight_finish(cur: np.ndarray, k1: np.ndarray, k2: np.ndarray, k3: np.ndarray,
                  k4: np.ndarray, h: float, fp: np.ndarray, glide: np.ndarray,
                  live: np.ndarray, grounded: np.ndarray) -> None:
    """End an RK4 sub-step of ``h`` s in place: cur (6, M) += h/6 (k1 + 2 k2 + 2 k3 + k4) where
    ``live`` (M,), then a glider's height limits: above the ceiling it is held at it, below the
    floor at the floor, unless it reached z <= 0: then it keeps its state, leaves ``live`` and
    is marked in ``grounded`` (M,)."""
    h6 = h / 6.0
    for m in range(cur.shape[1]):
        if not live[m]:
            continue
        z = cur[2, m] + h6 * (((k1[2, m] + 2.0 * k2[2, m]) + 2.0 * k3[2, m]) + k4[2, m])
        if glide[m]:
            below = z < fp[FP_FLOOR, m]
            if below and z <= 0.0:
                grounded[m] = True
                live[m] = False
                continue
            if z > fp[FP_CEIL, m]:
                z = fp[FP_CEIL, m]
            elif below:
                z = fp[FP_FLOOR, m]
        for r in range(6):
            if r != 2:
                cur[r, m] = cur[r, m] + h6 * (((k1[r, m] + 2.0 * k2[r, m]) + 2.0 * k3[r, m])
                                              + k4[r, m])
        cur[2, m] = z
