"""The pre-cull of the beam selection, compiled: guards, range and cone in one pass.

:func:`precull` is the first step of every echo's selection (:func:`sim_core.sonar.model.
prepare`): it examines every leaf in range of the query, so it is the echo's largest per-leaf
cost. One compiled pass (numba, ``cache=True``: compiled once per installation and CPU, then
loaded from the on-disk cache; :func:`warm_up` does either ahead of a realtime loop) replaces
the numpy passes and the compaction that followed them; it computes the same expressions in
the same order (no fused multiply-add, no reassociation), so it keeps the same leaves with
the same values.

Per leaf, offsets ``d = c - p`` and ``r² = (dx² + dy²) + dz²``, ``|n|² = (nx² + ny²) + nz²``:

- **guards** (counted as *dropped*): a non-finite centre, normal or radius (the sum
  ``dx + dy + dz + (nx + ny + nz) + a`` is not finite), a zero normal, ``r² < r_min²``;
- **range**: ``r² <= reach²`` (``(r0 A0)²``: no leaf farther can pass the waterdrop test);
- **cone** (when the selection has one): ``r·b >= cos_reach · r``, ``b`` the beam axis.

The survivors are written in order to the given output arrays: their row, ``r``, ``r·b``,
the offset ``d`` and ``n̂·d`` (the unit normal dotted with the offset, m).
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit
from numpy.typing import NDArray

from sim_core.frozen import readonly

__all__ = ["precull", "warm_up"]

F64 = NDArray[np.float64]


@njit(cache=True, nogil=True)
def _precull(c: F64, n: F64, a: F64, rows: NDArray[np.intp], use_rows: bool,
             pos: F64, axis: F64, r_min2: float, reach2: float, cone: bool, cos_reach: float,
             out_rows: NDArray[np.intp], out_r: F64, out_proj: F64, out_d: F64,
             out_nd: F64) -> tuple[int, int]:  # pragma: no cover - compiled
    px, py, pz = pos[0], pos[1], pos[2]
    bx, by, bz = axis[0], axis[1], axis[2]
    count = rows.shape[0] if use_rows else c.shape[0]
    found = 0
    dropped = 0
    for k in range(count):
        i = rows[k] if use_rows else k
        dx = c[i, 0] - px
        dy = c[i, 1] - py
        dz = c[i, 2] - pz
        nx, ny, nz = n[i, 0], n[i, 1], n[i, 2]
        r2 = dx * dx
        r2 += dy * dy
        r2 += dz * dz
        nn2 = nx * nx
        nn2 += ny * ny
        nn2 += nz * nz
        if not (nn2 > 0.0 and r2 >= r_min2 and math.isfinite(dx + dy + dz + (nx + ny + nz)
                                                              + a[i])):
            dropped += 1
            continue
        if not r2 <= reach2:
            continue
        r = math.sqrt(r2)
        proj = dx * bx
        proj += dy * by
        proj += dz * bz
        if cone and not proj >= cos_reach * r:
            continue
        nd = nx * dx
        nd += ny * dy
        nd += nz * dz
        out_rows[found] = i
        out_r[found] = r
        out_proj[found] = proj
        out_d[found, 0] = dx
        out_d[found, 1] = dy
        out_d[found, 2] = dz
        out_nd[found] = nd / math.sqrt(nn2)
        found += 1
    return found, dropped


def precull(c: F64, n: F64, a: F64, rows: NDArray[np.intp] | None, pos: F64, axis: F64, *,
            r_min2: float, reach2: float, cone: bool, cos_reach: float,
            out: tuple[NDArray[np.intp], F64, F64, F64, F64]) -> tuple[int, int]:
    """Pre-cull the leaves ``c``, ``n`` (M, 3) and ``a`` (M,) (C-contiguous float64; only the
    rows ``rows`` when given) for a beam from ``pos`` (3,) along unit ``axis`` (3,) (module
    docstring). The survivors' rows, ``r`` (m), ``r·b`` (m), offsets (·, 3) (m) and ``n̂·d``
    (m) go to the five arrays of ``out``, each with room for every leaf examined. Returns
    (survivors, dropped by the guards)."""
    use_rows = rows is not None
    found, dropped = _precull(
        readonly(c), readonly(n), readonly(a),
        readonly(rows if rows is not None else np.empty(0, np.intp)), use_rows, readonly(pos),
        readonly(axis), float(r_min2), float(reach2), bool(cone), float(cos_reach), *out)
    return int(found), int(dropped)


def warm_up() -> None:
    """Compile :func:`precull` or load it from the cache, so no echo pays it."""
    z = np.zeros((1, 3))
    out = (np.empty(1, np.intp), np.empty(1), np.empty(1), np.empty((1, 3)), np.empty(1))
    for rows in (None, np.zeros(1, np.intp)):
        precull(z, z, np.zeros(1), rows, np.zeros(3), np.array([1.0, 0.0, 0.0]), r_min2=0.0,
                reach2=1.0, cone=True, cos_reach=0.5, out=out)
