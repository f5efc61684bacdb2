"""ArduPilot SITL's JSON physics interface: servo packets in, state lines out.

The contract is ArduPilot's ``libraries/SITL/SIM_JSON.cpp`` (``docs/ardupilot.md``). SITL
(``--model JSON:<host>``) sends a little-endian servo packet to UDP port 9002 + 10·instance
for every physics frame: ``<HHI16H`` (magic 18458, frame_rate, frame_count, 16 PWM µs) or, with
``SERVO_32_ENABLE``, ``<HHI32H`` (magic 29569). The simulator answers each with one JSON object
framed by newlines (SITL reads the text between the last two): ``timestamp`` s, ``imu.gyro``
rad/s and ``imu.accel_body`` m/s² (body FRD, specific force: about [0, 0, -9.81] at rest),
``position`` m and ``velocity`` m/s (NED from home), ``quaternion`` [w, x, y, z] (NED from
FRD), and ``airspeed`` m/s (without it SITL assumes still air). Keys go in that order.

This module is the one place the edge's frames are converted: echoloop's states are ENU/FLU
(:class:`hil_bridge.bus.messages.FdmState`), SITL's NED/FRD. A noisy IMU comes from echoloop's
sensor model (:class:`sim_core.sensors.SensorSuite`), like every other firmware edge's.
"""

from __future__ import annotations

import json
import math
import struct
from dataclasses import dataclass

import numpy as np

from hil_bridge.bus.messages import FdmState
from sim_core.pose import frd_from_flu, ned_from_enu, quat_ned_frd_from_enu_flu
from sim_core.sensors import SensorReadings

__all__ = [
    "MAGIC_16",
    "MAGIC_32",
    "ChannelMap",
    "FrameError",
    "ServoPacket",
    "fdm_line",
    "parse_servo_packet",
    "surfaces_from_pwm",
]

MAGIC_16 = 18458
MAGIC_32 = 29569
_HEADER = struct.Struct("<HHI")
_SIZES = {MAGIC_16: _HEADER.size + 2 * 16, MAGIC_32: _HEADER.size + 2 * 32}


class FrameError(ValueError):
    """A datagram that is not a servo packet (wrong magic or size)."""


@dataclass(frozen=True, slots=True)
class ServoPacket:
    """One servo packet: ``frame_rate`` Hz SITL asks for, its ``frame_count``, ``pwm`` µs."""

    magic: int
    frame_rate: int
    frame_count: int
    pwm: tuple[int, ...]


def parse_servo_packet(data: bytes) -> ServoPacket:
    """The servo packet in ``data``; :class:`FrameError` naming what is wrong otherwise."""
    if len(data) < _HEADER.size:
        raise FrameError(f"short servo packet: {len(data)} bytes")
    magic, rate, count = _HEADER.unpack_from(data)
    size = _SIZES.get(magic)
    if size is None:
        raise FrameError(f"bad magic {magic} (expected {MAGIC_16} or {MAGIC_32})")
    if len(data) != size:
        raise FrameError(f"servo packet with magic {magic}: {len(data)} bytes, expected {size}")
    n = (size - _HEADER.size) // 2
    return ServoPacket(magic, rate, count, struct.unpack_from(f"<{n}H", data, _HEADER.size))


@dataclass(frozen=True, slots=True)
class ChannelMap:
    """Which servo channel (1-based) drives which surface, and which are reversed. ArduPlane's
    defaults: 1 aileron, 2 elevator, 3 throttle, 4 rudder."""

    aileron: int = 1
    elevator: int = 2
    throttle: int = 3
    rudder: int = 4
    reversed: tuple[str, ...] = ()

    def __post_init__(self) -> None:
        chans = (self.aileron, self.elevator, self.throttle, self.rudder)
        if any(not 1 <= c <= 32 for c in chans) or len(set(chans)) != 4:
            raise ValueError(f"channels: expected four distinct channels in 1..32, got "
                             f"{list(chans)}")
        bad = sorted(set(self.reversed) - {"aileron", "elevator", "throttle", "rudder"})
        if bad:
            raise ValueError(f"reversed: unknown surface(s) {bad}; expected aileron, elevator, "
                             "throttle or rudder")


def surfaces_from_pwm(pwm: tuple[int, ...], channels: ChannelMap) -> tuple[float, ...]:
    """``(aileron, elevator, throttle, rudder)`` from PWM µs as ArduPilot's JSBSim backend maps
    them: (pwm − 1500)/500 in [-1, 1], throttle (pwm − 1000)/1000 in [0, 1]; a channel that is
    0 (not output) or beyond the packet is neutral (0)."""
    out = []
    for name in ("aileron", "elevator", "throttle", "rudder"):
        ch = getattr(channels, name)
        p = pwm[ch - 1] if ch <= len(pwm) else 0
        if p == 0:
            out.append(0.0)
            continue
        if name == "throttle":
            v = min(max((p - 1000) / 1000.0, 0.0), 1.0)
            out.append(1.0 - v if name in channels.reversed else v)
        else:
            v = min(max((p - 1500) / 500.0, -1.0), 1.0)
            out.append(-v if name in channels.reversed else v)
    return tuple(out)


def fdm_line(state: FdmState, imu: SensorReadings | None = None, k: int = 0) -> bytes | None:
    """The JSON line SITL reads for ``state`` (newline before and after), its IMU (rates and
    specific force) from row ``k`` of the sensor model's readings ``imu`` (None: the state's
    own, which is what the model reads without noise), or None when a value is not finite
    (SITL must never be sent a NaN)."""
    flu = imu.table[k, :6].tolist() if imu is not None else [
        state.fx, state.fy, state.fz, state.p, state.q, state.r]
    values = [state.x, state.y, state.z, state.vx, state.vy, state.vz, *flu]
    quat_in = [state.qw, state.qx, state.qy, state.qz]
    if not all(map(math.isfinite, [*values, *quat_in, state.airspeed])):
        return None
    rows = np.array(values).reshape(4, 3)  # position, velocity (ENU); specific force, rates
    pos, vel = ned_from_enu(rows[:2]).tolist()
    accel, gyro = frd_from_flu(rows[2:]).tolist()
    doc = {
        "timestamp": state.stamp_ns / 1e9,
        "imu": {"gyro": gyro, "accel_body": accel},
        "position": pos,
        "quaternion": quat_ned_frd_from_enu_flu(quat_in).tolist(),
        "velocity": vel,
        "airspeed": float(state.airspeed),
    }
    return b"\n" + json.dumps(doc, separators=(",", ":")).encode() + b"\n"
