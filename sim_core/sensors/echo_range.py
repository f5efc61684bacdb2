"""The echo → range rule of every range finder in echoloop: the first return above a threshold,
by its time of flight.

An echo (:func:`sim_core.sonar.synthesize`: samples at ``fs`` from the emission, amplitude re
A0, the emitted amplitude at 1 m) is a band-limited signal, so the rule works on its envelope
(the magnitude of the analytic signal, per channel: one per ear). The detection level is the
higher of an absolute threshold (``threshold_db`` re A0, the receiver's sensitivity) and one
``relative_db`` below the echo's strongest return (the band-limited pulse has time sidelobes:
the Hann window of the echo model's band puts its first at -31.5 dB, so a level above it never
fires on the sidelobe before a strong return). The first sample at or above the level, after
the blind zone (``min_range_m``), starts the first return; its range is the envelope's peak
that follows (refined between samples by a parabola through the peak and its neighbours):
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

import numpy as np
from numpy.typing import ArrayLike, NDArray

__all__ = ["EchoRanges", "RangeRule", "echo_ranges"]

F8 = NDArray[np.float64]


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
    e^{j2πf_c t})), whose envelope is 2|iq|."""
    from scipy.signal import hilbert

    rule = RangeRule() if rule is None else rule
    if not (math.isfinite(fs) and fs > 0):
        raise ValueError(f"fs: expected a finite rate > 0 Hz, got {fs}")
    x = np.asarray(samples)
    x = x.astype(np.complex128 if np.iscomplexobj(x) else np.float64, copy=False)
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
    env = 2.0 * np.abs(x) if np.iscomplexobj(x) else np.abs(hilbert(x, axis=-1))
    start = min(n, math.ceil(2.0 * rule.min_range_m / rule.sound_speed * fs))
    floor = 10.0 ** (rule.threshold_db / 20.0)
    for k in range(c):
        e = env[k, start:]
        if e.size < 3:
            continue
        detect = max(floor, float(e.max()) * 10.0 ** (rule.relative_db / 20.0))
        above = np.flatnonzero(e >= detect)
        if above.size == 0:
            continue
        i = int(above[0])
        falls = np.flatnonzero(np.diff(e[i:]) < 0)
        j = i + int(falls[0]) if falls.size else e.size - 1
        shift = 0.0
        if 0 < j < e.size - 1:
            y0, y1, y2 = float(e[j - 1]), float(e[j]), float(e[j + 1])
            den = y0 - 2.0 * y1 + y2
            shift = 0.5 * (y0 - y2) / den if den < 0 else 0.0
        t = (start + j + shift) / fs
        rng[k] = rule.sound_speed * t / 2.0
        level[k] = 20.0 * math.log10(float(e[j]))
        margin[k] = level[k] - 20.0 * math.log10(detect)
    return EchoRanges(rng, level, margin, window)
