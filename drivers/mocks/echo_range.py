"""What the mock sonar head measures of an echo: the range of its first return."""

from __future__ import annotations

import numpy as np

__all__ = ["first_return_range"]


def first_return_range(
    samples: np.ndarray, fs_hz: float, *, sound_speed: float = 340.0,
    threshold: float | None = None, threshold_rel: float = 0.1,
) -> float | None:
    """Range (m) of the first sample whose magnitude reaches the threshold, or None.

    ``samples``: (C, N) or (N,), real or complex, at ``fs_hz`` with t = 0 at emission; the
    magnitude is the maximum over channels. Range = sound_speed * t / 2.
    """
    mag = np.abs(np.asarray(samples))
    if mag.ndim == 2:
        mag = mag.max(axis=0)
    if mag.size == 0:
        return None
    peak = float(mag.max())
    level = threshold if threshold is not None else threshold_rel * peak
    if peak <= 0.0 or level <= 0.0:
        return None
    hits = np.flatnonzero(mag >= level)
    if hits.size == 0:
        return None
    return float(sound_speed * (hits[0] / fs_hz) / 2.0)
