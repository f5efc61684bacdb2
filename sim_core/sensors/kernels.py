"""The compiled kernels of the sensor model (numba, ``cache=True``): the ISA and one sample of
every vehicle's sensors, as scalar loops over float64.

They are *the* implementation: :func:`sim_core.sensors.atmosphere.isa` and
:func:`~sim_core.sensors.atmosphere.pressure_altitude` are wrappers over the same compiled
functions that :class:`sim_core.sensors.SensorSuite` samples with, so a reading and the
atmosphere a test computes agree to the bit. For one vehicle a sample costs a few µs here
against about 40 µs as numpy array passes (BENCHMARKS.md, *PX4 HIL*), which is most of a
lockstep step's budget. Compiled once per installation and CPU (``make`` calls
:func:`warm_up`), then loaded from numba's on-disk cache. All kernels live in this one module,
since numba invalidates a cache only when the cached function's own file changes.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit
from numpy.typing import NDArray

__all__ = ["TRUTH_COLUMNS", "isa_into", "pressure_altitude_into", "sample_into", "warm_up"]

F8 = NDArray[np.float64]

#: the columns of a truth table (N, 17)
TRUTH_COLUMNS = ("lat", "lon", "height", "vx", "vy", "vz", "qw", "qx", "qy", "qz", "p", "q",
                 "r", "fx", "fy", "fz", "airspeed")
#: the columns of a readings table (N, 14)
READING_COLUMNS = ("ax", "ay", "az", "gx", "gy", "gz", "mx", "my", "mz", "abs_pressure",
                   "diff_pressure", "pressure_alt", "temperature", "density")

G0 = 9.80665
R_AIR = 287.05287
T0 = 288.15
P0 = 101325.0
LAPSE = 0.0065
R_EARTH = 6356766.0
H11 = 11000.0
T11 = T0 - LAPSE * H11
EXP = G0 / (R_AIR * LAPSE)
P11 = P0 * (T11 / T0) ** EXP
H_MIN = -5000.0
H_MAX = 20000.0
_T0_C = 273.15


@njit(cache=True, nogil=True)
def _isa1(h: float) -> tuple[float, float, float]:  # pragma: no cover - compiled
    hg = R_EARTH * h / (R_EARTH + h)
    if hg <= H11:
        t = T0 - LAPSE * hg
        p = P0 * (t / T0) ** EXP
    else:
        t = T11
        p = P11 * math.exp(-G0 * (hg - H11) / (R_AIR * T11))
    return p, t, p / (R_AIR * t)


@njit(cache=True, nogil=True)
def _pressure_altitude1(p: float) -> float:  # pragma: no cover - compiled
    if p >= P11:
        return (T0 / LAPSE) * (1.0 - (p / P0) ** (1.0 / EXP))
    return H11 - R_AIR * T11 / G0 * math.log(p / P11)


@njit(cache=True, nogil=True)
def isa_into(h: F8, p: F8, t: F8, rho: F8) -> bool:  # pragma: no cover - compiled
    """ISA pressure Pa, temperature K, density kg/m³ at heights ``h`` m (flat arrays);
    False when a height is outside [-5 km, 20 km] or not finite (nothing is written then)."""
    for k in range(h.shape[0]):
        if not H_MIN <= h[k] <= H_MAX:
            return False
    for k in range(h.shape[0]):
        p[k], t[k], rho[k] = _isa1(h[k])
    return True


@njit(cache=True, nogil=True)
def pressure_altitude_into(p: F8, out: F8) -> None:  # pragma: no cover - compiled
    """The ISA geopotential height m of each pressure Pa (flat arrays)."""
    for k in range(p.shape[0]):
        out[k] = _pressure_altitude1(p[k])


@njit(cache=True, nogil=True)
def sample_into(truth: F8, field: F8, noise: F8, bias: F8, white: F8, walk: F8,
                baro_sigma: float, pitot_sigma: float, dt: float,
                out: F8) -> bool:  # pragma: no cover - compiled
    """One sample of N vehicles: ``truth`` (N, 17) (:data:`TRUTH_COLUMNS`), the field (N, 3)
    gauss ENU at each, ``noise`` (N, 17) standard normals (N = 0 rows: no noise), ``bias``
    (N, 6) accel and gyro biases (FLU, updated: a random walk of ``walk`` (6,) per √s),
    ``white`` (9,) accel, gyro, mag densities per √Hz, sigmas Pa, ``dt`` s since the last
    sample; writes ``out`` (N, 14) (:data:`READING_COLUMNS`; the density is the ISA's
    at the vehicle, not a reading: no noise). A vehicle outside the ISA's layers (or at a
    non-finite height) reads NaN on its barometer, pitot, temperature and density; False
    then."""
    noisy = noise.shape[0] > 0
    sw = 1.0 / math.sqrt(dt)
    sb = math.sqrt(dt)
    inside = True
    for k in range(truth.shape[0]):
        h = truth[k, 2]
        # the field in body axes: v_b = q* v_w q (t = 2 u x v with u the conjugate's vector)
        w, ux, uy, uz = truth[k, 6], -truth[k, 7], -truth[k, 8], -truth[k, 9]
        vx, vy, vz = field[k, 0], field[k, 1], field[k, 2]
        tx = 2.0 * (uy * vz - uz * vy)
        ty = 2.0 * (uz * vx - ux * vz)
        tz = 2.0 * (ux * vy - uy * vx)
        out[k, 6] = vx + w * tx + (uy * tz - uz * ty)
        out[k, 7] = vy + w * ty + (uz * tx - ux * tz)
        out[k, 8] = vz + w * tz + (ux * ty - uy * tx)
        if H_MIN <= h <= H_MAX:
            p, t, rho = _isa1(h)
        else:
            p, t, rho = math.nan, math.nan, math.nan
            inside = False
        tas = truth[k, 16]
        q = 0.5 * rho * tas * tas
        for j in range(3):
            out[k, j] = truth[k, 13 + j]
            out[k, 3 + j] = truth[k, 10 + j]
        if noisy:
            for j in range(6):
                bias[k, j] += noise[k, 11 + j] * (walk[j] * sb)
            for j in range(9):
                out[k, j] += (bias[k, j] if j < 6 else 0.0) + noise[k, j] * (white[j] * sw)
            p += baro_sigma * noise[k, 9]
            q += pitot_sigma * noise[k, 10]
        out[k, 9] = p
        out[k, 10] = q
        out[k, 11] = _pressure_altitude1(p)
        out[k, 12] = t - _T0_C
        out[k, 13] = rho
    return inside


def warm_up() -> None:
    """Compile, or load from the on-disk cache, every kernel here (before a realtime loop,
    or after installing)."""
    h = np.zeros(1)
    isa_into(h, np.empty(1), np.empty(1), np.empty(1))
    pressure_altitude_into(np.full(1, P0), np.empty(1))
    truth = np.zeros((1, 17))
    truth[0, 6] = 1.0
    sample_into(truth, np.zeros((1, 3)), np.zeros((0, 17)), np.zeros((1, 6)), np.zeros(9),
                np.zeros(6), 0.0, 0.0, 0.004, np.empty((1, 14)))
