"""The International Standard Atmosphere (ICAO Doc 7488, ISO 2533) to 20 km: what a barometer,
a thermometer and a pitot tube read in still standard air.

Heights are geometric metres above mean sea level, turned into geopotential ones
(``H = r0 h / (r0 + h)``, r0 = 6,356,766 m) for the two layers: the troposphere (lapse rate
6.5 K/km from 288.15 K and 101,325 Pa at sea level) and the isothermal stratosphere from 11 km
(216.65 K, 22,632.06 Pa). Below sea level the troposphere's law goes on (the Dead Sea is at
-430 m). Every function is vectorised over its arrays; the ISA's own formulas are compiled
(:mod:`sim_core.sensors.kernels`), the same the sensor model reads barometers with.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike, NDArray

from sim_core.sensors import kernels

__all__ = [
    "G0",
    "P0",
    "RHO0",
    "R_AIR",
    "T0",
    "dynamic_pressure",
    "equivalent_airspeed",
    "isa",
    "pressure_altitude",
]

F8 = NDArray[np.float64]

#: standard gravity m/s²
G0 = kernels.G0
#: specific gas constant of dry air J/(kg K)
R_AIR = kernels.R_AIR
#: sea-level temperature K, pressure Pa, density kg/m³
T0 = kernels.T0
P0 = kernels.P0
RHO0 = P0 / (R_AIR * T0)


def isa(height_m: ArrayLike) -> tuple[F8, F8, F8]:
    """``(pressure Pa, temperature K, density kg/m³)`` at ``height_m`` (any shape) m above
    mean sea level; ``ValueError`` above 20 km or below -5 km (outside the two layers)."""
    h = np.asarray(height_m, dtype=np.float64)
    flat = np.ascontiguousarray(h).ravel()
    p, t, rho = np.empty_like(flat), np.empty_like(flat), np.empty_like(flat)
    if not kernels.isa_into(flat, p, t, rho):
        bad = flat[~((flat >= kernels.H_MIN) & (flat <= kernels.H_MAX))][0]
        raise ValueError(f"height {bad} m is outside the ISA's layers modelled here "
                         f"({kernels.H_MIN:.0f} m to {kernels.H_MAX:.0f} m)")
    return p.reshape(h.shape), t.reshape(h.shape), rho.reshape(h.shape)


def pressure_altitude(pressure_pa: ArrayLike) -> F8:
    """The ISA geopotential height m whose pressure is ``pressure_pa`` (any shape): what an
    altimeter set to 1013.25 hPa shows (the inverse of :func:`isa`'s pressure)."""
    p = np.asarray(pressure_pa, dtype=np.float64)
    flat = np.ascontiguousarray(p).ravel()
    out = np.empty_like(flat)
    kernels.pressure_altitude_into(flat, out)
    return out.reshape(p.shape)


def dynamic_pressure(density: ArrayLike, true_airspeed: ArrayLike) -> F8:
    """``½ ρ V²`` Pa: what a pitot-static tube's differential pressure reads at true airspeed
    V (m/s) through air of ``density`` kg/m³ (incompressible: below Mach 0.3 the compressible
    reading is higher by M²/4, 0.09 % at 35 m/s)."""
    v = np.asarray(true_airspeed, dtype=np.float64)
    return 0.5 * np.asarray(density, dtype=np.float64) * v * v


def equivalent_airspeed(true_airspeed: ArrayLike, density: ArrayLike) -> F8:
    """``V √(ρ / ρ0)`` m/s: the airspeed a pitot calibrated at sea level shows (indicated
    airspeed, for an ideal instrument) at true airspeed V through air of ``density``."""
    return np.asarray(true_airspeed, dtype=np.float64) * np.sqrt(
        np.asarray(density, dtype=np.float64) / RHO0)
