"""Property tests at the numerical extremes: commands and states stay finite and limited."""

from __future__ import annotations

import math

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from sim_core.soaring import GliderObs, Law, accel_to_command, controller_command, glider_step

LAW = Law().replace(bankMin=-math.radians(80), bankMax=math.radians(80))
finite = st.floats(min_value=-1e300, max_value=1e300, allow_nan=False, allow_infinity=False)
angle = st.floats(min_value=-50.0, max_value=50.0, allow_nan=False)
coord = st.floats(min_value=-5000.0, max_value=5000.0, allow_nan=False)


@settings(max_examples=200, deadline=None)
@given(ax=finite, ay=finite, heading=angle, speed=st.floats(8.0, 13.0), dt=st.floats(1e-3, 5.0))
def test_any_acceleration_gives_finite_limited_flight(
    ax: float, ay: float, heading: float, speed: float, dt: float
) -> None:
    a = np.array([[ax]]), np.array([[ay]])
    h, v = np.array([[heading]]), np.array([[speed]])
    bank_cmd, speed_cmd = accel_to_command(a[0], a[1], h, v, dt=dt, g=9.81,
                                           thermal_bank_factor=0.0, updraft=0.0)
    assert not np.isnan(bank_cmd).any() and not np.isnan(speed_cmd).any()
    out = glider_step(np.zeros((1, 1)), np.zeros((1, 1)), np.full((1, 1), 1000.0), h,
                      np.zeros((1, 1)), v, bank_cmd, speed_cmd, np.zeros((1, 1)), dt=dt, g=9.81,
                      speed_min=8.0, speed_max=13.0, bank_min=LAW.bankMin, bank_max=LAW.bankMax,
                      sink_abc=(LAW.Sink_A, LAW.Sink_B, LAW.Sink_C), ceiling=2600.0, floor=0.0)
    for name in ("x", "y", "z", "heading", "bank", "speed", "omega", "vz"):
        assert np.isfinite(getattr(out, name)).all(), name
    assert abs(out.bank[0, 0]) <= LAW.bankMax and 8.0 <= out.speed[0, 0] <= 13.0


@settings(max_examples=150, deadline=None)
@given(
    own=st.tuples(coord, coord, st.floats(0.0, 2600.0), angle, st.floats(8.0, 13.0),
                  st.floats(-10.0, 10.0)),
    offsets=st.lists(
        st.tuples(st.floats(-5.0, 5.0), st.floats(-5.0, 5.0), st.floats(-300.0, 300.0),
                  angle, st.floats(8.0, 13.0), st.floats(-10.0, 10.0)),
        max_size=12,
    ),
    stacked=st.booleans(),
    controller=st.sampled_from(["unified", "baseline"]),
)
def test_controller_is_finite_for_close_and_stacked_neighbours(
    own: tuple[float, ...], offsets: list[tuple[float, ...]], stacked: bool, controller: str
) -> None:
    x, y, z, h, v, vz = own
    me = GliderObs(x, y, z, h, v, vz)
    nbrs = [GliderObs(x + (0.0 if stacked else dx), y + (0.0 if stacked else dy), z + dz, hh, vv,
                      ww) for dx, dy, dz, hh, vv, ww in offsets]
    bank, speed = controller_command(me, nbrs, LAW, controller=controller)  # type: ignore[arg-type]
    assert not math.isnan(bank) and not math.isnan(speed)
    assert abs(bank) <= math.pi / 2
