"""A sonar on a vehicle: the ping's beam and ears turn with the vehicle's attitude and mount."""

from __future__ import annotations

import math

import numpy as np
import pytest

from sim_core.pose import pose_compose, quat_from_euler, quat_to_matrix
from sim_core.sonar import Ear
from sim_core.sonar.mount import ears_for_ping, ping_beam

D = math.radians


def _rz(a: float) -> np.ndarray:
    return np.array([[math.cos(a), -math.sin(a), 0], [math.sin(a), math.cos(a), 0], [0, 0, 1]])


def _rx(a: float) -> np.ndarray:
    return np.array([[1, 0, 0], [0, math.cos(a), -math.sin(a)], [0, math.sin(a), math.cos(a)]])


def test_a_banked_vehicle_rolls_the_beam() -> None:
    heading, az, el = 0.7, 0.4, -0.3
    level = ping_beam([1, 2, 3], quat_from_euler(0.0, 0.0, heading), az, el, 0.5)
    # the old attitude-blind beam: world azimuth heading + az, elevation el
    assert level.az_el == pytest.approx((heading + az, el), abs=1e-12)
    # 30 degrees of bank into a left turn: roll = -30 deg about the body's forward axis
    banked = ping_beam([1, 2, 3], quat_from_euler(-D(30), 0.0, heading), az, el, 0.5)
    d = np.array([math.cos(el) * math.cos(az), math.cos(el) * math.sin(az), math.sin(el)])
    np.testing.assert_allclose(banked.boresight, _rz(heading) @ _rx(-D(30)) @ d, atol=1e-15)
    assert banked.az_el[1] < el - D(5)  # a beam looking left and down dips further (9 deg)
    np.testing.assert_array_equal(banked.position, [1.0, 2.0, 3.0])
    assert banked.beamwidth_rad == 0.5


def test_a_ninety_degree_yaw_mount_points_sideways() -> None:
    body = quat_from_euler(0.0, 0.0, 0.0)  # flying east
    pos, q = pose_compose([0, 0, 2], body, [0.3, 0.0, 0.1], quat_from_euler(0, 0, D(90)))
    beam = ping_beam(pos, q, 0.0, 0.0, 0.6)
    np.testing.assert_allclose(beam.boresight, [0.0, 1.0, 0.0], atol=1e-15)  # north: left
    np.testing.assert_allclose(beam.position, [0.3, 0.0, 2.1])


def test_ears_fixed_on_the_sonar_match_the_models_beam_frame_ears() -> None:
    left, right = Ear.binaural(0.03, D(15))
    pos = [left.offset, right.offset]
    axes = [[math.cos(D(15)), math.sin(D(15)), 0.0], [math.cos(D(15)), -math.sin(D(15)), 0.0]]
    level = quat_from_euler(0.0, 0.0, 1.2)
    beam = ping_beam([0, 0, 0], level, 0.0, 0.0, 0.6)
    ears = ears_for_ping(beam, level, pos, axes, [None, D(40)])
    for got, want in zip(ears, (left, right), strict=True):
        np.testing.assert_allclose(got.offset, want.offset, atol=1e-15)
        assert got.yaw_rad == pytest.approx(want.yaw_rad, abs=1e-12)
        assert got.pitch_rad == pytest.approx(0.0, abs=1e-12)
    assert ears[0].beamwidth_rad is None and ears[1].beamwidth_rad == D(40)
    # rolled 90 degrees (right wing down): the left ear is now above the emitter, and the
    # model puts it at the world position R @ p whatever the ping's direction
    rolled = quat_from_euler(D(90), 0.0, 1.2)
    for az, el in ((0.0, 0.0), (0.5, -0.4)):
        beam = ping_beam([5, 5, 5], rolled, az, el, 0.6)
        ears = ears_for_ping(beam, rolled, pos, axes, [None, None])
        world = np.asarray(ears[0].offset) @ beam.frame()
        np.testing.assert_allclose(world, quat_to_matrix(rolled) @ np.asarray(left.offset),
                                   atol=1e-15)
        np.testing.assert_allclose(world, [0.0, 0.0, 0.015], atol=1e-15)
