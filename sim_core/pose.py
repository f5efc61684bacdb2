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
  functions at the end of this module;
- a *pose* is a position ``(..., 3)`` m and a world-from-frame quaternion ``(..., 4)``; a
  sensor mounted on a vehicle has a mount pose in body axes (offset m, body-from-sensor
  rotation), composed with the vehicle's pose by :func:`pose_compose`;
- body rates ``(p, q, r)`` are the angular velocity in body axes (rad/s), right-handed about
  x, y, z: in FLU a positive ``p`` lowers the right wing, ``q`` lowers the nose, ``r`` turns
  left (heading grows).

Every function is vectorised over leading axes: quaternions have shape ``(..., 4)``, vectors
``(..., 3)``, angles ``(...)``; inputs broadcast against each other. Angles in radians.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike, NDArray

__all__ = [
    "ENU_FROM_NED",
    "body_rates_from_euler_rates",
    "body_rates_from_quats",
    "cross",
    "direction_from_az_el",
    "enu_from_ned",
    "euler_from_quat",
    "flu_from_frd",
    "frd_from_flu",
    "ned_from_enu",
    "pose_compose",
    "pose_extrapolate",
    "pose_interpolate",
    "quat_between",
    "quat_conjugate",
    "quat_enu_flu_from_ned_frd",
    "quat_from_euler",
    "quat_from_rotation_vector",
    "quat_multiply",
    "quat_ned_frd_from_enu_flu",
    "quat_normalize",
    "quat_rotate",
    "quat_slerp",
    "quat_to_matrix",
    "velocity_interpolate",
]

FloatArray = NDArray[np.float64]

#: matrix taking NED coordinates to ENU ones (a proper rotation, its own inverse)
ENU_FROM_NED: FloatArray = np.array([[0.0, 1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, -1.0]])
ENU_FROM_NED.setflags(write=False)
#: that rotation as a quaternion: 180° about (x + y)/√2
_Q_ENU_FROM_NED = np.array([0.0, np.sqrt(0.5), np.sqrt(0.5), 0.0])
#: FRD-from-FLU (and FLU-from-FRD): 180° about x
_Q_FLIP_X = np.array([0.0, 1.0, 0.0, 0.0])
#: ``q ↦ q_enu_ned ⊗ q ⊗ q_frd_flu`` as a matrix on ``[w, x, y, z]`` (its own inverse up to
#: sign: both frame changes are 180° rotations)
_M_ENU_FLU_FROM_NED_FRD = np.sqrt(0.5) * np.array([
    [-1.0, 0.0, 0.0, -1.0], [0.0, -1.0, -1.0, 0.0], [0.0, -1.0, 1.0, 0.0], [-1.0, 0.0, 0.0, 1.0],
])


def _f(a: ArrayLike) -> FloatArray:
    return np.asarray(a, dtype=np.float64)


def cross(a: ArrayLike, b: ArrayLike) -> FloatArray:
    """``a × b`` over the last axis (``(..., 3)``, broadcast), float64: the products and
    differences of ``np.cross`` (the same bits) without its axis bookkeeping, which made it 3
    times slower on the few vectors of a tick or a bridge batch (16 µs against 6 µs a call)."""
    fa, fb = _f(a), _f(b)
    a0, a1, a2 = fa[..., 0], fa[..., 1], fa[..., 2]
    b0, b1, b2 = fb[..., 0], fb[..., 1], fb[..., 2]
    out = np.empty(fa.shape if fa.shape == fb.shape else np.broadcast_shapes(fa.shape, fb.shape))
    out[..., 0] = a1 * b2 - a2 * b1
    out[..., 1] = a2 * b0 - a0 * b2
    out[..., 2] = a0 * b1 - a1 * b0
    return out


def _columns(*cols: FloatArray) -> FloatArray:
    """``np.stack(cols, axis=-1)`` of same-shape arrays, the same values at a third of its cost
    on the few quaternions of a tick (its axis bookkeeping cost more than the arithmetic)."""
    out = np.empty((*np.shape(cols[0]), len(cols)))
    for i, col in enumerate(cols):
        out[..., i] = col
    return out


def _wxyz(q: ArrayLike) -> tuple[FloatArray, FloatArray, FloatArray, FloatArray]:
    """The components of quaternions ``(..., 4)`` as views (cheaper than ``np.moveaxis``, whose
    axis bookkeeping cost more than the arithmetic on a tick's few quaternions)."""
    fq = _f(q)
    return fq[..., 0], fq[..., 1], fq[..., 2], fq[..., 3]


def quat_multiply(a: ArrayLike, b: ArrayLike) -> FloatArray:
    """Hamilton product ``a ⊗ b`` (apply ``b`` first, then ``a``), shape ``(..., 4)``."""
    aw, ax, ay, az = _wxyz(a)
    bw, bx, by, bz = _wxyz(b)
    return np.stack([  # a and b may broadcast: not _columns
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
    if not ((n > 0.0) & (n < np.inf)).all():  # zero, NaN or infinite: no rotation to keep
        raise ValueError("quaternion with zero or non-finite norm cannot be normalised")
    unit = qa / n
    return np.where(unit[..., :1] < 0.0, -unit, unit)


def quat_from_euler(roll: ArrayLike, pitch: ArrayLike, yaw: ArrayLike) -> FloatArray:
    """``q_z(yaw) ⊗ q_y(pitch) ⊗ q_x(roll)``, shape ``broadcast(roll, pitch, yaw) + (4,)``."""
    hr, hp, hy = 0.5 * _f(roll), 0.5 * _f(pitch), 0.5 * _f(yaw)
    cr, sr = np.cos(hr), np.sin(hr)
    cp, sp = np.cos(hp), np.sin(hp)
    cy, sy = np.cos(hy), np.sin(hy)
    return _columns(  # every column is a product of all three: one shape
        cy * cp * cr + sy * sp * sr,
        cy * cp * sr - sy * sp * cr,
        cy * sp * cr + sy * cp * sr,
        sy * cp * cr - cy * sp * sr,
    )


def euler_from_quat(q: ArrayLike) -> tuple[FloatArray, FloatArray, FloatArray]:
    """``(roll, pitch, yaw)`` of unit quaternions ``(..., 4)``; pitch in [−π/2, π/2].

    At pitch ±π/2 (gimbal lock) roll and yaw are not separable; the sum is put in yaw and
    roll is 0 there up to rounding.
    """
    w, x, y, z = _wxyz(q)
    roll = np.arctan2(2.0 * (w * x + y * z), 1.0 - 2.0 * (x * x + y * y))
    pitch = np.arcsin(np.minimum(np.maximum(2.0 * (w * y - z * x), -1.0), 1.0))
    yaw = np.arctan2(2.0 * (w * z + x * y), 1.0 - 2.0 * (y * y + z * z))
    return roll, pitch, yaw


def quat_rotate(q: ArrayLike, v: ArrayLike) -> FloatArray:
    """Rotate vectors ``v (..., 3)`` by unit quaternions ``q (..., 4)``: ``q ⊗ v ⊗ q*``."""
    qa, va = _f(q), _f(v)
    w = qa[..., :1]
    u = qa[..., 1:]
    t = 2.0 * cross(u, va)
    return va + w * t + cross(u, t)


def quat_to_matrix(q: ArrayLike) -> FloatArray:
    """Rotation matrices ``(..., 3, 3)`` of unit quaternions: ``R @ v == quat_rotate(q, v)``."""
    w, x, y, z = _wxyz(q)
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


def quat_between(a: ArrayLike, b: ArrayLike) -> FloatArray:
    """The shortest-arc rotation taking direction ``a`` to direction ``b`` (``(..., 3)``, any
    non-zero length), as unit quaternions ``(..., 4)``: ``[1 + a·b, a × b]`` normalised, with
    ``1 + a·b`` taken as ``|a + b|²/2`` so that it stays accurate near opposite directions
    (within ~1e-16 / |a × b| there). Exactly opposite directions turn by π about an axis
    perpendicular to ``a``."""
    ua = _f(a) / np.linalg.norm(_f(a), axis=-1, keepdims=True)
    ub = _f(b) / np.linalg.norm(_f(b), axis=-1, keepdims=True)
    ua, ub = np.broadcast_arrays(ua, ub)
    half = 0.5 * np.sum((ua + ub) ** 2, axis=-1, keepdims=True)
    q = np.concatenate([half, cross(ua, ub)], axis=-1)
    n = np.linalg.norm(q, axis=-1, keepdims=True)
    # opposite: any axis perpendicular to a (x unless a is close to x)
    alt = cross(ua, np.where(np.abs(ua[..., :1]) < 0.9, [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]))
    alt = np.concatenate([np.zeros_like(half), alt], axis=-1)
    q = np.where(n > 1e-12, q, alt)
    return q / np.linalg.norm(q, axis=-1, keepdims=True)


def direction_from_az_el(az: ArrayLike, el: ArrayLike) -> FloatArray:
    """Unit vectors ``(..., 3)`` at azimuth ``az`` (from +x towards +y) and elevation ``el``
    (towards +z) in whatever frame the angles are measured in."""
    a, e = np.broadcast_arrays(_f(az), _f(el))
    ce = np.cos(e)
    return np.stack([ce * np.cos(a), ce * np.sin(a), np.sin(e)], axis=-1)


def pose_compose(
    position: ArrayLike, orientation: ArrayLike, offset: ArrayLike, rotation: ArrayLike
) -> tuple[FloatArray, FloatArray]:
    """World pose of a frame mounted on a body: ``offset (..., 3)`` m and ``rotation (..., 4)``
    (body-from-frame) composed with the body's ``position (..., 3)`` and world-from-body
    ``orientation (..., 4)``. Returns ``(position (..., 3), world-from-frame (..., 4))``."""
    p = _f(position) + quat_rotate(orientation, offset)
    return p, quat_multiply(orientation, rotation)


def body_rates_from_euler_rates(
    roll: ArrayLike, pitch: ArrayLike, roll_rate: ArrayLike, pitch_rate: ArrayLike,
    yaw_rate: ArrayLike,
) -> FloatArray:
    """Body rates ``(p, q, r)`` ``(..., 3)`` rad/s from Z-Y-X Euler angles and their time
    derivatives (rad, rad/s): ``p = φ̇ − ψ̇ sin θ``, ``q = θ̇ cos φ + ψ̇ sin φ cos θ``,
    ``r = −θ̇ sin φ + ψ̇ cos φ cos θ`` (φ roll, θ pitch, ψ yaw)."""
    r, p = _f(roll), _f(pitch)
    dr, dp, dy = _f(roll_rate), _f(pitch_rate), _f(yaw_rate)
    cr, sr, cp, sp = np.cos(r), np.sin(r), np.cos(p), np.sin(p)
    return np.stack(np.broadcast_arrays(
        dr - dy * sp, dp * cr + dy * sr * cp, -dp * sr + dy * cr * cp
    ), axis=-1)


def body_rates_from_quats(q0: ArrayLike, q1: ArrayLike, dt: ArrayLike) -> FloatArray:
    """Mean body rates ``(..., 3)`` rad/s that turn attitude ``q0`` into ``q1`` (world-from-
    body, ``(..., 4)``) in ``dt`` s: the rotation vector of ``q0* ⊗ q1`` divided by ``dt``
    (the shorter way round)."""
    d = quat_multiply(quat_conjugate(q0), q1)
    d = np.where(d[..., :1] < 0.0, -d, d)
    v = d[..., 1:]
    s = np.linalg.norm(v, axis=-1, keepdims=True)
    angle = 2.0 * np.arctan2(s, d[..., :1])
    # angle / s -> 2 as s -> 0 (w -> 1): the small-angle limit, without dividing by zero
    scale = np.where(s > 1e-12, angle / np.where(s > 1e-12, s, 1.0), 2.0)
    return np.asarray(scale * v / _f(dt)[..., None], dtype=np.float64)


def pose_interpolate(
    t0: ArrayLike, t1: ArrayLike, p0: ArrayLike, p1: ArrayLike, v0: ArrayLike, v1: ArrayLike,
    q0: ArrayLike, q1: ArrayLike, t: ArrayLike,
) -> tuple[FloatArray, FloatArray]:
    """Pose at time ``t`` between two states of a moving body at ``t0 < t1`` (s): position by
    cubic Hermite interpolation of positions ``p0, p1 (..., 3)`` m and velocities ``v0, v1
    (..., 3)`` m/s (exact for cubic motion; a coordinated turn sampled at 50 Hz is off by
    under a micrometre), attitude by :func:`quat_slerp` of ``q0, q1 (..., 4)``. ``t`` outside
    ``[t0, t1]`` is clamped. Returns ``(position (..., 3), orientation (..., 4))``."""
    a, b = _f(t0), _f(t1)
    h = b - a
    s = np.clip((_f(t) - a) / h, 0.0, 1.0)
    s2, s3 = s * s, s * s * s
    h00 = (2.0 * s3 - 3.0 * s2 + 1.0)[..., None]
    h10 = ((s3 - 2.0 * s2 + s) * h)[..., None]
    h01 = (-2.0 * s3 + 3.0 * s2)[..., None]
    h11 = ((s3 - s2) * h)[..., None]
    p = h00 * _f(p0) + h10 * _f(v0) + h01 * _f(p1) + h11 * _f(v1)
    return p, quat_slerp(q0, q1, s)


def velocity_interpolate(
    t0: ArrayLike, t1: ArrayLike, p0: ArrayLike, p1: ArrayLike, v0: ArrayLike, v1: ArrayLike,
    t: ArrayLike,
) -> FloatArray:
    """Velocity ``(..., 3)`` m/s at time ``t`` of the position :func:`pose_interpolate` gives
    (the time derivative of the same cubic Hermite: ``v0`` at ``t0``, ``v1`` at ``t1``); ``t``
    outside ``[t0, t1]`` is clamped."""
    a, b = _f(t0), _f(t1)
    h = b - a
    s = np.clip((_f(t) - a) / h, 0.0, 1.0)
    s2 = s * s
    d00 = ((6.0 * s2 - 6.0 * s) / h)[..., None]
    d10 = (3.0 * s2 - 4.0 * s + 1.0)[..., None]
    d11 = (3.0 * s2 - 2.0 * s)[..., None]
    return np.asarray(d00 * (_f(p0) - _f(p1)) + d10 * _f(v0) + d11 * _f(v1), dtype=np.float64)


def quat_from_rotation_vector(v: ArrayLike) -> FloatArray:
    """Unit quaternions ``(..., 4)`` of rotation vectors ``v (..., 3)`` (axis times angle,
    rad): the inverse of the rotation vector :func:`body_rates_from_quats` takes."""
    va = _f(v)
    angle = np.linalg.norm(va, axis=-1, keepdims=True)
    half = 0.5 * angle
    # sin(half) / angle -> 1/2 as angle -> 0, without dividing by zero
    scale = np.where(angle > 1e-12, np.sin(half) / np.where(angle > 1e-12, angle, 1.0), 0.5)
    return np.concatenate([np.cos(half), scale * va], axis=-1)


def pose_extrapolate(
    t1: ArrayLike, p1: ArrayLike, v1: ArrayLike, a1: ArrayLike, q1: ArrayLike,
    rates: ArrayLike, t: ArrayLike,
) -> tuple[FloatArray, FloatArray, FloatArray]:
    """Pose and velocity at time ``t`` (s) of a body last known at ``t1``: position
    ``p1 + v1 τ + a1 τ²/2`` and velocity ``v1 + a1 τ`` (``τ = t − t1``; ``p1, v1, a1 (..., 3)``
    m, m/s, m/s², world axes), attitude ``q1 ⊗ exp(rates τ)`` (``q1 (..., 4)`` world-from-body
    turning at constant body ``rates (..., 3)`` rad/s: exact for a steady coordinated turn).
    Returns ``(position (..., 3), orientation (..., 4), velocity (..., 3))``."""
    tau = (_f(t) - _f(t1))[..., None]
    a = _f(a1)
    p = _f(p1) + _f(v1) * tau + 0.5 * a * tau * tau
    q = quat_multiply(q1, quat_from_rotation_vector(_f(rates) * tau))
    return p, q / np.linalg.norm(q, axis=-1, keepdims=True), _f(v1) + a * tau


_NE_SWAP = [1, 0, 2]
_DOWN_UP = np.array([1.0, 1.0, -1.0])
_RD_LU = np.array([1.0, -1.0, -1.0])


def enu_from_ned(v: ArrayLike) -> FloatArray:
    """NED vectors ``(..., 3)`` (north, east, down) in ENU axes (east, north, up)."""
    return _f(v)[..., _NE_SWAP] * _DOWN_UP


def flu_from_frd(v: ArrayLike) -> FloatArray:
    """FRD body vectors ``(..., 3)`` (forward, right, down) in FLU axes (forward, left, up).

    Also converts body rates: ``(p, q, r)`` about FRD axes give the rates about FLU axes.
    """
    return _f(v) * _RD_LU


def quat_enu_flu_from_ned_frd(q_ned_frd: ArrayLike) -> FloatArray:
    """A world-from-body attitude logged as NED-from-FRD, as ENU-from-FLU ``(..., 4)``.

    ``q_enu_flu = q_enu_ned ⊗ q_ned_frd ⊗ q_frd_flu`` (a fixed linear map of the components);
    the result is normalised with w ≥ 0.
    """
    return quat_normalize(_f(q_ned_frd) @ _M_ENU_FLU_FROM_NED_FRD.T)


def ned_from_enu(v: ArrayLike) -> FloatArray:
    """ENU vectors ``(..., 3)`` in NED axes: the inverse of :func:`enu_from_ned` (the same
    swap, which is its own inverse)."""
    return enu_from_ned(v)


def frd_from_flu(v: ArrayLike) -> FloatArray:
    """FLU body vectors (or rates) ``(..., 3)`` in FRD axes: the inverse of
    :func:`flu_from_frd` (its own inverse)."""
    return flu_from_frd(v)


def quat_ned_frd_from_enu_flu(q_enu_flu: ArrayLike) -> FloatArray:
    """A world-from-body attitude ENU-from-FLU as NED-from-FRD ``(..., 4)``, normalised with
    w ≥ 0: the inverse of :func:`quat_enu_flu_from_ned_frd` (both frame changes are 180°
    rotations, so the same products invert it)."""
    return quat_enu_flu_from_ned_frd(q_enu_flu)
