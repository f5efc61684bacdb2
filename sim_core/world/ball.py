"""Which leaves lie in a ball: the gather of every echo from a tiled forest, compiled.

:func:`ball_rows` returns the rows of a tile's leaf centres that lie in a ball, in the leaves'
order (numba, ``cache=True``: compiled once per installation and CPU, then loaded from the
on-disk cache; :func:`warm_up` does either ahead of a realtime loop). A leaf is in the ball
when ``(x - px)² + (y - py)² + (z - pz)²``, summed in that order, is at most ``r²``: the test
of ``scipy.spatial.cKDTree.query_ball_point`` it replaced for tiles, which had to build a k-d
tree per tile and turn every hit into a Python int (``python -m bench multisonar`` measures
both). The rows are ascending, so the gathered set is that of the k-d tree, in the same order.

**Blocks.** A ball of an echo's query radius holds a few per cent of the leaves of the tiles it
touches, so the leaves are not all tested: :func:`block_bounds` boxes every run of
:data:`BLOCK` consecutive leaves (a tile stores its trees' leaves branch after branch, so a run
is a compact piece of crown), and a block whose box lies beyond the ball is skipped whole. The
test of a box is the leaves' own test applied to the box's nearest point, so it never skips a
block holding a leaf that passes: per axis, the nearest point's offset is no larger than any of
the block's leaves' (the same subtraction from the same bound, and rounding is monotonic), and
so is the rounded sum of squares. A non-finite centre makes its block's box non-finite, and
such a block is always tested leaf by leaf.
"""

from __future__ import annotations

import numpy as np
from numba import njit
from numpy.typing import NDArray

from sim_core.frozen import readonly

__all__ = ["BLOCK", "ball_rows", "block_bounds", "warm_up"]

#: consecutive leaves boxed together by :func:`block_bounds`
BLOCK = 128


def block_bounds(centers: NDArray[np.float64]) -> NDArray[np.float64]:
    """``(ceil(M / BLOCK), 2, 3)``: the lowest and highest coordinates (m) of each run of
    :data:`BLOCK` consecutive leaves of ``centers (M, 3)`` (NaN where a run holds one)."""
    starts = np.arange(0, centers.shape[0], BLOCK)
    if starts.shape[0] == 0:
        return np.zeros((0, 2, 3))
    return np.stack([np.minimum.reduceat(centers, starts, axis=0),
                     np.maximum.reduceat(centers, starts, axis=0)], axis=1)


@njit(cache=True, nogil=True)
def _gap(p: float, lo: float, hi: float) -> float:  # pragma: no cover - compiled
    """Offset from ``p`` to the nearest point of ``[lo, hi]`` (0 inside, and for NaN bounds,
    which compare false)."""
    if p < lo:
        return lo - p
    if p > hi:
        return hi - p
    return 0.0


@njit(cache=True, nogil=True)
def _rows(c: NDArray[np.float64], bounds: NDArray[np.float64], px: float, py: float,
          pz: float, r2: float) -> NDArray[np.intp]:  # pragma: no cover - compiled
    out = np.empty(c.shape[0], np.intp)
    found = 0
    for b in range(bounds.shape[0]):
        bx = _gap(px, bounds[b, 0, 0], bounds[b, 1, 0])
        by = _gap(py, bounds[b, 0, 1], bounds[b, 1, 1])
        bz = _gap(pz, bounds[b, 0, 2], bounds[b, 1, 2])
        if not bx * bx + by * by + bz * bz <= r2:
            continue
        for i in range(b * BLOCK, min((b + 1) * BLOCK, c.shape[0])):
            dx = c[i, 0] - px
            dy = c[i, 1] - py
            dz = c[i, 2] - pz
            if dx * dx + dy * dy + dz * dz <= r2:
                out[found] = i
                found += 1
    return out[:found]


def ball_rows(centers: NDArray[np.float64], bounds: NDArray[np.float64],
              point: NDArray[np.float64], radius_m: float) -> NDArray[np.intp]:
    """Ascending rows of ``centers (M, 3)`` (m, C-contiguous float64) within ``radius_m`` of
    ``point (3,)`` (m), with ``bounds`` their :func:`block_bounds` (the module docstring says
    how it is decided)."""
    return _rows(readonly(centers), readonly(bounds), float(point[0]), float(point[1]),
                 float(point[2]), float(radius_m) * float(radius_m))


def warm_up() -> None:
    """Compile :func:`ball_rows` or load it from the cache, so no echo pays it."""
    c = np.zeros((1, 3))
    ball_rows(c, block_bounds(c), np.zeros(3), 1.0)
