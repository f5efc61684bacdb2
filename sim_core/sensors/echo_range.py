"""The echo → range rule of every range finder in echoloop: the first return above a threshold,
by its time of flight.

An echo (:func:`sim_core.sonar.synthesize`: samples at ``fs`` from the emission, amplitude re
A0, the emitted amplitude at 1 m) is a band-limited signal, so the rule works on its envelope
(the magnitude of the analytic signal, per channel: one per ear). The detection level is the
higher of an absolute threshold (``threshold_db`` re A0, the receiver's sensitivity) and one
``relative_db`` below the echo's strongest return (the band-limited pulse has time sidelobes:
the Hann window of the echo model's band puts its first at -31.5 dB, so a level above it never
fires on the sidelobe before a strong return). The first sample at or above the level, after
the blind zone (``min_range_m``), starts the first return; its range is the time of the
envelope's peak that follows (the envelope's maximum between samples, from the spectrum):
``range = sound_speed · t / 2``. A point scatterer's echo peaks at its delay 2r/v exactly, so
the rule is unbiased for an isolated return; on a flat ground the first return's peak is its
nearest point plus up to a couple of centimetres (``tests/sim_core/sensors/test_echo_range.py``
measures it).

What the rule never looks at: the scene's geometry. A range finder fed from here reports what
the echo says, including nothing (no return: NaN) where the sonar hears nothing.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

__all__ = ["EchoRanges", "RangeRule", "echo_ranges"]

F8 = NDArray[np.float64]
#: the bins kept: above this share of the largest, by precision (double, single)
_KEEP = (1e-7, 2e-6)


@dataclass(frozen=True, slots=True)
class RangeRule:
    """The detection rule (module docstring): ``threshold_db`` dB re A0 on the envelope,
    ``relative_db`` below the strongest return (negative), ``sound_speed`` m/s (the echo
    model's), ``min_range_m`` the blind zone."""

    threshold_db: float = -100.0
    relative_db: float = -25.0
    sound_speed: float = 340.0
    min_range_m: float = 0.1

    def __post_init__(self) -> None:
        if not math.isfinite(self.threshold_db):
            raise ValueError(f"threshold_db: expected a finite level in dB, got "
                             f"{self.threshold_db}")
        if not (math.isfinite(self.relative_db) and -200.0 <= self.relative_db <= 0):
            raise ValueError(f"relative_db: expected -200 <= dB <= 0, got {self.relative_db}")
        if not 100.0 <= self.sound_speed <= 2000.0:
            raise ValueError(f"sound_speed: expected 100..2000 m/s, got {self.sound_speed}")
        if not (math.isfinite(self.min_range_m) and self.min_range_m >= 0):
            raise ValueError(f"min_range_m: expected >= 0, got {self.min_range_m}")


@dataclass(frozen=True, slots=True)
class EchoRanges:
    """Per channel (C,): ``range_m`` of the first return (NaN: none), its envelope peak
    ``level_db`` re A0 and its ``margin_db`` above the detection level (NaN: none);
    ``window_m``: the farthest range the echo's samples reach."""

    range_m: F8
    level_db: F8
    margin_db: F8
    window_m: float


def echo_ranges(samples: ArrayLike, fs: float, rule: RangeRule | None = None) -> EchoRanges:
    """The first return of each channel of ``samples`` ((C, n) or (n,) at ``fs`` Hz, t = 0 at
    emission) by ``rule`` (:class:`RangeRule` defaults when None). Real samples are the echo
    itself; complex ones its baseband (:func:`sim_core.sonar.to_baseband`: x = 2 Re(iq
    e^{j2πf_c t})), whose envelope is 2|iq|.

    How (the same envelope as the analytic signal's at every sample, without its full-length
    transform): the signal's spectrum (one real FFT), the bins that carry it (above 1e-7 of the
    largest; 2e-6 for single-precision samples, whose transform's rounding reaches 1e-7 and
    would keep a bin of noise one time and not the next), shifted to baseband and transformed
    back on as few samples as hold them (every D-th sample of the envelope, exactly); the
    level, the first sample at or above it and the first peak after it on those; then the
    peak's time to a thousandth of a sample by Newton's method on the envelope's square,
    evaluated from the bins themselves (all channels at once)."""
    rule = RangeRule() if rule is None else rule
    if not (math.isfinite(fs) and fs > 0):
        raise ValueError(f"fs: expected a finite rate > 0 Hz, got {fs}")
    x = np.asarray(samples)
    complex_in = np.iscomplexobj(x)
    if x.dtype not in (np.float32, np.complex64):  # single precision is transformed as it is
        x = x.astype(np.complex128 if complex_in else np.float64, copy=False)
    if x.ndim == 1:
        x = x[None]
    if x.ndim != 2:
        raise ValueError(f"samples: expected shape (n,) or (channels, n), got {x.shape}")
    c, n = x.shape
    window = rule.sound_speed * n / fs / 2.0
    rng = np.full(c, np.nan)
    level = np.full(c, np.nan)
    margin = np.full(c, np.nan)
    if n < 3 or not np.all(np.isfinite(x)):
        return EchoRanges(rng, level, margin, window)
    bins, spec = _analytic_bins(x, complex_in)
    if bins.size == 0:
        return EchoRanges(rng, level, margin, window)
    step, env = _coarse_envelope(bins, spec, n)
    start = min(n, math.ceil(2.0 * rule.min_range_m / rule.sound_speed * fs))
    first = -(-start // step)
    floor = 10.0 ** (rule.threshold_db / 20.0)
    found: list[int] = []
    guesses: list[float] = []
    detects: list[float] = []
    for k in range(c):
        e = env[k, first:]
        if e.size < 3:
            continue
        detect = max(floor, float(e.max()) * 10.0 ** (rule.relative_db / 20.0))
        above = np.flatnonzero(e >= detect)
        if above.size == 0:
            continue
        i = int(above[0])
        falls = np.flatnonzero(np.diff(e[i:]) < 0)
        j = first + i + (int(falls[0]) if falls.size else e.size - 1)
        guess = float(j * step)
        if step > 1 and 0 < j < env.shape[1] - 1:  # a coarse peak's parabola: a close start
            y0, y1, y2 = (float(v) for v in env[k, j - 1:j + 2])
            den = y0 - 2.0 * y1 + y2
            if y1 >= max(y0, y2) and den < 0:  # its vertex is within half a step
                guess += step * 0.5 * (y0 - y2) / den
        found.append(k)
        guesses.append(guess)
        detects.append(detect)
    if found:
        t, peak = _peaks(bins, spec[found], n, np.array(guesses), step)
        rng[found] = rule.sound_speed * (t / fs) / 2.0
        level[found] = 20.0 * np.log10(peak)
        margin[found] = level[found] - 20.0 * np.log10(np.array(detects))
    return EchoRanges(rng, level, margin, window)


def _analytic_bins(x: NDArray[Any], complex_in: bool
                   ) -> tuple[NDArray[np.int64], NDArray[np.complex128]]:
    """The signed bins (K,) and values (C, K) of the analytic signal's spectrum that carry it:
    a(n) = (1/N) Σ A_k e^{j2πkn/N} is the analytic signal of real samples (A_k = 2 X_k on the
    positive bins, X_0 and the Nyquist bin once) and twice a complex baseband."""
    import scipy.fft  # its single-precision transform: twice numpy's speed on float32 echoes

    n = x.shape[-1]
    if complex_in:
        spec = 2.0 * scipy.fft.fft(x, axis=-1)
        bins = np.fft.fftfreq(n, 1.0 / n).astype(np.int64)
    else:
        spec = scipy.fft.rfft(x.real, axis=-1)
        spec[:, 1:(n + 1) // 2] *= 2.0
        bins = np.arange(spec.shape[-1], dtype=np.int64)
    mag = np.abs(spec).max(axis=0)
    top = float(mag.max())
    if not top > 0:
        return bins[:0], np.zeros((x.shape[0], 0), dtype=np.complex128)
    keep = np.flatnonzero(mag > _KEEP[spec.dtype == np.complex64] * top)
    return bins[keep], spec[:, keep].astype(np.complex128)


def _coarse_envelope(bins: NDArray[np.int64], spec: NDArray[np.complex128], n: int
                     ) -> tuple[int, F8]:
    """(D, the envelope at every D-th sample (C, n/D)): the bins shifted to baseband on the
    fewest samples, a divisor of n, that hold them with a quarter to spare (exact: no
    aliasing)."""
    lo, hi = int(bins.min()), int(bins.max())
    span = hi - lo + 1
    step = 1
    for d in range(min(64, n // max(1, math.ceil(1.25 * span))), 1, -1):
        if n % d == 0:
            step = d
            break
    m = n // step
    centre = (lo + hi) // 2
    z = np.zeros((spec.shape[0], m), dtype=np.complex128)
    z[:, (bins - centre) % m] = spec
    return step, np.abs(np.fft.ifft(z, axis=-1)) * (m / n)


def _peaks(bins: NDArray[np.int64], a_k: NDArray[np.complex128], n: int, guess: F8,
           step: int) -> tuple[F8, F8]:
    """(time in samples, envelope there) (C,) of each channel's envelope maximum nearest its
    ``guess`` (C,), by Newton's method on |a(t)|² (at most ``step`` samples from the guess),
    the channels side by side (a channel stops where it converged, within 1e-3 of a sample,
    or where its curvature is not a maximum's). a(t) = Σ A_k e^{jω_k t}, so a' = j Σ ω_k A_k
    e^{jω_k t} and a'' = -Σ ω_k² A_k e^{jω_k t}: one cosine and one sine per bin and step, in
    real arithmetic on contiguous arrays (numpy's vector loops)."""
    omega = 2.0 * math.pi * bins / n  # rad a sample
    powers = np.stack([np.ones_like(omega), omega, omega * omega], axis=1)  # (K, 3)
    cycles = bins / n
    ar, ai = np.ascontiguousarray(a_k.real), np.ascontiguousarray(a_k.imag)
    t = guess.astype(np.float64, copy=True)
    on = np.ones(t.size, dtype=bool)
    value = np.zeros(t.size)
    for _ in range(12):
        turn = np.outer(t, cycles)
        turn -= np.floor(turn)  # one turn: the cosine of a small argument is the cheaper
        turn *= 2.0 * math.pi
        c, s = np.cos(turn), np.sin(turn)
        re = ar * c - ai * s  # A_k e^{jω_k t}
        im = ar * s + ai * c
        sr, si = re @ powers, im @ powers  # (C, 3): Σ, Σω, Σω² of each part
        a = sr[:, 0] + 1j * si[:, 0]
        b = sr[:, 1] + 1j * si[:, 1]  # a' = j b
        d = sr[:, 2] + 1j * si[:, 2]  # a'' = -d
        value = np.where(on, np.abs(a) / n, value)
        f1 = -2.0 * (a.conjugate() * b).imag  # d|a|²/dt = 2 Re(conj(a) a')
        f2 = 2.0 * (np.abs(b) ** 2 - (a.conjugate() * d).real)
        on &= f2 < 0
        if not on.any():
            break
        delta = np.where(on, np.clip(-f1 / np.where(on, f2, -1.0), -0.5 * step, 0.5 * step), 0.0)
        t = np.clip(t + delta, guess - step, guess + step)
        on &= np.abs(delta) >= 1e-3
        if not on.any():
            break
    return t, value
