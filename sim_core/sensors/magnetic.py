"""The Earth's magnetic field where a vehicle flies: the World Magnetic Model 2025 (NOAA/BGS),
evaluated by ``pygeomag`` (a pure-Python port of the WMM's own code, MIT licence).

The WMM is the model autopilots themselves carry (PX4's and ArduPilot's declination tables are
generated from it), so a magnetometer fed from here agrees with the field the firmware expects
at that place and date. WMM2025 is valid from 2025.0 to 2030.0; an ``epoch_year`` outside is
refused. The coefficients come from ``pygeomag``'s Python module (no file is read).
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

__all__ = ["WMM_VALID", "field_enu"]

#: the decimal years WMM2025 is valid for
WMM_VALID = (2025.0, 2030.0)
_NT_PER_GAUSS = 1e5
_MODEL: list[Any] = []


def _model() -> Any:
    if not _MODEL:
        from pygeomag import GeoMag
        from pygeomag.wmm.wmm_2025 import WMM_2025

        _MODEL.append(GeoMag(coefficients_data=WMM_2025))
    return _MODEL[0]


def field_enu(lat_deg: ArrayLike, lon_deg: ArrayLike, height_m: ArrayLike,
              epoch_year: float) -> NDArray[np.float64]:
    """The main field (N, 3) in gauss, world ENU axes, at geodetic ``lat_deg``, ``lon_deg``
    (N,) degrees and ``height_m`` (N,) m above the WGS-84 ellipsoid, at decimal year
    ``epoch_year`` (e.g. 2026.5). At 47° N 8° E in 2026 it is about 0.48 gauss, dipping 63°."""
    lo, hi = WMM_VALID
    if not (math.isfinite(epoch_year) and lo <= epoch_year < hi):
        raise ValueError(f"epoch_year: WMM2025 is valid for {lo} <= year < {hi}, got "
                         f"{epoch_year}")
    lat = np.atleast_1d(np.asarray(lat_deg, dtype=np.float64))
    lon = np.atleast_1d(np.asarray(lon_deg, dtype=np.float64))
    h = np.atleast_1d(np.asarray(height_m, dtype=np.float64))
    lat, lon, h = np.broadcast_arrays(lat, lon, h)
    model = _model()
    out = np.empty((lat.size, 3))
    for k, (la, lo_, hh) in enumerate(zip(lat.tolist(), lon.tolist(), h.tolist(), strict=True)):
        r = model.calculate(glat=la, glon=((lo_ + 180.0) % 360.0) - 180.0,
                            alt=hh / 1e3, time=epoch_year, allow_date_outside_lifespan=False,
                            raise_in_warning_zone=False)
        out[k] = r.y, r.x, -r.z  # WMM: x north, y east, z down (nT)
    return out / _NT_PER_GAUSS
