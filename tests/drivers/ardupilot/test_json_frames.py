"""SITL's JSON interface: servo packets, PWM to surfaces, state lines and their frames."""

from __future__ import annotations

import json
import math
import struct

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from drivers.ardupilot.json_frames import (
    MAGIC_16,
    MAGIC_32,
    ChannelMap,
    FrameError,
    fdm_line,
    parse_servo_packet,
    surfaces_from_pwm,
)
from drivers.mocks.sitl_double import ContractError, SitlDouble
from hil_bridge.bus.messages import FdmState, fdm_truth
from sim_core.pose import quat_from_euler
from sim_core.sensors import SensorSpec, SensorSuite

G = 9.80665
u16 = st.integers(0, 65535)


@given(rate=u16, count=st.integers(0, 2**32 - 1), wide=st.booleans(), data=st.data())
def test_servo_packets_round_trip(rate: int, count: int, wide: bool, data: st.DataObject) -> None:
    n = 32 if wide else 16
    pwm = data.draw(st.lists(u16, min_size=n, max_size=n))
    raw = struct.pack(f"<HHI{n}H", MAGIC_32 if wide else MAGIC_16, rate, count, *pwm)
    pkt = parse_servo_packet(raw)
    assert (pkt.frame_rate, pkt.frame_count, list(pkt.pwm)) == (rate, count, pwm)
    with pytest.raises(FrameError, match="bytes"):
        parse_servo_packet(raw[: data.draw(st.integers(0, len(raw) - 1))])
    with pytest.raises(FrameError, match="bytes"):
        parse_servo_packet(raw + b"\0")


@given(magic=u16.filter(lambda m: m not in (MAGIC_16, MAGIC_32)))
def test_an_unknown_magic_is_refused(magic: int) -> None:
    with pytest.raises(FrameError, match=f"bad magic {magic}"):
        parse_servo_packet(struct.pack("<HHI16H", magic, 400, 1, *[1500] * 16))


def test_pwm_maps_like_ardupilots_jsbsim_backend() -> None:
    chans = ChannelMap()
    assert surfaces_from_pwm((1000, 2000, 1000, 1500), chans) == (-1.0, 1.0, 0.0, 0.0)
    assert surfaces_from_pwm((1750, 1250, 1500, 2000), chans) == (0.5, -0.5, 0.5, 1.0)
    assert surfaces_from_pwm((900, 2200, 2500, 0), chans) == (-1.0, 1.0, 1.0, 0.0)  # clipped
    assert surfaces_from_pwm((0, 0, 0, 0), chans) == (0.0, 0.0, 0.0, 0.0)  # not output
    rev = ChannelMap(reversed=("elevator", "throttle"))
    assert surfaces_from_pwm((1500, 1750, 1250, 1500), rev) == (0.0, -0.5, 0.75, 0.0)
    moved = ChannelMap(aileron=5, elevator=6, throttle=7, rudder=20)
    pwm = (1500,) * 4 + (2000, 1000, 2000) + (1500,) * 9
    assert surfaces_from_pwm(pwm, moved) == (1.0, -1.0, 1.0, 0.0)  # 20 beyond 16: neutral


def test_channel_map_rejects_clashes_and_unknown_names() -> None:
    with pytest.raises(ValueError, match="distinct"):
        ChannelMap(aileron=2)
    with pytest.raises(ValueError, match="flaps"):
        ChannelMap(reversed=("flaps",))


def _state(**kw: float) -> FdmState:
    base = dict(stamp_ns=2_500_000, glider_id=3, step=1, x=10.0, y=20.0, z=300.0, vx=0.0,
                vy=20.0, vz=-0.8, qw=1.0, qx=0.0, qy=0.0, qz=0.0, p=0.0, q=0.0, r=0.0, fx=0.0,
                fy=0.0, fz=G, airspeed=20.0)
    base.update(kw)
    return FdmState(**base)  # type: ignore[arg-type]


def line_of(state: FdmState) -> bytes | None:
    """``fdm_line`` with the noise-free sensor model's IMU, which must be the state's own."""
    imu = SensorSuite(SensorSpec(noise=False), 1).sample(state.stamp_ns, fdm_truth([state]))
    line = fdm_line(state, imu)
    assert line == fdm_line(state)  # what the node sends without noise, not sampling
    return line


def test_a_glider_flying_north_in_enu_is_north_in_ned() -> None:
    """ENU heading 90° (north) is yaw 0 in NED; position and velocity swap x/y and negate z;
    the accelerometer at rest reads -g on FRD z; FLU rates flip q and r."""
    q = quat_from_euler(0.0, 0.0, math.pi / 2)  # ENU-from-FLU facing north
    line = line_of(_state(qw=q[0], qx=q[1], qy=q[2], qz=q[3], p=0.1, q=0.2, r=0.3))
    assert line is not None and line.startswith(b"\n") and line.endswith(b"\n")
    doc = json.loads(line.split(b"\n")[-2])
    assert list(doc) == ["timestamp", "imu", "position", "quaternion", "velocity", "airspeed"]
    assert doc["timestamp"] == pytest.approx(0.0025)
    np.testing.assert_allclose(doc["position"], [20.0, 10.0, -300.0])
    np.testing.assert_allclose(doc["velocity"], [20.0, 0.0, 0.8])
    np.testing.assert_allclose(doc["imu"]["accel_body"], [0.0, 0.0, -G])
    np.testing.assert_allclose(doc["imu"]["gyro"], [0.1, -0.2, -0.3])
    np.testing.assert_allclose(doc["quaternion"], [1.0, 0.0, 0.0, 0.0], atol=1e-12)
    assert doc["airspeed"] == 20.0


def test_east_and_a_right_bank() -> None:
    """ENU yaw 0 faces east: NED yaw +90°. A right bank (right wing down) is a positive roll
    about the forward axis in FLU as in FRD."""
    q = quat_from_euler(0.3, 0.0, 0.0)
    doc = json.loads(line_of(_state(qw=q[0], qx=q[1], qy=q[2], qz=q[3])).split(b"\n")[-2])
    np.testing.assert_allclose(doc["quaternion"], quat_from_euler(0.3, 0.0, math.pi / 2),
                               atol=1e-12)


@pytest.mark.parametrize("field", ["x", "vz", "qw", "fz", "airspeed", "p"])
def test_a_non_finite_state_is_never_sent(field: str) -> None:
    assert line_of(_state(**{field: math.nan})) is None
    assert line_of(_state(**{field: math.inf})) is None


def test_the_double_accepts_our_lines_and_refuses_broken_ones() -> None:
    double = SitlDouble(port=9)
    try:
        line = line_of(_state())
        assert line is not None
        assert double.check(line)["airspeed"] == 20.0
        doc = json.loads(line.split(b"\n")[-2])
        broken = {
            "NaN": line.replace(b'"airspeed":20.0', b'"airspeed":NaN'),
            "order": b"\n" + json.dumps({k: doc[k] for k in ["timestamp", "imu", "velocity",
                                                             "position", "quaternion"]}).encode()
            + b"\n",
            "newline": line[:-1],
            "back": b"\n" + json.dumps({**doc, "timestamp": -1.0}).encode() + b"\n",
        }
        for what, data in broken.items():
            with pytest.raises(ContractError):
                double.check(data)
            assert what
    finally:
        double.close()
