"""The HIL edge's messages: frames, units and scales of HIL_SENSOR, HIL_GPS and
HIL_STATE_QUATERNION from echoloop's readings, and PX4's controls to JSBSim's surfaces."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from drivers.mavlink.hil import (
    FIELDS_ALL,
    ActuatorMap,
    Clip,
    hil_gps,
    hil_sensor,
    hil_state_quaternion,
    surfaces_from_controls,
)
from drivers.mavlink.link import mavlink
from hil_bridge.bus.messages import FdmState
from sim_core.pose import quat_from_euler, quat_ned_frd_from_enu_flu
from sim_core.sensors import GpsFix, SensorReadings

finite = st.floats(-1e4, 1e4, allow_nan=False)


def readings(values: list[float]) -> SensorReadings:
    return SensorReadings(t_ns=0, table=np.array([values], dtype=np.float64))


def roundtrip(msg: object) -> object:
    tx = mavlink.MAVLink(None, srcSystem=1, srcComponent=158)
    rx = mavlink.MAVLink(None)
    return rx.parse_buffer(msg.pack(tx))[0]  # type: ignore[attr-defined]


@settings(max_examples=100, deadline=None)
@given(st.lists(finite, min_size=9, max_size=9), st.floats(100.0, 1.1e5),
       st.floats(0.0, 3000.0), st.floats(-60, 50))
def test_hil_sensor_is_frd_in_hpa(flu: list[float], p: float, q: float, temp: float) -> None:
    r = readings([*flu, p, q, 123.4, temp, 1.2])
    m = roundtrip(hil_sensor(1_000_004, r))
    sign = [1, -1, -1] * 3
    got = [m.xacc, m.yacc, m.zacc, m.xgyro, m.ygyro, m.zgyro, m.xmag, m.ymag, m.zmag]
    np.testing.assert_allclose(got, np.float32(np.array(flu) * sign), rtol=1e-7, atol=0)
    assert m.abs_pressure == pytest.approx(p / 100, rel=1e-7)
    assert m.diff_pressure == pytest.approx(q / 100, rel=1e-7, abs=1e-9)
    assert m.fields_updated == FIELDS_ALL and m.id == 0 and m.time_usec == 1_000_004


def test_nothing_non_finite_is_ever_built() -> None:
    good = [0.0] * 9 + [1e5, 10.0, 100.0, 15.0, 1.2]
    for k in range(13):
        bad = list(good)
        bad[k] = math.nan if k % 2 else math.inf
        assert hil_sensor(0, readings(bad)) is None
    fix = GpsFix(t_ns=0, measured_ns=0, lat_deg=np.array([math.nan]), lon_deg=np.array([8.0]),
                 alt_m=np.array([1.0]), velocity=np.zeros((1, 3)), eph_m=1, epv_m=1,
                 satellites=10)
    assert hil_gps(0, fix, Clip()) is None


def test_hil_gps_scales_and_course() -> None:
    fix = GpsFix(t_ns=0, measured_ns=0, lat_deg=np.array([47.1234567]),
                 lon_deg=np.array([-8.7654321]), alt_m=np.array([432.1]),
                 velocity=np.array([[3.0, 4.0, -0.5]]), eph_m=0.9, epv_m=1.4, satellites=11)
    m = roundtrip(hil_gps(5, fix, Clip()))
    assert (m.lat, m.lon, m.alt) == (471234567, -87654321, 432100)
    assert (m.vn, m.ve, m.vd, m.vel) == (400, 300, 50, 500)  # NED cm/s, ground speed
    assert m.cog == round(math.degrees(math.atan2(3.0, 4.0)) * 100)
    assert (m.eph, m.epv, m.fix_type, m.satellites_visible) == (90, 140, 3, 11)


def test_hil_state_quaternion_is_the_truth_in_ned_frd() -> None:
    q = quat_from_euler(0.3, 0.05, 1.0)
    s = FdmState(stamp_ns=0, glider_id=7, step=3, x=0, y=0, z=0, vx=20.0, vy=-1.0, vz=-0.7,
                 qw=q[0], qx=q[1], qy=q[2], qz=q[3], p=0.1, q=0.2, r=0.3, fx=0.5, fy=0.2,
                 fz=9.8, airspeed=21.0, lat=47.0, lon=8.0, alt=400.0)
    r = readings([0.0] * 13 + [1.0])  # density 1.0 kg/m³
    clip = Clip()
    m = roundtrip(hil_state_quaternion(9, s, r, clip))
    np.testing.assert_allclose(m.attitude_quaternion, quat_ned_frd_from_enu_flu(q), atol=1e-7)
    assert (m.rollspeed, m.pitchspeed, m.yawspeed) == pytest.approx((0.1, -0.2, -0.3))
    assert (m.vx, m.vy, m.vz) == (-100, 2000, 70)  # north, east, down cm/s
    assert m.true_airspeed == 2100
    assert m.ind_airspeed == round(2100 * math.sqrt(1.0 / 1.225))
    assert (m.xacc, m.yacc, m.zacc) == (51, -20, -999)  # mG, FRD
    assert clip.count == 0
    fast = FdmState(stamp_ns=0, glider_id=7, step=3, x=0, y=0, z=0, vx=400.0, vy=0, vz=0,
                    qw=1, qx=0, qy=0, qz=0, p=0, q=0, r=0, fx=0, fy=0, fz=9.8, airspeed=700.0,
                    lat=47.0, lon=8.0, alt=400.0)
    m = roundtrip(hil_state_quaternion(9, fast, r, clip))
    assert m.vy == 32767 and m.true_airspeed == 65535 and clip.count == 2


def test_controls_map_to_jsbsim_surfaces_with_their_signs() -> None:
    u = [0.0] * 16
    u[0], u[1], u[2], u[3] = 0.4, 0.3, 0.2, 0.9
    # PX4: roll + right, pitch + up, yaw + right; JSBSim: aileron + right, elevator + down,
    # rudder + left
    assert surfaces_from_controls(u, ActuatorMap()) == pytest.approx((0.4, -0.3, 0.9, -0.2))
    split = ActuatorMap(roll=((5, 0.5), (6, -0.5)), throttle=((4, 1.0),))
    u2 = [0.0] * 16
    u2[5], u2[6], u2[4] = 0.6, -0.6, 2.0
    a, _, t, _ = surfaces_from_controls(u2, split)  # type: ignore[misc]
    assert a == pytest.approx(0.6) and t == 1.0  # clipped to its range
    u2[6] = math.nan
    assert surfaces_from_controls(u2, split) is None
    with pytest.raises(ValueError, match=r"actuators\.yaw"):
        ActuatorMap(yaw=((16, 1.0),))
