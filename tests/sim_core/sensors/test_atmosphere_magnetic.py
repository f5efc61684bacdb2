"""The ISA against its published table and its own inverse; the WMM field's size and dip."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from sim_core.sensors import WMM_VALID, dynamic_pressure, field_enu, isa, pressure_altitude

R0 = 6356766.0


def geopotential(h: float) -> float:
    return R0 * h / (R0 + h)


@pytest.mark.parametrize(("h_geopotential", "p", "t", "rho"), [
    (0.0, 101325.0, 288.15, 1.2250),
    (1000.0, 89874.6, 281.65, 1.1117),
    (5000.0, 54019.9, 255.65, 0.73612),
    (11000.0, 22632.1, 216.65, 0.36392),
    (15000.0, 12044.6, 216.65, 0.19367),
    (-500.0, 107477.8, 291.40, 1.2849),
])
def test_isa_matches_the_standard_table(h_geopotential: float, p: float, t: float,
                                        rho: float) -> None:
    """ICAO Doc 7488 values at geopotential heights (geometric h = R0 H / (R0 - H))."""
    h = R0 * h_geopotential / (R0 - h_geopotential)
    pi, ti, ri = isa(np.array([h]))
    assert pi[0] == pytest.approx(p, rel=2e-5)
    assert ti[0] == pytest.approx(t, abs=1e-9)
    assert ri[0] == pytest.approx(rho, rel=1e-4)


@given(st.floats(-5000.0, 20000.0))
def test_pressure_altitude_inverts_the_isa(h: float) -> None:
    p, _, _ = isa(np.array([h]))
    assert pressure_altitude(p)[0] == pytest.approx(geopotential(h), abs=1e-6)


def test_isa_refuses_heights_outside_its_layers() -> None:
    with pytest.raises(ValueError, match="20001"):
        isa(np.array([100.0, 20001.0]))


def test_dynamic_pressure_is_half_rho_v_squared() -> None:
    assert dynamic_pressure(1.225, 20.0) == pytest.approx(0.5 * 1.225 * 400.0, rel=1e-15)


def test_the_field_near_the_scene_origin() -> None:
    """WMM2025 at 47° N 8° E in 2026: 0.482 gauss, dipping 63.1°, declination 3.5° E
    (pinned to 0.3°: the model's secular variation moves them by about 0.1° a year)."""
    b = field_enu(np.array([47.0]), np.array([8.0]), np.array([400.0]), 2026.0)[0]
    total = float(np.linalg.norm(b))
    assert total == pytest.approx(0.482, abs=0.003)
    dip = math.degrees(math.atan2(-b[2], math.hypot(b[0], b[1])))
    assert dip == pytest.approx(63.1, abs=0.3)
    decl = math.degrees(math.atan2(b[0], b[1]))
    assert decl == pytest.approx(3.5, abs=0.3)


def test_the_field_is_vectorised_and_refuses_dates_outside_the_model() -> None:
    lat = np.array([47.0, -33.9, 0.0])
    lon = np.array([8.0, 151.2, 200.0])  # 200° E is 160° W
    b = field_enu(lat, lon, np.zeros(3), 2027.5)
    for k in range(3):
        assert np.array_equal(b[k], field_enu(lat[k:k + 1], lon[k:k + 1], np.zeros(1),
                                              2027.5)[0])
    assert b[1, 2] > 0  # the southern hemisphere's field points up
    with pytest.raises(ValueError, match="epoch_year"):
        field_enu(lat, lon, np.zeros(3), WMM_VALID[1])
