"""The International Standard Atmosphere (ICAO Doc 7488, ISO 2533) to 20 km: what a barometer,
a thermometer and a pitot tube read in still standard air.

Heights are geometric metres above mean sea level, turned into geopotential ones
(``H = r0 h / (r0 + h)``, r0 = 6,356,766 m) for the two layers: the troposphere (lapse rate
6.5 K/km from 288.15 K and 101,325 Pa at sea level) and the isothermal stratosphere from 11 km
(216.65 K, 22,632.06 Pa). Below sea level the troposphere's law goes on (the Dead Sea is at
-430 m). Every function is vectorised over its arrays.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike, NDArray

__all__ = [
    "G0",
    "P0",
    "RHO0",
    "R_AIR",
    "T0",
    "dynamic_pressure",
    "isa",
    "pressure_altitude",
]

F8 = NDArray[np.float64]

#: standard gravity m/s²
G0 = 9.80665
#: specific gas constant of dry air J/(kg K)
R_AIR = 287.05287
#: sea-level temperature K, pressure Pa, density kg/m³
T0 = 288.15
P0 = 101325.0
RHO0 = P0 / (R_AIR * T0)
_LAPSE = 0.0065
_R_EARTH = 6356766.0
_H11 = 11000.0
_T11 = T0 - _LAPSE * _H11
_EXP = G0 / (R_AIR * _LAPSE)
_P11 = P0 * (_T11 / T0) ** _EXP
_H_MAX = 20000.0


def _geopotential(h: F8) -> F8:
    return _R_EARTH * h / (_R_EARTH + h)


def isa(height_m: ArrayLike) -> tuple[F8, F8, F8]:
    """``(pressure Pa, temperature K, density kg/m³)`` at ``height_m`` (any shape) m above
    mean sea level; ``ValueError`` above 20 km or below -5 km (outside the two layers)."""
    h = np.asarray(height_m, dtype=np.float64)
    if h.size and not (np.all(h <= _H_MAX) and np.all(h >= -5000.0)):
        bad = h[(h > _H_MAX) | (h < -5000.0) | ~np.isfinite(h)].ravel()[0]
        raise ValueError(f"height {bad} m is outside the ISA's layers modelled here "
                         f"(-5000 m to {_H_MAX:.0f} m)")
    hg = _geopotential(h)
    t = T0 - _LAPSE * hg
    p = P0 * (t / T0) ** _EXP
    high = hg > _H11
    if high.any():  # the stratosphere's layer, where asked for
        t = np.where(high, _T11, t)
        p = np.where(high, _P11 * np.exp(-G0 * (hg - _H11) / (R_AIR * _T11)), p)
    return p, t, p / (R_AIR * t)


def pressure_altitude(pressure_pa: ArrayLike) -> F8:
    """The ISA geopotential height m whose pressure is ``pressure_pa`` (any shape): what an
    altimeter set to 1013.25 hPa shows (the inverse of :func:`isa`'s pressure)."""
    p = np.asarray(pressure_pa, dtype=np.float64)
    high = p < _P11
    h = (T0 / _LAPSE) * (1.0 - (np.maximum(p, _P11) / P0) ** (1.0 / _EXP))
    if high.any():  # the stratosphere's layer, where asked for
        h = np.where(high, _H11 - R_AIR * _T11 / G0 * np.log(np.minimum(p, _P11) / _P11), h)
    return h


def dynamic_pressure(density: ArrayLike, true_airspeed: ArrayLike) -> F8:
    """``½ ρ V²`` Pa: what a pitot-static tube's differential pressure reads at true airspeed
    V (m/s) through air of ``density`` kg/m³ (incompressible: below Mach 0.3 the compressible
    reading is higher by M²/4, 0.09 % at 35 m/s)."""
    v = np.asarray(true_airspeed, dtype=np.float64)
    return 0.5 * np.asarray(density, dtype=np.float64) * v * v
