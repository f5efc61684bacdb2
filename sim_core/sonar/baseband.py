"""Complex baseband (IQ) for narrow links: mix to the band centre, low-pass, decimate.

The echo of :func:`sim_core.sonar.synthesize` is one period of a band-limited periodic signal
(it is an inverse FFT), so mixing, an ideal (brick-wall) low-pass and decimation are done
exactly in the frequency domain: the bins within f_center +- fs_out/2 are kept and shifted to
0 Hz, and an inverse FFT of N/decimation points gives the IQ samples. The only error is the
energy of ``samples`` outside that window (zero for an echo whose band fits; measured in
BENCHMARKS.md and tests).
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike, NDArray

__all__ = ["from_baseband", "to_baseband"]


def _check(fs: float, f_center: float, decimation: int, n: int) -> None:
    if isinstance(decimation, bool) or not isinstance(decimation, int | np.integer):
        raise ValueError(f"decimation must be an integer >= 1, got {decimation!r}")
    if decimation < 1:
        raise ValueError(f"decimation must be an integer >= 1, got {decimation!r}")
    if not (np.isfinite(fs) and fs > 0):
        raise ValueError(f"fs must be a finite number > 0, got {fs!r}")
    if not (np.isfinite(f_center) and 0 <= f_center <= fs / 2):
        raise ValueError(f"f_center must be in [0, fs/2] = [0, {fs / 2}], got {f_center!r}")
    if n % decimation:
        raise ValueError(f"decimation {decimation} must divide the number of samples {n}")


def _bins(n: int, fs: float, f_center: float, decimation: int) -> tuple[NDArray[np.intp], int]:
    """Signed FFT bins of the IQ window (n_out,) and the centre bin."""
    n_out = n // decimation
    k_c = round(f_center * n / fs)
    offsets = np.fft.fftfreq(n_out, 1.0 / n_out).astype(np.intp)  # -n_out/2 .. n_out/2-1
    return offsets, k_c


def to_baseband(
    samples: ArrayLike, fs: float, f_center: float, decimation: int
) -> tuple[NDArray[np.complex128], float]:
    """Real echo (..., N) at ``fs`` Hz -> complex IQ (..., N / decimation) at fs / decimation.

    iq(t) = lowpass(x(t) e^{-j 2 pi f_c t}) sampled every ``decimation`` samples, with f_c the
    bin nearest ``f_center``; keeps |f - f_c| < fs / (2 decimation), so pick
    decimation <= fs / bandwidth (20 for the default 60-80 kHz band at 400 kHz).
    x = 2 Re(iq e^{j 2 pi f_c t}) recovers the echo (:func:`from_baseband`).
    """
    x = np.asarray(samples, dtype=np.float64)
    n = x.shape[-1]
    _check(fs, f_center, decimation, n)
    offsets, k_c = _bins(n, fs, f_center, decimation)
    spec = np.fft.fft(x, axis=-1)
    picked = spec[..., (k_c + offsets) % n]
    positive = (k_c + offsets >= 0) & (k_c + offsets <= n // 2)
    picked = np.where(positive, picked, 0.0)
    n_out = n // decimation
    iq = np.fft.ifft(picked, axis=-1) * (n_out / n)
    return np.asarray(iq, dtype=np.complex128), fs / decimation


def from_baseband(
    iq: ArrayLike, fs_out: float, f_center: float, decimation: int, n: int
) -> NDArray[np.float64]:
    """Inverse of :func:`to_baseband`: the real echo (..., n) at fs_out * decimation Hz."""
    z = np.asarray(iq, dtype=np.complex128)
    fs = fs_out * decimation
    _check(fs, f_center, decimation, n)
    if z.shape[-1] != n // decimation:
        raise ValueError(f"iq must have {n // decimation} samples for n={n}, got {z.shape[-1]}")
    offsets, k_c = _bins(n, fs, f_center, decimation)
    spec_iq = np.fft.fft(z, axis=-1) * (n / z.shape[-1])
    full = np.zeros((*z.shape[:-1], n // 2 + 1), dtype=np.complex128)
    k = k_c + offsets
    ok = (k >= 0) & (k <= n // 2)
    full[..., k[ok]] = spec_iq[..., ok]
    return np.asarray(np.fft.irfft(full, n=n, axis=-1), dtype=np.float64)
