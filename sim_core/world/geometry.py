"""Small vectorised 3-D helpers shared by the tree generators (all angles in radians)."""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray
from scipy.special import ndtr, ndtri

from sim_core.pose import cross

__all__ = [
    "axis_rotation",
    "clipped_normal",
    "perpendicular",
    "rotate",
    "rotz",
    "truncated_normal",
    "unit",
]

F64 = NDArray[np.float64]


def unit(v: F64) -> F64:
    """Rows of ``v (..., 3)`` scaled to unit length (zero rows stay zero)."""
    n = np.linalg.norm(v, axis=-1, keepdims=True)
    return np.divide(v, n, out=np.zeros_like(v), where=n > 0)


def rotz(angle: F64 | float) -> F64:
    """Rotation matrices about +z, shape ``(..., 3, 3)`` for ``angle (...)``."""
    a = np.asarray(angle, dtype=np.float64)
    c, s = np.cos(a), np.sin(a)
    z, o = np.zeros_like(a), np.ones_like(a)
    return np.stack(
        [np.stack([c, -s, z], -1), np.stack([s, c, z], -1), np.stack([z, z, o], -1)], -2
    )


def axis_rotation(axis: F64, angle: F64) -> F64:
    """Rodrigues rotation matrices ``(N, 3, 3)`` about unit ``axis (N, 3)`` by ``angle (N,)``."""
    k = np.asarray(axis, dtype=np.float64)
    a = np.asarray(angle, dtype=np.float64)
    c, s = np.cos(a)[:, None, None], np.sin(a)[:, None, None]
    kx, ky, kz = k[:, 0], k[:, 1], k[:, 2]
    zero = np.zeros_like(kx)
    rows = [[zero, -kz, ky], [kz, zero, -kx], [-ky, kx, zero]]
    K = np.stack([np.stack(r, -1) for r in rows], -2)
    eye = np.eye(3)[None]
    return eye + s * K + (1.0 - c) * (K @ K)


def rotate(v: F64, axis: F64, angle: F64) -> F64:
    """Rotate rows ``v (N, 3)`` about unit ``axis (N, 3)`` by ``angle (N,)`` (right-hand rule)."""
    c = np.cos(angle)[:, None]
    s = np.sin(angle)[:, None]
    kxv = cross(axis, v)
    kdv = np.sum(axis * v, axis=1, keepdims=True)
    return v * c + kxv * s + axis * kdv * (1.0 - c)


def perpendicular(v: F64) -> F64:
    """A unit vector perpendicular to each row of ``v (N, 3)``."""
    a = np.abs(v)
    pick = np.argmin(a, axis=1)
    e = np.zeros_like(v)
    e[np.arange(v.shape[0]), pick] = 1.0
    return unit(cross(v, e))


def clipped_normal(
    rng: np.random.Generator, mean: F64 | float, sd: F64 | float, size: int | None = None
) -> F64:
    """``mean + sd * clip(z, -2, 2)`` with ``z ~ N(0, 1)``: the seed's clipped (not truncated)
    normal deviate (FG ``normalRandom``)."""
    shape = size if size is not None else np.broadcast(np.asarray(mean), np.asarray(sd)).shape
    z = np.clip(rng.standard_normal(shape), -2.0, 2.0)
    return np.asarray(mean + sd * z, dtype=np.float64)


def truncated_normal(
    rng: np.random.Generator, mean: float, sd: float, low: float, high: float, size: int
) -> F64:
    """``size`` draws of N(mean, sd²) truncated to ``[low, high]`` by inverse-CDF sampling."""
    if sd <= 0:
        return np.full(size, float(np.clip(mean, low, high)))
    a = float(ndtr((low - mean) / sd))
    b = float(ndtr((high - mean) / sd))
    u = a + (b - a) * rng.random(size)
    x = mean + sd * ndtri(u)
    return np.clip(x, low, high)
