"""Complex baseband (IQ) for narrow links: mix to the band centre, low-pass, decimate.

The echo of :func:`sim_core.sonar.synthesize` is one period of a band-limited periodic signal
(it is an inverse FFT), so mixing and an ideal (brick-wall) low-pass are done exactly in the
frequency domain: the bins within f_center +- fs_out/2 are kept and shifted to 0 Hz, an
inverse FFT gives the complex baseband at fs, and every ``decimation``-th sample is kept. The
only error is the energy of ``samples`` outside that window (zero for an echo whose band fits;
measured in BENCHMARKS.md and tests).
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike, NDArray

__all__ = ["envelope_db", "from_baseband", "to_baseband"]


def _check(fs: float, f_center: float, decimation: int) -> None:
    if isinstance(decimation, bool) or not isinstance(decimation, int | np.integer):
        raise ValueError(f"decimation must be an integer >= 1, got {decimation!r}")
    if decimation < 1:
        raise ValueError(f"decimation must be an integer >= 1, got {decimation!r}")
    if not (np.isfinite(fs) and fs > 0):
        raise ValueError(f"fs must be a finite number > 0, got {fs!r}")
    if not (np.isfinite(f_center) and 0 <= f_center <= fs / 2):
        raise ValueError(f"f_center must be in [0, fs/2] = [0, {fs / 2}], got {f_center!r}")


def _window(n: int, fs: float, f_center: float, decimation: int) -> tuple[NDArray[np.intp], int]:
    """Signed bin offsets kept around the centre bin (|f - f_c| < fs / (2 decimation))."""
    k_c = round(f_center * n / fs)
    half = n / (2.0 * decimation)
    lo = -int(np.floor(half)) if half != np.floor(half) else -int(half)
    hi = int(np.ceil(half))  # exclusive
    return np.arange(lo, hi, dtype=np.intp), k_c


def to_baseband(
    samples: ArrayLike, fs: float, f_center: float, decimation: int
) -> tuple[NDArray[np.complex128], float]:
    """Real echo (..., N) at ``fs`` Hz -> complex IQ (..., ceil(N / decimation)) at fs/decimation.

    iq[m] = lowpass(x(t) e^{-j 2 pi f_c t})(m decimation / fs) with f_c the bin nearest
    ``f_center`` and an ideal low-pass keeping |f - f_c| < fs / (2 decimation); so pick
    decimation <= fs / bandwidth (20 for the default 60-80 kHz band at 400 kHz, lossless up to
    16). x = 2 Re(iq e^{j 2 pi f_c t}) recovers the echo (:func:`from_baseband`).
    """
    x = np.asarray(samples, dtype=np.float64)
    n = x.shape[-1]
    _check(fs, f_center, decimation)
    offsets, k_c = _window(n, fs, f_center, decimation)
    k = k_c + offsets
    keep = (k >= 0) & (k <= n // 2)
    spec = np.fft.fft(x, axis=-1)
    shifted = np.zeros(spec.shape, dtype=np.complex128)
    shifted[..., offsets[keep] % n] = spec[..., k[keep]]
    iq = np.fft.ifft(shifted, axis=-1)[..., ::decimation]
    return np.asarray(iq, dtype=np.complex128), fs / decimation


def from_baseband(
    iq: ArrayLike, fs_out: float, f_center: float, decimation: int, n: int
) -> NDArray[np.float64]:
    """Inverse of :func:`to_baseband` for ``decimation`` dividing ``n``: the echo (..., n)."""
    z = np.asarray(iq, dtype=np.complex128)
    fs = fs_out * decimation
    _check(fs, f_center, decimation)
    if n % decimation or z.shape[-1] != n // decimation:
        raise ValueError(
            f"from_baseband needs decimation {decimation} dividing n={n} and "
            f"{n // decimation} IQ samples, got {z.shape[-1]}"
        )
    offsets, k_c = _window(n, fs, f_center, decimation)
    n_out = z.shape[-1]
    spec_iq = np.fft.fft(z, axis=-1) * (n / n_out)
    full = np.zeros((*z.shape[:-1], n // 2 + 1), dtype=np.complex128)
    k = k_c + offsets
    ok = (k >= 0) & (k <= n // 2)
    full[..., k[ok]] = spec_iq[..., offsets[ok] % n_out]
    return np.asarray(np.fft.irfft(full, n=n, axis=-1), dtype=np.float64)


def envelope_db(samples: NDArray[np.floating], floor_db: float = -160.0) -> NDArray[np.float64]:
    """Hilbert envelope of ``samples`` (..., N) in dB re 1 (= re A0), floored at ``floor_db``."""
    from scipy.signal import hilbert

    env = np.abs(hilbert(np.asarray(samples, dtype=np.float64), axis=-1))
    with np.errstate(divide="ignore"):
        return np.maximum(20.0 * np.log10(env), floor_db)
