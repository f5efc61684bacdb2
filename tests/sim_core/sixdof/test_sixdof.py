"""The JSBSim glider against closed forms: frames, the glide polar, climb in an updraft, rest."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from sim_core.config import from_dict
from sim_core.pose import quat_rotate
from sim_core.sixdof import (
    GROUND_MARGIN_M,
    SixDofGliders,
    SixDofSpec,
    enu_from_geodetic,
    fit_polar,
    geodetic_from_enu,
    measure_glides,
    polar_sink,
)

G = 9.80665


def _still(xy: np.ndarray) -> np.ndarray:
    return np.zeros(xy.shape[1])


def _fly(g: SixDofGliders, seconds: float, controls: np.ndarray, updraft=_still,
         dt: float = 0.01) -> None:
    for _ in range(round(seconds / dt)):
        g.step(dt, controls, updraft)


@settings(max_examples=60, deadline=None)
@given(
    lat0=st.floats(-80, 80), lon0=st.floats(-180, 180), h0=st.floats(-100, 3000),
    e=st.floats(-50e3, 50e3), n=st.floats(-50e3, 50e3), u=st.floats(-500, 5000),
)
def test_geodetic_round_trip_is_below_a_millimetre(lat0, lon0, h0, e, n, u) -> None:
    origin = (lat0, lon0, h0)
    p = np.array([[e, n, u]])
    lat, lon, h = geodetic_from_enu(p, origin)
    assert np.abs(enu_from_geodetic(lat, lon, h, origin) - p).max() < 1e-3


def test_height_above_the_origin_is_up() -> None:
    origin = (47.0, 8.0, 400.0)
    p = enu_from_geodetic(np.radians([47.0]), np.radians([8.0]), np.array([1400.0]), origin)
    np.testing.assert_allclose(p, [[0.0, 0.0, 1000.0]], atol=1e-9)


def test_spec_rejects_bad_values_with_the_key() -> None:
    with pytest.raises(ValueError, match="airspeed_mps"):
        SixDofSpec(airspeed_mps=0.0)
    with pytest.raises(ValueError, match="origin"):
        SixDofSpec(origin=(95.0, 0.0, 0.0))
    with pytest.raises(ValueError, match="aircraft"):
        SixDofGliders([SixDofSpec(aircraft="no_such_glider")], np.zeros((1, 3)), np.zeros(1))
    with pytest.raises(Exception, match="unknown"):
        from_dict(SixDofSpec, {"aircraft": "sgs126", "wingspan": 12})


def test_start_pose_heading_and_airspeed() -> None:
    g = SixDofGliders([SixDofSpec(airspeed_mps=22.0)], np.array([[100.0, -50.0, 600.0]]),
                      np.array([math.pi / 2]))  # ENU heading 90°: north
    o = g.outputs()
    np.testing.assert_allclose(o.position, [[100.0, -50.0, 600.0]], atol=1e-6)
    np.testing.assert_allclose(o.velocity, [[0.0, 22.0, 0.0]], atol=1e-6)
    np.testing.assert_allclose(o.yaw, [math.pi / 2], atol=1e-9)
    np.testing.assert_allclose(o.airspeed, [22.0], rtol=1e-9)


@pytest.mark.slow
def test_still_air_glides_follow_the_fitted_polar_and_the_sgs126_book() -> None:
    """Three steady glides fix ArduPilot's polar (K from mass and wing area in closed form); it
    predicts a glide it was not fitted on to 1 cm/s. The SGS 1-26 flies about as the type does
    (published for the 1-26E: best glide 23:1, minimum sink 2.7 ft/s): the model's best glide
    ratio is 24-28, its sink at 18 m/s below 0.8 m/s."""
    spec = SixDofSpec()
    glides, mass, area = measure_glides(spec, [-0.3, -0.15, -0.05, -0.2])
    polar = fit_polar(glides[:3], mass, area)
    assert polar.k == pytest.approx(2 * mass * G / (1.225 * area), rel=1e-12)
    assert 200.0 < mass < 205.0 and area == pytest.approx(160 * 0.3048**2)
    for gl in glides[3:]:
        assert gl.sink == pytest.approx(polar_sink(polar, gl.airspeed, gl.density), abs=0.01)
    assert 24.0 < polar.best_glide_ratio < 28.0
    assert polar_sink(polar, 18.0, 1.225) < 0.8
    # glide ratio is ground distance over height: airspeed/sink in still air, up to cos(gamma)
    for gl in glides:
        assert gl.glide_ratio == pytest.approx(
            math.sqrt(gl.airspeed**2 - gl.sink**2) / gl.sink, rel=2e-3)


@pytest.mark.slow
def test_climb_is_the_updraft_minus_the_sink_in_a_uniform_updraft() -> None:
    """A uniform updraft moves the whole air mass: once the start transient has died out, the
    glider's vertical speed is the updraft minus its still-air sink at the density it has
    climbed into (the same elevator holds the same equivalent airspeed, so the true sink
    scales with 1/sqrt(density))."""
    starts = np.array([[0.0, 0.0, 800.0], [0.0, 0.0, 800.0]])
    w = 1.7

    def updraft(xy: np.ndarray) -> np.ndarray:
        return np.array([0.0, w])

    g = SixDofGliders([SixDofSpec(), SixDofSpec()], starts, np.zeros(2), updraft=updraft)
    u = np.array([[0.0, -0.15, 0.0, 0.0]] * 2)
    _fly(g, 60.0, u, updraft)
    vz = []
    for _ in range(45):  # five phugoid periods (about 9 s each), sampled every 1 s
        _fly(g, 1.0, u, updraft)
        vz.append(g.outputs().velocity[:, 2])
    still, lifted = np.mean(vz, axis=0)
    assert 0.6 < -still < 0.9
    # the same motion through the air (up to the density the climb changed): w - sink
    assert lifted == pytest.approx(w + still, abs=0.01)


def test_specific_force_at_rest_is_g_up() -> None:
    """On the ground, at rest, an accelerometer reads g upwards, whatever the pitch the gear
    gives the glider."""
    g = SixDofGliders([SixDofSpec(airspeed_mps=0.01, origin=(47.0, 8.0, 300.0))],
                      np.zeros((1, 3)), np.zeros(1))
    _fly(g, 10.0, np.zeros((1, 4)))
    o = g.outputs()
    assert np.linalg.norm(o.velocity) < 0.05
    np.testing.assert_allclose(quat_rotate(o.quat[0], o.specific_force[0]), [0.0, 0.0, G],
                               atol=0.02)
    assert o.position[0, 2] == pytest.approx(0.0, abs=1.5)  # on the ground at the origin


def test_same_inputs_same_bits() -> None:
    runs = []
    for _ in range(2):
        g = SixDofGliders([SixDofSpec()], np.array([[0.0, 0.0, 500.0]]), np.zeros(1))
        u = np.array([[0.3, -0.2, 0.0, 0.1]])
        _fly(g, 5.0, u, lambda xy: 0.5 + 1e-3 * xy[0])
        o = g.outputs()
        runs.append(np.concatenate([o.position.ravel(), o.quat.ravel(), o.specific_force.ravel()]))
    assert runs[0].tobytes() == runs[1].tobytes()


def test_a_glider_that_comes_down_is_held_at_rest_where_it_was_last_sound() -> None:
    # banked hard from 30 m: it hits the ground, rolls onto its wing and (JSBSim's contact
    # points are its skid and wheel) falls through the terrain, where JSBSim's state goes NaN
    g = SixDofGliders([SixDofSpec(airspeed_mps=20.0)], np.array([[0.0, 0.0, 30.0]]),
                      np.zeros(1))
    u = np.array([[0.5, 0.0, 0.0, 0.0]])
    down_at, held = None, None
    for k in range(2500):
        g.step(0.01, u, _still)
        o = g.outputs()
        rows = np.concatenate([o.position, o.velocity, o.quat, o.rates, o.specific_force,
                               o.geodetic], axis=1)
        assert np.isfinite(rows).all() and np.isfinite(o.airspeed).all()
        if not o.alive[0] and down_at is None:
            down_at, held = k, o
        if down_at is not None:
            assert not o.alive[0]
            np.testing.assert_array_equal(o.position, held.position)  # type: ignore[union-attr]
            np.testing.assert_array_equal(o.quat, held.quat)  # type: ignore[union-attr]
    assert down_at is not None and 5 <= down_at / 100 <= 25
    assert held is not None and held.position[0, 2] > -GROUND_MARGIN_M - 1.0
    np.testing.assert_array_equal(held.velocity, 0.0)
    np.testing.assert_array_equal(held.rates, 0.0)
    assert held.airspeed[0] == 0.0
    # at rest the accelerometer reads gravity's reaction: +g up in the world
    np.testing.assert_allclose(quat_rotate(held.quat[0], held.specific_force[0]), [0.0, 0.0, G],
                               atol=1e-9)


def test_controls_are_clipped_and_nan_is_neutral() -> None:
    g = SixDofGliders([SixDofSpec()], np.array([[0.0, 0.0, 500.0]]), np.zeros(1))
    g.step(0.01, np.array([[5.0, math.nan, -3.0, -9.0]]), _still)
    np.testing.assert_array_equal(g._controls, [[1.0, 0.0, 0.0, -1.0]])
    assert g.outputs().alive.all()
