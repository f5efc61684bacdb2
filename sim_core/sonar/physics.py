"""Opt-in physics of the echo model: air absorption, incident-frequency beamwidth, calls, shading.

Every function is pure vectorised numpy; shapes and units are in each docstring.
"""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy.spatial import cKDTree

from sim_core.sonar.params import SIGMA_FACTOR, Call

__all__ = [
    "absorption_db_per_m",
    "call_waveform",
    "incident_freq_sigma",
    "shading_factor",
    "sound_speed_from_temperature",
]


def sound_speed_from_temperature(temperature_c: float) -> float:
    """Speed of sound in dry air, m/s: 331.3 sqrt(1 + T/273.15)."""
    return 331.3 * math.sqrt(1.0 + temperature_c / 273.15)


def absorption_db_per_m(
    f: ArrayLike, temperature_c: float, humidity_pct: float, pressure_kpa: float
) -> NDArray[np.float64]:
    """ISO 9613-1:1993 pure-tone atmospheric absorption coefficient, dB/m.

    ``f`` Hz (any shape), ``temperature_c`` degC, ``humidity_pct`` relative humidity in %,
    ``pressure_kpa`` ambient pressure in kPa. Returns alpha with the shape of ``f``.
    """
    f = np.asarray(f, dtype=np.float64)
    t_k = temperature_c + 273.15
    t0, t01, pr = 293.15, 273.16, 101.325
    pa = pressure_kpa / pr
    c_sat = -6.8346 * (t01 / t_k) ** 1.261 + 4.6151
    h = humidity_pct * 10.0**c_sat / pa
    fr_o = pa * (24.0 + 4.04e4 * h * (0.02 + h) / (0.391 + h))
    n_term = 280.0 * h * math.exp(-4.170 * ((t_k / t0) ** (-1.0 / 3.0) - 1.0))
    fr_n = pa * (t_k / t0) ** -0.5 * (9.0 + n_term)
    f2 = f * f
    return 8.686 * f2 * (
        1.84e-11 / pa * (t_k / t0) ** 0.5
        + (t_k / t0) ** -2.5
        * (
            0.01275 * math.exp(-2239.1 / t_k) / (fr_o + f2 / fr_o)
            + 0.1068 * math.exp(-3352.0 / t_k) / (fr_n + f2 / fr_n)
        )
    )


def incident_freq_sigma(f: ArrayLike) -> NDArray[np.float64]:
    """Gaussian beam sigma (rad) of the seed's horseshoe-bat ``'incident_freq'`` beamwidth.

    BW(f) = 0.011333 f^3 - 2.3219 f^2 + 156.15 f - 3402.7 degrees with f in kHz (seed code,
    fitted for about 55-85 kHz); ``f`` Hz, any shape. Raises ValueError where BW leaves (0, 180).
    """
    fk = np.asarray(f, dtype=np.float64) / 1e3
    bw_deg = ((0.011333 * fk - 2.3219) * fk + 156.15) * fk - 3402.7
    if np.any(~(bw_deg > 0.0)) or np.any(~(bw_deg < 180.0)):
        raise ValueError(
            "beam_model='incident_freq' gives a beamwidth outside (0, 180) deg for "
            f"frequencies {float(np.min(fk)):.1f}..{float(np.max(fk)):.1f} kHz; use a band "
            "inside about 50-90 kHz"
        )
    return np.radians(bw_deg) * 0.5 / SIGMA_FACTOR


def call_waveform(call: Call, fs: float) -> NDArray[np.float64]:
    """Emitted call sampled at ``fs`` Hz, unit peak, shape (L,), L = round(total_s * fs).

    FM: linear sweep f_start -> f_end; CF-FM: constant ``cf_hz`` then a sweep cf_hz -> f_end.
    A Hann taper of ``taper_s`` shapes onset and end.
    """
    n = max(2, round(call.total_s * fs))
    t = np.arange(n) / fs
    if call.kind == "fm":
        f0, f1, t_cf = call.f_start, call.f_end, 0.0
    else:
        f0, f1, t_cf = call.cf_hz, call.f_end, call.cf_duration_s
    tau = np.clip(t - t_cf, 0.0, None)
    rate = (f1 - f0) / call.duration_s
    phase = 2.0 * np.pi * (f0 * t + 0.5 * rate * tau * tau)
    wave = np.sin(phase)
    n_taper = min(n // 2, max(1, round(call.taper_s * fs)))
    ramp = 0.5 * (1.0 - np.cos(np.pi * np.arange(n_taper) / n_taper))
    wave[:n_taper] *= ramp
    wave[n - n_taper :] *= ramp[::-1]
    return wave


def shading_factor(
    directions: NDArray[np.float64],
    ranges: NDArray[np.float64],
    radii: NDArray[np.float64],
    cos_beta: NDArray[np.float64],
    opacity: float,
) -> NDArray[np.float64]:
    """Two-way shading transmission per leaf, shape (M,), in (0, 1].

    Approximate model (docs/sonar.md): leaf j occludes leaf i when j is nearer (r_j < r_i) and
    the direction to i passes through j's disc as seen from the sonar, i.e. the angle between
    u_i and u_j is below j's angular radius a_j sqrt(|cos beta_j|) / r_j (the disc's
    area-equivalent projected radius). Each occluder passes (1 - opacity) of the amplitude one
    way; the factor is (1 - opacity)^(2 n_i). Inputs: unit ``directions`` (M,3), ``ranges`` (M,)
    m, ``radii`` (M,) m, ``cos_beta`` (M,) = |n . u|.
    """
    m = ranges.shape[0]
    if m < 2 or opacity == 0.0:
        return np.ones(m)
    ang = np.minimum(radii * np.sqrt(np.abs(cos_beta)) / ranges, np.pi)
    chord = 2.0 * np.sin(0.5 * ang)
    tree = cKDTree(directions)
    hits = tree.query_ball_point(directions, chord, return_sorted=False)
    lengths = np.fromiter((len(h) for h in hits), dtype=np.int64, count=m)
    occluder = np.repeat(np.arange(m), lengths)
    target = np.fromiter((i for h in hits for i in h), dtype=np.int64, count=int(lengths.sum()))
    behind = ranges[target] > ranges[occluder]
    counts = np.bincount(target[behind], minlength=m)
    if opacity == 1.0:
        return np.where(counts > 0, 0.0, 1.0)
    return np.exp(2.0 * counts * math.log1p(-opacity))
