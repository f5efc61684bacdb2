"""Synthetic leaf clouds and closed-form helpers shared by the sonar tests."""

from __future__ import annotations

from collections.abc import Callable

import numpy as np
from numpy.typing import NDArray
from scipy.special import erf

from sim_core.rng import make_rng

V = 340.0
FS = 400e3
N = 24000


def cone_cloud(
    m: int, *, seed: int = 0, half_angle_deg: float = 8.0, r_lo: float = 1.0, r_hi: float = 8.0
) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64]]:
    """``m`` leaves in a cone around +x from the origin: (centers, normals, radii)."""
    rng = make_rng(seed)
    r = rng.uniform(r_lo, r_hi, m)
    th = np.radians(half_angle_deg) * np.sqrt(rng.uniform(0.0, 1.0, m))
    ph = rng.uniform(0.0, 2.0 * np.pi, m)
    st = np.sin(th)
    centers = np.stack([r * np.cos(th), r * st * np.cos(ph), r * st * np.sin(ph)], 1)
    normals = rng.normal(size=(m, 3))
    radii = np.clip(rng.normal(0.025, 0.005, m), 0.0, 0.5)
    return centers, normals, radii


def rel_l2(x: NDArray[np.float64], ref: NDArray[np.float64]) -> float:
    den = float(np.linalg.norm(ref))
    return float(np.linalg.norm(x - ref)) / den if den > 0 else float(np.linalg.norm(x))


def envelope(h: NDArray[np.float64]) -> NDArray[np.float64]:
    """|analytic signal| of a real signal (exact for a band-limited periodic signal)."""
    spec = np.fft.fft(h)
    n = h.shape[-1]
    gain = np.zeros(n)
    gain[0] = 1.0
    gain[1 : (n + 1) // 2] = 2.0
    if n % 2 == 0:
        gain[n // 2] = 1.0
    return np.abs(np.fft.ifft(spec * gain))


def single_leaf_peak(
    r: float,
    a: float,
    beta: float,
    spreading: bool = True,
    factor: Callable[[NDArray[np.float64]], NDArray[np.float64]] | None = None,
    gain: float = 1.0,
    cap: float | None = None,
) -> float:
    """Closed-form envelope peak of one leaf at t = 2r/v (spec formulas, default band).

    ``factor(f)`` multiplies the amplitude per frequency, ``gain`` is the two-way beam gain S,
    ``cap`` replaces g0 L / k by min(g0 L / k, cap).
    """
    df = FS / N
    k = np.arange(1201)
    f = (3600 + k) * df
    w = 0.5 * (1.0 - np.cos(2.0 * np.pi * k / 1201))
    kk = 2.0 * np.pi * f / V
    c = kk * a
    p1 = 0.5003 * c**2 + 0.6867
    p2 = 0.3999 * c**-0.9065 + 0.9979
    lb = np.maximum(0.0, p1 * np.cos(p2 * beta))
    psi = erf((0.9824 * c**0.3523 - 0.9459) * (1.57 - beta)) - 2.6343
    amp = 0.2 * lb / kk
    if cap is not None:
        amp = np.minimum(amp, cap)
    amp = gain * amp / (r * r if spreading else 1.0)
    if factor is not None:
        amp = amp * factor(f)
    return float(4.0 / N * abs(np.sum(w * amp * np.exp(-1j * psi))))
