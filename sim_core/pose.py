"""Rotations and frames: unit quaternions, Z-Y-X Euler angles, and the ENU/NED edge.

Conventions (ROS REP 103), used everywhere in echoloop:

- world frame ENU (x east, y north, z up); body frame FLU (x forward, y left, z up);
- a quaternion is ``[w, x, y, z]`` (scalar first) and, for a vehicle, the rotation
  *world-from-body*: ``quat_rotate(q, v_body)`` gives ``v`` in world axes;
- Euler angles are Z-Y-X (yaw about world z, then pitch about the new y, then roll about the
  new x): ``q = q_z(yaw) ⊗ q_y(pitch) ⊗ q_x(roll)``. With FLU bodies a positive roll lowers
  the right wing, a positive pitch lowers the nose, and yaw is measured from +x (east)
  towards +y (north);
- NED/FRD (aviation logs, autopilots) are converted to ENU/FLU only at the edge, by the
  functions at the end of this module.

Every function is vectorised over leading axes: quaternions have shape ``(..., 4)``, vectors
``(..., 3)``, angles ``(...)``; inputs broadcast against each other. Angles in radians.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike, NDArray

__all__ = [
    "ENU_FROM_NED",
    "enu_from_ned",
    "euler_from_quat",
    "flu_from_frd",
    "quat_conjugate",
    "quat_enu_flu_from_ned_frd",
    "quat_from_euler",
    "quat_multiply",
    "quat_normalize",
    "quat_rotate",
    "quat_slerp",
    "quat_to_matrix",
]

FloatArray = NDArray[np.float64]

#: matrix taking NED coordinates to ENU ones (a proper rotation, its own inverse)
ENU_FROM_NED: FloatArray = np.array([[0.0, 1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, -1.0]])
ENU_FROM_NED.setflags(write=False)
#: that rotation as a quaternion: 180° about (x + y)/√2
_Q_ENU_FROM_NED = np.array([0.0, np.sqrt(0.5), np.sqrt(0.5), 0.0])
#: FRD-from-FLU (and FLU-from-FRD): 180° about x
_Q_FLIP_X = np.array([0.0, 1.0, 0.0, 0.0])


def _f(a: ArrayLike) -> FloatArray:
    return np.asarray(a, dtype=np.float64)


def quat_multiply(a: ArrayLike, b: ArrayLike) -> FloatArray:
    """Hamilton product ``a ⊗ b`` (apply ``b`` first, then ``a``), shape ``(..., 4)``."""
    aw, ax, ay, az = np.moveaxis(_f(a), -1, 0)
    bw, bx, by, bz = np.moveaxis(_f(b), -1, 0)
    return np.stack([
        aw * bw - ax * bx - ay * by - az * bz,
        aw * bx + ax * bw + ay * bz - az * by,
        aw * by - ax * bz + ay * bw + az * bx,
        aw * bz + ax * by - ay * bx + az * bw,
    ], axis=-1)


def quat_conjugate(q: ArrayLike) -> FloatArray:
    """Inverse of a unit quaternion, shape ``(..., 4)``."""
    return _f(q) * np.array([1.0, -1.0, -1.0, -1.0])


def quat_normalize(q: ArrayLike) -> FloatArray:
    """Unit quaternion with ``w >= 0`` (the same rotation; one canonical sign).

    A zero quaternion has no rotation to keep and raises ``ValueError``.
    """
    qa = _f(q)
    n = np.linalg.norm(qa, axis=-1, keepdims=True)
    if np.any(n == 0.0) or not np.all(np.isfinite(n)):
        raise ValueError("quaternion with zero or non-finite norm cannot be normalised")
    unit = qa / n
    return np.where(unit[..., :1] < 0.0, -unit, unit)


def quat_from_euler(roll: ArrayLike, pitch: ArrayLike, yaw: ArrayLike) -> FloatArray:
    """``q_z(yaw) ⊗ q_y(pitch) ⊗ q_x(roll)``, shape ``broadcast(roll, pitch, yaw) + (4,)``."""
    hr, hp, hy = 0.5 * _f(roll), 0.5 * _f(pitch), 0.5 * _f(yaw)
    cr, sr = np.cos(hr), np.sin(hr)
    cp, sp = np.cos(hp), np.sin(hp)
    cy, sy = np.cos(hy), np.sin(hy)
    return np.stack([
        cy * cp * cr + sy * sp * sr,
        cy * cp * sr - sy * sp * cr,
        cy * sp * cr + sy * cp * sr,
        sy * cp * cr - cy * sp * sr,
    ], axis=-1)


def euler_from_quat(q: ArrayLike) -> tuple[FloatArray, FloatArray, FloatArray]:
    """``(roll, pitch, yaw)`` of unit quaternions ``(..., 4)``; pitch in [−π/2, π/2].

    At pitch ±π/2 (gimbal lock) roll and yaw are not separable; the sum is put in yaw and
    roll is 0 there up to rounding.
    """
    w, x, y, z = np.moveaxis(_f(q), -1, 0)
    roll = np.arctan2(2.0 * (w * x + y * z), 1.0 - 2.0 * (x * x + y * y))
    pitch = np.arcsin(np.clip(2.0 * (w * y - z * x), -1.0, 1.0))
    yaw = np.arctan2(2.0 * (w * z + x * y), 1.0 - 2.0 * (y * y + z * z))
    return roll, pitch, yaw


def quat_rotate(q: ArrayLike, v: ArrayLike) -> FloatArray:
    """Rotate vectors ``v (..., 3)`` by unit quaternions ``q (..., 4)``: ``q ⊗ v ⊗ q*``."""
    qa, va = _f(q), _f(v)
    w = qa[..., :1]
    u = qa[..., 1:]
    t = 2.0 * np.cross(u, va)
    return va + w * t + np.cross(u, t)


def quat_to_matrix(q: ArrayLike) -> FloatArray:
    """Rotation matrices ``(..., 3, 3)`` of unit quaternions: ``R @ v == quat_rotate(q, v)``."""
    w, x, y, z = np.moveaxis(_f(q), -1, 0)
    return np.stack([
        np.stack([1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)], -1),
        np.stack([2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)], -1),
        np.stack([2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)], -1),
    ], axis=-2)


def quat_slerp(q0: ArrayLike, q1: ArrayLike, t: ArrayLike) -> FloatArray:
    """Spherical interpolation from ``q0`` (t = 0) to ``q1`` (t = 1) along the shorter arc.

    Shapes broadcast: ``q0, q1 (..., 4)``, ``t (...)``. Nearly equal rotations fall back to
    normalised linear interpolation (the arc is then below 1e-6 rad).
    """
    a, b, f = _f(q0), _f(q1), _f(t)[..., None]
    dot = np.sum(a * b, axis=-1, keepdims=True)
    b = np.where(dot < 0.0, -b, b)
    theta = np.arccos(np.clip(np.abs(dot), -1.0, 1.0))
    small = theta < 1e-6
    sin_theta = np.where(small, 1.0, np.sin(theta))
    w0 = np.where(small, 1.0 - f, np.sin((1.0 - f) * theta) / sin_theta)
    w1 = np.where(small, f, np.sin(f * theta) / sin_theta)
    out = w0 * a + w1 * b
    return out / np.linalg.norm(out, axis=-1, keepdims=True)


def enu_from_ned(v: ArrayLike) -> FloatArray:
    """NED vectors ``(..., 3)`` (north, east, down) in ENU axes (east, north, up)."""
    va = _f(v)
    return np.stack([va[..., 1], va[..., 0], -va[..., 2]], axis=-1)


def flu_from_frd(v: ArrayLike) -> FloatArray:
    """FRD body vectors ``(..., 3)`` (forward, right, down) in FLU axes (forward, left, up).

    Also converts body rates: ``(p, q, r)`` about FRD axes give the rates about FLU axes.
    """
    va = _f(v)
    return np.stack([va[..., 0], -va[..., 1], -va[..., 2]], axis=-1)


def quat_enu_flu_from_ned_frd(q_ned_frd: ArrayLike) -> FloatArray:
    """A world-from-body attitude logged as NED-from-FRD, as ENU-from-FLU ``(..., 4)``.

    ``q_enu_flu = q_enu_ned ⊗ q_ned_frd ⊗ q_frd_flu``; the result is normalised with w ≥ 0.
    """
    q = quat_multiply(_Q_ENU_FROM_NED, quat_multiply(q_ned_frd, _Q_FLIP_X))
    return quat_normalize(q)
