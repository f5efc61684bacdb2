"""The DroneCAN node's parts: CAN over UDP multicast, the allocatee's state machine against the
protocol's allocator, and the messages' frames, units and rounding."""

from __future__ import annotations

import math
import random
import struct

import dronecan
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from drivers.dronecan.allocation import Allocatee
from drivers.dronecan.interfaces import open_can
from drivers.dronecan.mcast import MCAST_PORT, McastDriver
from drivers.dronecan.messages import (
    FLOAT16_STEP,
    ServoMap,
    fix2,
    measurement,
    surfaces_from_array,
    surfaces_from_esc,
)
from sim_core.sensors import GpsFix

uc = dronecan.uavcan.equipment


@settings(max_examples=300, deadline=None)
@given(st.binary(max_size=80))
def test_the_datagram_crc_is_the_package_s(data: bytes) -> None:
    from dronecan.dsdl.common import crc16_from_bytes

    from drivers.dronecan.mcast import _crc

    assert _crc(data) == crc16_from_bytes(data)


def test_mcast_frames_cross_and_noise_is_counted() -> None:
    a, b, other = McastDriver(201), McastDriver(201), McastDriver(202)
    try:
        a.send(0x1ABCDE, b"\x01\x02\x03", extended=True)
        f = b.receive(2.0)
        assert f is not None and f.id == 0x1ABCDE and f.extended
        assert bytes(f.data) == b"\x01\x02\x03"
        assert a.receive(0.05) is None  # its own frame does not come back
        assert other.receive(0.05) is None  # another bus
        import socket

        s = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        s.setsockopt(socket.IPPROTO_IP, socket.IP_MULTICAST_TTL, 0)
        for junk in (b"short", struct.pack("<HHHI", 0x1234, 0, 0, 5), struct.pack(
                "<HHHI", 0x2934, 0xBEEF, 0, 5) + b"\x00"):
            s.sendto(junk, ("239.65.82.201", MCAST_PORT))
        s.close()
        a.send(7, b"", extended=False)
        f = b.receive(2.0)
        assert f is not None and f.id == 7 and not f.extended
        assert b.counts["bad_datagrams"] == 3
    finally:
        for d in (a, b, other):
            d.close()


def test_interfaces_by_url() -> None:
    d = open_can("mcast:203")
    d.close()
    with pytest.raises(ValueError, match="unknown scheme 'carrier'"):
        open_can("carrier:pigeon")
    with pytest.raises(ValueError, match="mcast:N"):
        open_can("mcast:x")


class _Allocator:
    """The allocator's side as the protocol specifies it (and the dronecan package's
    CentralizedServer does): echo each stage, grant on the last."""

    def __init__(self, grant: int) -> None:
        self.query = b""
        self.grant = grant

    def on_request(self, first: bool, uid: bytes) -> tuple[int, bytes]:
        if first:
            self.query = uid
        elif (len(uid) == 6 and len(self.query) == 6) or (len(uid) == 4 and len(self.query) == 12):
            self.query += uid
        return (self.grant if len(self.query) == 16 else 0), self.query


def test_the_allocatee_is_given_an_id_in_three_stages() -> None:
    uid = bytes(range(16))
    a = Allocatee(uid, 42, rng=random.Random(1), now=0.0)
    server = _Allocator(42)
    t, sent = 0.0, []
    while a.node_id is None and t < 10.0:
        t += 0.01
        req = a.poll(t)
        if req is not None:
            sent.append(req)
            a.on_message(*server.on_request(req.first_part, req.unique_id), t + 0.005)
    assert a.node_id == 42 and len(sent) == 3
    assert [len(r.unique_id) for r in sent] == [6, 6, 4] and sent[0].first_part
    assert all(r.node_id == 42 for r in sent)


def test_a_stranger_s_echo_or_silence_starts_again() -> None:
    a = Allocatee(bytes(16), rng=random.Random(2), now=0.0)
    t = 0.0
    while (req := a.poll(t)) is None:
        t += 0.01
    a.on_message(0, bytes(6), t)
    a.on_message(0, b"\xff" * 12, t + 0.01)  # another allocatee's conversation
    assert a.restarts == 1
    while (req := a.poll(t)) is None:
        t += 0.01
    assert req.first_part
    a.on_message(0, bytes(6), t)
    t += 0.6  # no follow-up answer within 500 ms
    while (req := a.poll(t)) is None:
        t += 0.01
    assert a.restarts == 2 and req.first_part


@settings(max_examples=200, deadline=None)
@given(st.floats(0.2, 10.0))
def test_measurement_ranges_are_float16_within_their_step(r: float) -> None:
    m = measurement(7, 3, r, np.array([0.0, 0.0, -1.0]), min_m=0.2, max_m=10.0, fov_rad=0.7)
    assert m.reading_type == m.READING_TYPE_VALID_RANGE
    assert abs(m.range - r) <= FLOAT16_STEP(r) / 2 + 1e-12
    assert list(m.beam_orientation_in_body_frame.fixed_axis_roll_pitch_yaw) == [0, -8, 0]


def test_too_far_and_too_close() -> None:
    far = measurement(0, 1, math.nan, np.array([1.0, 0, 0]), min_m=0.2, max_m=10.0, fov_rad=0)
    near = measurement(0, 1, 0.1, np.array([1.0, 0, 0]), min_m=0.2, max_m=10.0, fov_rad=0)
    assert (far.reading_type, far.range) == (far.READING_TYPE_TOO_FAR, 10.0)
    assert near.reading_type == near.READING_TYPE_TOO_CLOSE
    assert near.range == pytest.approx(0.2, abs=FLOAT16_STEP(0.2))


@pytest.mark.parametrize("axis", [[0.0, 0.0, 0.0], [math.nan, 0.0, 1.0], [math.inf, 0.0, 0.0]])
def test_an_axis_without_a_direction_leaves_the_orientation_undefined(axis: list[float]) -> None:
    m = measurement(0, 1, 2.0, np.array(axis), min_m=0.2, max_m=10.0, fov_rad=0)
    assert not m.beam_orientation_in_body_frame.orientation_defined
    assert m.reading_type == m.READING_TYPE_VALID_RANGE


def _cmd(actuator: int, value: float, kind: int = 0) -> object:
    return uc.actuator.Command(actuator_id=actuator, command_type=kind, command_value=value)


def test_commands_to_surfaces() -> None:
    smap = ServoMap()
    held = (0.0, 0.0, 0.0, 0.0)
    out = surfaces_from_array([_cmd(1, 0.5), _cmd(2, -0.25), _cmd(3, 0.0), _cmd(9, 1.0)],
                              smap, held)
    assert out == pytest.approx((0.5, -0.25, 0.5, 0.0))  # throttle (v + 1)/2; 9: no surface
    pwm = surfaces_from_array([_cmd(4, 1750.0, 4)], ServoMap(reversed=("rudder",)), held)
    assert pwm == pytest.approx((0.0, 0.0, 0.0, -0.5))
    assert surfaces_from_array([_cmd(1, 1.0, 2)], smap, held) is None  # a force: not ours
    assert surfaces_from_esc([8191, 0], smap, held)[2] == 1.0
    assert surfaces_from_esc([], smap, held) == held
    with pytest.raises(ValueError, match="distinct"):
        ServoMap(elevator=1)


def test_fix2_scales() -> None:
    fix = GpsFix(t_ns=0, measured_ns=0, lat_deg=np.array([47.1234567]),
                 lon_deg=np.array([8.7654321]), alt_m=np.array([432.1]),
                 velocity=np.array([[3.0, 4.0, -0.5]]), eph_m=1.0, epv_m=1.5, satellites=11)
    m = fix2(9, fix)
    assert (m.latitude_deg_1e8, m.longitude_deg_1e8) == (4712345670, 876543210)
    assert m.height_msl_mm == 432100 and m.status == m.STATUS_3D_FIX and m.sats_used == 11
    np.testing.assert_allclose(list(m.ned_velocity), [4.0, 3.0, 0.5])
    np.testing.assert_allclose(list(m.covariance)[:3], [1.0, 1.0, 2.25], rtol=1e-3)
