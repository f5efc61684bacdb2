"""Complex baseband (IQ) for narrow links: mix to the band centre, low-pass, decimate."""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy.signal import resample_poly

__all__ = ["from_baseband", "to_baseband"]


def _check(fs: float, f_center: float, decimation: int) -> None:
    if isinstance(decimation, bool) or not isinstance(decimation, int | np.integer):
        raise ValueError(f"decimation must be an integer >= 1, got {decimation!r}")
    if decimation < 1:
        raise ValueError(f"decimation must be an integer >= 1, got {decimation!r}")
    if not (np.isfinite(fs) and fs > 0):
        raise ValueError(f"fs must be a finite number > 0, got {fs!r}")
    if not (np.isfinite(f_center) and 0 <= f_center <= fs / 2):
        raise ValueError(f"f_center must be in [0, fs/2] = [0, {fs / 2}], got {f_center!r}")


def to_baseband(
    samples: ArrayLike, fs: float, f_center: float, decimation: int
) -> tuple[NDArray[np.complex128], float]:
    """Real echo (..., N) at ``fs`` Hz -> complex IQ (..., ceil(N / decimation)) at fs/decimation.

    iq[n] = lowpass(x(t) e^{-j 2 pi f_center t})[n * decimation]; the low-pass is the Kaiser
    FIR of ``scipy.signal.resample_poly`` (cut-off at the new Nyquist rate). Keeps
    |f - f_center| < fs / (2 decimation): pick decimation <= fs / bandwidth.
    The amplitude is that of the analytic signal / 2 (x = 2 Re(iq e^{j 2 pi f_center t})).
    """
    _check(fs, f_center, decimation)
    x = np.asarray(samples, dtype=np.float64)
    t = np.arange(x.shape[-1]) / fs
    mixed = x * np.exp(-2j * np.pi * f_center * t)
    if decimation == 1:
        return mixed, float(fs)
    iq = resample_poly(mixed, 1, int(decimation), axis=-1)
    return np.asarray(iq, dtype=np.complex128), fs / decimation


def from_baseband(
    iq: ArrayLike, fs_out: float, f_center: float, decimation: int, n: int
) -> NDArray[np.float64]:
    """Inverse of :func:`to_baseband`: interpolate back to fs_out * decimation, remix, 2 Re.

    Returns (..., n) real samples; used to measure the decimation error in-band.
    """
    fs = fs_out * decimation
    _check(fs, f_center, decimation)
    z = np.asarray(iq, dtype=np.complex128)
    up = resample_poly(z, int(decimation), 1, axis=-1) if decimation > 1 else z
    up = up[..., :n]
    t = np.arange(up.shape[-1]) / fs
    return np.asarray(2.0 * np.real(up * np.exp(2j * np.pi * f_center * t)), dtype=np.float64)
