"""Leaves as a struct of arrays with a lazily built k-d tree for range and cone queries.

Every leaf is an acoustic disc: a centre (metres, world ENU), a unit normal and a radius (metres),
plus the index of the tree it belongs to. Storage is exactly those four arrays
(float64 centres 24 B + normals 24 B + radii 8 B + int32 tree id 4 B = 60 B per leaf); the
:class:`scipy.spatial.cKDTree` used by the queries is built on first use and not saved (the
``.npz`` file of those arrays is ``hil_bridge.files.world``).
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy.spatial import cKDTree

__all__ = ["BYTES_PER_LEAF", "Leaves"]

#: bytes of array storage per leaf (centres, normals, radii, tree id)
BYTES_PER_LEAF = 3 * 8 + 3 * 8 + 8 + 4

# Approximate size of a cKDTree per point (data copy 24 B + index 8 B + nodes), used only for the
# memory accounting of caches.
_KDTREE_BYTES_PER_POINT = 48


class Leaves:
    """Struct of arrays: ``centers (M,3) f8`` m, ``normals (M,3) f8`` unit, ``radii (M,) f8`` m,
    ``tree_id (M,) int32``.

    The arrays are validated for shape and dtype (converted if needed) but not copied when they
    already have the right dtype and are C-contiguous. Treat them as read-only: the k-d tree is
    cached and would go stale if ``centers`` changed in place.
    """

    __slots__ = ("_kdtree", "centers", "normals", "radii", "tree_id")

    def __init__(
        self, centers: ArrayLike, normals: ArrayLike, radii: ArrayLike, tree_id: ArrayLike
    ) -> None:
        c = np.ascontiguousarray(centers, dtype=np.float64)
        n = np.ascontiguousarray(normals, dtype=np.float64)
        r = np.ascontiguousarray(radii, dtype=np.float64)
        t = np.ascontiguousarray(tree_id, dtype=np.int32)
        if c.ndim != 2 or c.shape[1] != 3:
            raise ValueError(f"centers must have shape (M, 3), got {c.shape}")
        m = c.shape[0]
        if n.shape != (m, 3):
            raise ValueError(f"normals must have shape ({m}, 3), got {n.shape}")
        if r.shape != (m,):
            raise ValueError(f"radii must have shape ({m},), got {r.shape}")
        if t.shape != (m,):
            raise ValueError(f"tree_id must have shape ({m},), got {t.shape}")
        self.centers: NDArray[np.float64] = c
        self.normals: NDArray[np.float64] = n
        self.radii: NDArray[np.float64] = r
        self.tree_id: NDArray[np.int32] = t
        self._kdtree: cKDTree | None = None

    # --- construction -------------------------------------------------------------------------
    @classmethod
    def empty(cls) -> Leaves:
        """No leaves."""
        return cls(np.zeros((0, 3)), np.zeros((0, 3)), np.zeros(0), np.zeros(0, dtype=np.int32))

    @classmethod
    def concat(cls, parts: Sequence[Leaves]) -> Leaves:
        """Concatenate leaf sets in order (tree ids are kept as they are)."""
        parts = list(parts)
        if not parts:
            return cls.empty()
        return cls(
            np.concatenate([p.centers for p in parts]),
            np.concatenate([p.normals for p in parts]),
            np.concatenate([p.radii for p in parts]),
            np.concatenate([p.tree_id for p in parts]),
        )

    def select(self, index: ArrayLike) -> Leaves:
        """The subset given by a boolean mask of length M or an integer index array."""
        idx = np.asarray(index)
        if idx.size == 0 and idx.dtype != bool:
            idx = idx.astype(np.intp)
        if idx.dtype == bool and idx.shape != (len(self),):
            raise ValueError(f"boolean mask must have shape ({len(self)},), got {idx.shape}")
        return Leaves(self.centers[idx], self.normals[idx], self.radii[idx], self.tree_id[idx])

    # --- basic protocol -----------------------------------------------------------------------
    def __len__(self) -> int:
        return int(self.centers.shape[0])

    def __repr__(self) -> str:
        return f"Leaves(M={len(self)}, trees={np.unique(self.tree_id).size})"

    def __eq__(self, other: object) -> bool:
        if not isinstance(other, Leaves):
            return NotImplemented
        return (
            np.array_equal(self.centers, other.centers)
            and np.array_equal(self.normals, other.normals)
            and np.array_equal(self.radii, other.radii)
            and np.array_equal(self.tree_id, other.tree_id)
        )

    __hash__ = None  # type: ignore[assignment]

    @property
    def nbytes(self) -> int:
        """Bytes held: the four arrays, plus an estimate for the k-d tree once it is built."""
        arrays = self.centers.nbytes + self.normals.nbytes + self.radii.nbytes + self.tree_id.nbytes
        tree = _KDTREE_BYTES_PER_POINT * len(self) if self._kdtree is not None else 0
        return int(arrays + tree)

    # --- spatial queries ----------------------------------------------------------------------
    @property
    def kdtree(self) -> cKDTree:
        """k-d tree over ``centers``, built on first use."""
        if self._kdtree is None:
            self._kdtree = cKDTree(self.centers)
        return self._kdtree

    def query_ball(self, point: ArrayLike, r: float) -> NDArray[np.intp]:
        """Sorted indices of leaves whose centre lies within ``r`` metres of ``point (3,)``."""
        p = _point(point, "point")
        if not (np.isfinite(r) and r >= 0):
            raise ValueError(f"r must be a finite distance >= 0, got {r!r}")
        if len(self) == 0:
            return np.zeros(0, dtype=np.intp)
        idx = self.kdtree.query_ball_point(p, r)
        return np.sort(np.asarray(idx, dtype=np.intp))

    def query_cone(
        self, apex: ArrayLike, axis: ArrayLike, half_angle_rad: float, r_max: float
    ) -> NDArray[np.intp]:
        """Sorted indices of leaves inside the cone at ``apex (3,)`` around ``axis (3,)``.

        A leaf is inside when its centre is within ``r_max`` metres of the apex and the angle
        between ``centre - apex`` and ``axis`` is at most ``half_angle_rad`` (0..pi). A centre
        exactly at the apex counts as inside.
        """
        a = _point(apex, "apex")
        ax = _point(axis, "axis")
        norm = float(np.linalg.norm(ax))
        if norm == 0.0:
            raise ValueError("axis must be a non-zero vector")
        if not (np.isfinite(half_angle_rad) and 0.0 <= half_angle_rad <= np.pi):
            raise ValueError(f"half_angle_rad must be in [0, pi], got {half_angle_rad!r}")
        idx = self.query_ball(a, r_max)
        if idx.size == 0:
            return idx
        d = self.centers[idx] - a
        dist = np.linalg.norm(d, axis=1)
        cos_angle = (d @ (ax / norm)) / np.where(dist > 0, dist, 1.0)
        inside = (dist == 0) | (cos_angle >= np.cos(half_angle_rad))
        return idx[inside]


def _point(value: ArrayLike, name: str) -> NDArray[np.float64]:
    p = np.asarray(value, dtype=np.float64)
    if p.shape != (3,):
        raise ValueError(f"{name} must have shape (3,), got {p.shape}")
    if not np.all(np.isfinite(p)):
        raise ValueError(f"{name} must be finite, got {p.tolist()}")
    return p
