"""Rotations and frames against hand-computed cases and the explicit Z-Y-X matrices."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import assume, given
from hypothesis import strategies as st

from sim_core.pose import (
    ENU_FROM_NED,
    body_rates_from_euler_rates,
    body_rates_from_quats,
    direction_from_az_el,
    enu_from_ned,
    euler_from_quat,
    flu_from_frd,
    pose_compose,
    pose_extrapolate,
    pose_interpolate,
    quat_between,
    quat_conjugate,
    quat_enu_flu_from_ned_frd,
    quat_from_euler,
    quat_from_rotation_vector,
    quat_multiply,
    quat_normalize,
    quat_rotate,
    quat_slerp,
    quat_to_matrix,
    velocity_interpolate,
)

D = math.radians
angle = st.floats(-math.pi, math.pi, allow_nan=False)
pitch_angle = st.floats(-1.5, 1.5, allow_nan=False)


def _rz(a: float) -> np.ndarray:
    return np.array([[math.cos(a), -math.sin(a), 0], [math.sin(a), math.cos(a), 0], [0, 0, 1]])


def _ry(a: float) -> np.ndarray:
    return np.array([[math.cos(a), 0, math.sin(a)], [0, 1, 0], [-math.sin(a), 0, math.cos(a)]])


def _rx(a: float) -> np.ndarray:
    return np.array([[1, 0, 0], [0, math.cos(a), -math.sin(a)], [0, math.sin(a), math.cos(a)]])


@given(angle, pitch_angle, angle)
def test_quaternion_is_the_zyx_matrix_and_euler_round_trips(r: float, p: float, y: float) -> None:
    q = quat_from_euler(r, p, y)
    np.testing.assert_allclose(quat_to_matrix(q), _rz(y) @ _ry(p) @ _rx(r), atol=1e-12)
    np.testing.assert_allclose(np.linalg.norm(q), 1.0, rtol=1e-15, atol=1e-15)
    back = np.array(euler_from_quat(q))
    wrapped = (back - np.array([r, p, y]) + math.pi) % (2 * math.pi) - math.pi
    np.testing.assert_allclose(wrapped, 0.0, atol=1e-9)


@given(angle, pitch_angle, angle, st.lists(st.floats(-10, 10), min_size=3, max_size=3))
def test_rotate_is_the_matrix_and_conjugate_undoes_it(
    r: float, p: float, y: float, v: list[float]
) -> None:
    q = quat_from_euler(r, p, y)
    np.testing.assert_allclose(quat_rotate(q, v), quat_to_matrix(q) @ v, atol=1e-12)
    np.testing.assert_allclose(quat_rotate(quat_conjugate(q), quat_rotate(q, v)), v, atol=1e-12)
    two = quat_multiply(q, q)
    np.testing.assert_allclose(quat_rotate(two, v), quat_rotate(q, quat_rotate(q, v)), atol=1e-11)


def test_flu_sign_conventions() -> None:
    right, forward = np.array([0.0, -1.0, 0.0]), np.array([1.0, 0.0, 0.0])
    assert quat_rotate(quat_from_euler(0.3, 0.0, 0.0), right)[2] < 0  # +roll: right wing down
    assert quat_rotate(quat_from_euler(0.0, 0.3, 0.0), forward)[2] < 0  # +pitch: nose down
    np.testing.assert_allclose(quat_rotate(quat_from_euler(0, 0, math.pi / 2), forward),
                               [0.0, 1.0, 0.0], atol=1e-15)  # yaw pi/2: nose north


def test_vectorised_over_leading_axes() -> None:
    r = np.linspace(-1, 1, 12).reshape(3, 4)
    q = quat_from_euler(r, 0.5 * r, -r)
    assert q.shape == (3, 4, 4)
    v = quat_rotate(q, np.array([1.0, 2.0, 3.0]))
    assert v.shape == (3, 4, 3)
    np.testing.assert_allclose(v[1, 2], quat_rotate(q[1, 2], [1.0, 2.0, 3.0]))
    roll, pitch, yaw = euler_from_quat(q)
    np.testing.assert_allclose(np.stack([roll, pitch, yaw]), np.stack([r, 0.5 * r, -r]),
                               atol=1e-12)
    assert quat_to_matrix(q).shape == (3, 4, 3, 3)


def _ned_quat(roll: float, pitch: float, yaw: float) -> np.ndarray:
    """An attitude as a NED/FRD log stores it (the same Z-Y-X formula, NED axes)."""
    return quat_from_euler(roll, pitch, yaw)


def test_north_bound_level_vehicle() -> None:
    q = quat_enu_flu_from_ned_frd(_ned_quat(0.0, 0.0, 0.0))
    roll, pitch, yaw = euler_from_quat(q)
    assert (roll, pitch) == pytest.approx((0.0, 0.0), abs=1e-15)
    assert yaw == pytest.approx(math.pi / 2, abs=1e-15)
    np.testing.assert_allclose(quat_rotate(q, [1.0, 0, 0]), [0.0, 1.0, 0.0], atol=1e-15)
    np.testing.assert_allclose(quat_rotate(q, [0.0, 0, 1.0]), [0.0, 0.0, 1.0], atol=1e-15)


def test_thirty_degree_right_bank_heading_north() -> None:
    q = quat_enu_flu_from_ned_frd(_ned_quat(D(30), 0.0, 0.0))
    roll, pitch, yaw = euler_from_quat(q)
    assert (roll, pitch, yaw) == pytest.approx((D(30), 0.0, math.pi / 2), abs=1e-12)
    # the right wing (FLU -y) points east and 30 degrees down
    np.testing.assert_allclose(quat_rotate(q, [0.0, -1.0, 0.0]),
                               [math.cos(D(30)), 0.0, -math.sin(D(30))], atol=1e-15)


def test_ten_degree_climb_heading_east() -> None:
    q = quat_enu_flu_from_ned_frd(_ned_quat(0.0, D(10), D(90)))
    roll, pitch, yaw = euler_from_quat(q)
    assert (roll, pitch, yaw) == pytest.approx((0.0, -D(10), 0.0), abs=1e-12)
    np.testing.assert_allclose(quat_rotate(q, [1.0, 0.0, 0.0]),
                               [math.cos(D(10)), 0.0, math.sin(D(10))], atol=1e-15)


def test_vectors_and_rates_at_the_edge() -> None:
    np.testing.assert_array_equal(enu_from_ned([1.0, 2.0, 3.0]), [2.0, 1.0, -3.0])
    np.testing.assert_array_equal(ENU_FROM_NED @ np.array([1.0, 2.0, 3.0]), [2.0, 1.0, -3.0])
    np.testing.assert_array_equal(flu_from_frd([[1.0, 2.0, 3.0]]), [[1.0, -2.0, -3.0]])


def test_slerp_end_points_midpoint_and_short_arc() -> None:
    a, b = quat_from_euler(0, 0, 0.0), quat_from_euler(0, 0, 1.0)
    np.testing.assert_allclose(quat_slerp(a, b, 0.0), a, atol=1e-15)
    np.testing.assert_allclose(quat_slerp(a, b, 1.0), b, atol=1e-15)
    np.testing.assert_allclose(quat_slerp(a, b, 0.5), quat_from_euler(0, 0, 0.5), atol=1e-15)
    # -b is the same rotation: the arc taken is still the short one
    np.testing.assert_allclose(euler_from_quat(quat_slerp(a, -b, 0.25))[2], 0.25, atol=1e-12)
    np.testing.assert_allclose(quat_slerp(a, a, np.array([0.0, 0.3, 1.0])), np.tile(a, (3, 1)))


def test_normalize_canonical_sign_and_zero() -> None:
    np.testing.assert_allclose(quat_normalize([-2.0, 0.0, 0.0, 0.0]), [1.0, 0.0, 0.0, 0.0])
    with pytest.raises(ValueError, match="zero or non-finite"):
        quat_normalize([0.0, 0.0, 0.0, 0.0])


vec = st.lists(st.floats(-10, 10), min_size=3, max_size=3).filter(
    lambda v: float(np.linalg.norm(v)) > 1e-3)


@given(vec, vec)
def test_quat_between_takes_a_to_b(a: list[float], b: list[float]) -> None:
    q = quat_between(a, b)
    ua, ub = np.asarray(a) / np.linalg.norm(a), np.asarray(b) / np.linalg.norm(b)
    cross = float(np.linalg.norm(np.cross(ua, ub)))
    assume(cross > 1e-9 or float(ua @ ub) > 0)  # exact opposites: the test below
    # near opposite directions the rotation axis is only known to ~1e-16 / |a x b|
    tol = 1e-12 if float(ua @ ub) > 0 else max(1e-12, 1e-15 / cross)
    np.testing.assert_allclose(quat_rotate(q, ua), ub, atol=tol)
    np.testing.assert_allclose(np.linalg.norm(q), 1.0, atol=1e-12)


def test_quat_between_opposite_and_equal_directions() -> None:
    for a in ([1.0, 0, 0], [0, 0, 2.0], [0.3, -0.2, 0.9]):
        np.testing.assert_allclose(quat_rotate(quat_between(a, np.negative(a)), a),
                                   np.negative(a), atol=1e-12)
        np.testing.assert_allclose(quat_between(a, a), [1.0, 0, 0, 0], atol=1e-15)


def test_direction_from_az_el_and_a_sideways_mount() -> None:
    np.testing.assert_allclose(direction_from_az_el(0.0, 0.0), [1.0, 0.0, 0.0])
    np.testing.assert_allclose(direction_from_az_el(math.pi / 2, 0.0), [0.0, 1.0, 0.0],
                               atol=1e-16)
    np.testing.assert_allclose(direction_from_az_el(0.3, math.pi / 2), [0.0, 0.0, 1.0],
                               atol=1e-16)
    # a sonar yawed 90 degrees on a vehicle flying east, 0.5 m ahead of its centre: it
    # looks north (to the left), and sits 0.5 m east of the vehicle
    p, q = pose_compose([10.0, 0.0, 2.0], quat_from_euler(0, 0, 0.0), [0.5, 0.0, 0.0],
                        quat_from_euler(0, 0, math.pi / 2))
    np.testing.assert_allclose(p, [10.5, 0.0, 2.0])
    np.testing.assert_allclose(quat_rotate(q, [1.0, 0, 0]), [0.0, 1.0, 0.0], atol=1e-15)
    # banked 30 degrees into a left turn (roll = -30 deg): the sideways beam tilts down
    _, q = pose_compose([0.0, 0, 0], quat_from_euler(-D(30), 0.0, 0.0), [0.0, 0, 0],
                        quat_from_euler(0, 0, math.pi / 2))
    np.testing.assert_allclose(quat_rotate(q, [1.0, 0, 0]),
                               [0.0, math.cos(D(30)), -math.sin(D(30))], atol=1e-15)


@given(angle, pitch_angle, angle, vec)
def test_body_rates_from_euler_rates_match_the_attitude_change(
    r: float, p: float, y: float, rates: list[float]
) -> None:
    dr, dp, dy = (0.1 * v for v in rates)
    h = 1e-6
    q0 = quat_from_euler(r, p, y)
    q1 = quat_from_euler(r + dr * h, p + dp * h, y + dy * h)
    np.testing.assert_allclose(body_rates_from_quats(q0, q1, h),
                               body_rates_from_euler_rates(r, p, dr, dp, dy), atol=1e-5)


def test_body_rates_of_a_constant_rotation_and_no_rotation() -> None:
    q0 = quat_from_euler(0.2, -0.1, 1.0)
    spin = quat_from_euler(0.0, 0.0, 0.5)  # 0.5 rad about body z
    np.testing.assert_allclose(body_rates_from_quats(q0, quat_multiply(q0, spin), 2.0),
                               [0.0, 0.0, 0.25], atol=1e-15)
    np.testing.assert_array_equal(body_rates_from_quats(q0, q0, 0.1), [0.0, 0.0, 0.0])


def test_pose_interpolation_is_exact_for_cubic_motion() -> None:
    def pos(t: float) -> np.ndarray:
        return np.array([1.0 + 2 * t, -t * t, 0.5 * t**3 - t])

    def vel(t: float) -> np.ndarray:
        return np.array([2.0, -2 * t, 1.5 * t * t - 1.0])

    qa, qb = quat_from_euler(0, 0, 0.1), quat_from_euler(0, 0, 0.3)
    for t in (0.3, 0.55, 0.8):
        p, q = pose_interpolate(0.3, 0.8, pos(0.3), pos(0.8), vel(0.3), vel(0.8), qa, qb, t)
        np.testing.assert_allclose(p, pos(t), atol=1e-14)
        np.testing.assert_allclose(q, quat_from_euler(0, 0, 0.1 + 0.4 * (t - 0.3)), atol=1e-15)
    p, _ = pose_interpolate(0.3, 0.8, pos(0.3), pos(0.8), vel(0.3), vel(0.8), qa, qb, 2.0)
    np.testing.assert_allclose(p, pos(0.8))  # clamped to the newer state
    # the velocity of that cubic is its derivative, exactly
    for t in (0.3, 0.55, 0.8):
        v = velocity_interpolate(0.3, 0.8, pos(0.3), pos(0.8), vel(0.3), vel(0.8), t)
        np.testing.assert_allclose(v, vel(t), atol=1e-13)


def test_a_rotation_vector_is_the_inverse_of_the_mean_body_rates() -> None:
    q0 = quat_from_euler(0.3, -0.2, 2.0)
    for w in ([0.0, 0.0, 0.0], [0.4, -1.2, 0.7], [1e-14, 0.0, 0.0]):
        q1 = quat_multiply(q0, quat_from_rotation_vector(np.array(w) * 0.5))
        np.testing.assert_allclose(body_rates_from_quats(q0, q1, 0.5), w, atol=1e-13)
    np.testing.assert_allclose(quat_from_rotation_vector([0.0, 0.0, 0.5]),
                               quat_from_euler(0.0, 0.0, 0.5), atol=1e-15)


def test_extrapolation_is_exact_for_constant_acceleration_and_a_steady_turn() -> None:
    p1, v1, a1 = np.array([1.0, 2.0, 3.0]), np.array([4.0, -1.0, 0.5]), np.array([0.2, 1.0, 0.0])
    # a banked glider turning at a constant yaw rate: constant body rates
    roll, yaw0, yaw_rate = -0.5, 0.3, 0.8
    rates = body_rates_from_euler_rates(roll, 0.0, 0.0, 0.0, yaw_rate)
    for tau in (0.0, 0.013, 0.04):
        p, q, v = pose_extrapolate(2.0, p1, v1, a1, quat_from_euler(roll, 0.0, yaw0), rates,
                                   2.0 + tau)
        np.testing.assert_allclose(p, p1 + v1 * tau + 0.5 * a1 * tau**2, atol=1e-15)
        np.testing.assert_allclose(v, v1 + a1 * tau, atol=1e-15)
        np.testing.assert_allclose(q, quat_from_euler(roll, 0.0, yaw0 + yaw_rate * tau),
                                   atol=1e-15)
