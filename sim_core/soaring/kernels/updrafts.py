"""The seed's thermals in the kernels (spec §3.2): the updraft at a point and one step of the
fade cycle of the fading thermals."""

from __future__ import annotations

import math

import numpy as np

from sim_core.soaring.kernels.arith import jit, norm2, round_half_away, spow
from sim_core.soaring.kernels.layout import (
    ON_FADE,
    ON_VALID,
    P_FADE_BOTTOM,
    P_FADE_INCR,
    P_FADE_RATE,
    P_FADE_TOP,
    TH_DIR,
    TH_R,
    TH_TIMER,
    TH_W,
    TH_WMAX,
    TH_X,
    TH_Y,
)


@jit
def updraft(x: float, y: float, th: np.ndarray, on: np.ndarray, b: int) -> float:
    """w m/s at (x, y) of run b: the first thermal in slot order whose disc holds the point."""
    for t in range(th.shape[2]):
        if not on[ON_VALID, b, t]:
            continue
        d = norm2(th[TH_X, b, t] - x, th[TH_Y, b, t] - y)
        r = th[TH_R, b, t]
        if d < r:
            u = spow(3.0 * d / r, 2.0)
            return th[TH_W, b, t] * math.exp(-u) * (1.0 - u)
    return 0.0


@jit
def fade(th: np.ndarray, on: np.ndarray, b: int, p: np.ndarray) -> None:
    """One step of the fade cycle of run b's fading thermals, in place (``fadeThermals``)."""
    rate, incr = p[P_FADE_RATE], p[P_FADE_INCR]
    for t in range(th.shape[2]):
        if not (on[ON_VALID, b, t] and on[ON_FADE, b, t]):
            continue
        w = th[TH_W, b, t]
        at_top = w >= th[TH_WMAX, b, t] - 1e-5
        if at_top or round_half_away(10.0 * w) / 10.0 <= 1e-5:  # round(w, 1), as the Octave run did
            if th[TH_TIMER, b, t] >= (p[P_FADE_TOP] if at_top else p[P_FADE_BOTTOM]):
                th[TH_DIR, b, t] = -1.0 if at_top else 1.0
                th[TH_W, b, t] = w + th[TH_DIR, b, t] * rate
                th[TH_TIMER, b, t] = 0.0
            else:
                th[TH_TIMER, b, t] = th[TH_TIMER, b, t] + incr
        else:
            th[TH_W, b, t] = w + th[TH_DIR, b, t] * rate

