"""Which leaves lie in a ball: the gather of every echo from a tiled forest, compiled.

:func:`ball_mask` is one pass over a tile's leaf centres with no temporaries (numba,
``cache=True``: compiled once per installation and CPU, then loaded from the on-disk cache;
:func:`warm_up` does either ahead of a realtime loop). A leaf is in the ball when
``(x - px)² + (y - py)² + (z - pz)²``, summed in that order, is at most ``r²``: the test of
``scipy.spatial.cKDTree.query_ball_point`` it replaces for tiles, which had to build a k-d tree
per tile and turn every hit into a Python int (``python -m bench multisonar`` measures both).
The mask keeps the leaves' order, so the gathered set is that of the k-d tree, in the same
order.
"""

from __future__ import annotations

import numpy as np
from numba import njit
from numpy.typing import NDArray

__all__ = ["ball_mask", "warm_up"]


@njit(cache=True, nogil=True)
def _mask(c: NDArray[np.float64], px: float, py: float, pz: float,
          r2: float) -> NDArray[np.bool_]:  # pragma: no cover - compiled
    out = np.empty(c.shape[0], np.bool_)
    for i in range(c.shape[0]):
        dx = c[i, 0] - px
        dy = c[i, 1] - py
        dz = c[i, 2] - pz
        out[i] = dx * dx + dy * dy + dz * dz <= r2
    return out


def ball_mask(centers: NDArray[np.float64], point: NDArray[np.float64],
              radius_m: float) -> NDArray[np.bool_]:
    """``(M,) bool``: which of ``centers (M, 3)`` (m, C-contiguous float64) lie within
    ``radius_m`` of ``point (3,)`` (m; the module docstring says how it is decided)."""
    return _mask(centers, float(point[0]), float(point[1]), float(point[2]),
                 float(radius_m) * float(radius_m))


def warm_up() -> None:
    """Compile :func:`ball_mask` or load it from the cache, so no echo pays it."""
    ball_mask(np.zeros((1, 3)), np.zeros(3), 1.0)
