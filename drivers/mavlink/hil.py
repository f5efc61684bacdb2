"""PX4's simulator messages from echoloop's sensors, and its actuator controls to surfaces.

The contract is PX4's "Simulator MAVLink API" (``src/modules/simulation/simulator_mavlink``;
``docs/px4.md``). This module is the one place the HIL edge's frames and units are converted:
echoloop's readings are body FLU and world ENU in SI units (:mod:`sim_core.sensors`); PX4
reads body FRD and NED, pressures in hPa, GNSS in 1e-7 degrees, millimetres and cm/s.

* :func:`hil_sensor`: ``HIL_SENSOR`` — specific force m/s² and rates rad/s (FRD), field gauss
  (FRD), ``abs_pressure`` and ``diff_pressure`` hPa, ``pressure_alt`` m, ``temperature`` °C,
  ``fields_updated`` = 0x1FFF (accel 0-2, gyro 3-5, mag 6-8, pressure 9, differential
  pressure 10, pressure altitude 11, temperature 12: PX4 takes a group only when all its bits
  are set), ``id`` 0 (the instance whose ``time_usec`` sets PX4's clock in lockstep);
* :func:`hil_gps`: ``HIL_GPS`` — a 3-D fix: lat/lon 1e-7°, alt mm (MSL), eph/epv cm,
  ground speed, vn/ve/vd cm/s, course over ground c°;
* :func:`hil_state_quaternion`: ``HIL_STATE_QUATERNION`` — the truth, for PX4's ground-truth
  log topics: attitude (NED from FRD), rates FRD, position, NED velocity cm/s, indicated and
  true airspeed cm/s, specific force mG;
* :func:`surfaces_from_controls`: ``HIL_ACTUATOR_CONTROLS.controls`` (normalised: -1..1,
  throttle 0..1) to JSBSim's surfaces through an :class:`ActuatorMap`.

An integer field whose value does not fit its type is clipped to the type's range (counted
by the caller: :data:`Clip`); a message with a non-finite input is never built (None).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from drivers.mavlink.link import mavlink
from hil_bridge.bus.messages import FdmState
from sim_core.pose import frd_from_flu, ned_from_enu, quat_ned_frd_from_enu_flu
from sim_core.sensors import GpsFix, SensorReadings, equivalent_airspeed
from sim_core.sensors.atmosphere import G0

__all__ = ["FIELDS_ALL", "ActuatorMap", "Clip", "hil_gps", "hil_sensor",
           "hil_state_quaternion", "surfaces_from_controls"]

#: HIL_SENSOR.fields_updated with every field (accel, gyro, mag, pressures, altitude, temp)
FIELDS_ALL = 0x1FFF
#: :func:`sim_core.pose.frd_from_flu` of three body vectors in a row, as factors (9,)
_FRD_OF_FLU_3X3 = frd_from_flu(np.ones((3, 3))).ravel()


class Clip:
    """Counts the integer fields clipped to their type's range."""

    def __init__(self) -> None:
        self.count = 0

    def __call__(self, value: float, lo: int, hi: int) -> int:
        v = round(value)
        if v < lo or v > hi:
            self.count += 1
            return lo if v < lo else hi
        return int(v)


def hil_sensor(time_usec: int, r: SensorReadings, k: int = 0, sensor_id: int = 0) -> Any | None:
    """``HIL_SENSOR`` of vehicle row ``k`` of ``r`` at ``time_usec`` (sim time), or None."""
    row = r.table[k]
    p, q, alt, temp = row[9:13].tolist()
    v = [*(row[:9] * _FRD_OF_FLU_3X3).tolist(), p / 100.0, q / 100.0, alt, temp]
    if not math.isfinite(sum(v)):  # a NaN or an infinity anywhere makes the sum one
        return None
    return mavlink.MAVLink_hil_sensor_message(time_usec, *v, FIELDS_ALL, sensor_id)


def hil_gps(time_usec: int, fix: GpsFix, clip: Clip, k: int = 0, gps_id: int = 0) -> Any | None:
    """``HIL_GPS`` of vehicle row ``k`` of ``fix`` at ``time_usec`` (when reported), or None."""
    lat, lon, alt = float(fix.lat_deg[k]), float(fix.lon_deg[k]), float(fix.alt_m[k])
    vn, ve, vd = ned_from_enu(fix.velocity[k]).tolist()
    if not math.isfinite(lat + lon + alt + vn + ve + vd):
        return None
    ground = math.hypot(vn, ve)
    cog = math.degrees(math.atan2(ve, vn)) % 360.0
    return mavlink.MAVLink_hil_gps_message(
        time_usec, 3, clip(lat * 1e7, -900_000_000, 900_000_000),
        clip(lon * 1e7, -1_800_000_000, 1_800_000_000), clip(alt * 1e3, -2**31, 2**31 - 1),
        clip(fix.eph_m * 100.0, 0, 65534), clip(fix.epv_m * 100.0, 0, 65534),
        clip(ground * 100.0, 0, 65534), clip(vn * 100.0, -32767, 32767),
        clip(ve * 100.0, -32767, 32767), clip(vd * 100.0, -32767, 32767),
        clip(cog * 100.0, 0, 35999), fix.satellites, gps_id, 0)


def hil_state_quaternion(time_usec: int, s: FdmState, r: SensorReadings, clip: Clip,
                         k: int = 0) -> Any | None:
    """``HIL_STATE_QUATERNION`` (the truth) of one 6-DoF state, its indicated airspeed from
    the ISA density of readings row ``k``, or None."""
    q = quat_ned_frd_from_enu_flu([s.qw, s.qx, s.qy, s.qz]).tolist()
    rates_force = frd_from_flu(np.array([[s.p, s.q, s.r], [s.fx, s.fy, s.fz]])).ravel().tolist()
    vn, ve, vd = ned_from_enu(np.array([s.vx, s.vy, s.vz])).tolist()
    ias = float(equivalent_airspeed(s.airspeed, r.table[k, 13]))
    if not math.isfinite(sum((*q, *rates_force, vn, ve, vd, s.lat, s.lon, s.alt, s.airspeed,
                              ias))):
        return None
    p, qr, rr, fx, fy, fz = rates_force
    mg = 1000.0 / G0
    return mavlink.MAVLink_hil_state_quaternion_message(
        time_usec, q, p, qr, rr, clip(s.lat * 1e7, -900_000_000, 900_000_000),
        clip(s.lon * 1e7, -1_800_000_000, 1_800_000_000), clip(s.alt * 1e3, -2**31, 2**31 - 1),
        clip(vn * 100.0, -32767, 32767), clip(ve * 100.0, -32767, 32767),
        clip(vd * 100.0, -32767, 32767), clip(ias * 100.0, 0, 65535),
        clip(s.airspeed * 100.0, 0, 65535), clip(fx * mg, -32767, 32767),
        clip(fy * mg, -32767, 32767), clip(fz * mg, -32767, 32767))


@dataclass(frozen=True, slots=True)
class ActuatorMap:
    """Which of the 16 controls make roll, pitch, yaw and throttle, each a sum of ``[index,
    weight]`` pairs, in PX4's senses: roll + rolls right, pitch + pitches up, yaw + yaws right
    (-1..1), throttle 0..1. The default is PX4's fixed-wing order (0 roll, 1 pitch, 2 yaw,
    3 throttle); an airframe with split ailerons on outputs 5 and 6, say, gives
    ``roll: [[5, 0.5], [6, -0.5]]`` with the signs of its servos."""

    roll: tuple[tuple[int, float], ...] = ((0, 1.0),)
    pitch: tuple[tuple[int, float], ...] = ((1, 1.0),)
    yaw: tuple[tuple[int, float], ...] = ((2, 1.0),)
    throttle: tuple[tuple[int, float], ...] = ((3, 1.0),)

    def __post_init__(self) -> None:
        for name in ("roll", "pitch", "yaw", "throttle"):
            for index, weight in getattr(self, name):
                if not 0 <= index < 16 or not math.isfinite(weight):
                    raise ValueError(f"actuators.{name}: expected [index 0..15, finite weight] "
                                     f"pairs, got {[index, weight]}")


def surfaces_from_controls(controls: Sequence[float], amap: ActuatorMap
                           ) -> tuple[float, float, float, float] | None:
    """JSBSim's ``(aileron, elevator, throttle, rudder)`` (:data:`sim_core.sixdof.CONTROLS`
    order) from 16 controls, or None when a control used is not finite. JSBSim's signs:
    aileron + rolls right, elevator + pitches down, rudder + yaws left."""
    roll = sum([w * controls[i] for i, w in amap.roll])
    pitch = sum([w * controls[i] for i, w in amap.pitch])
    yaw = sum([w * controls[i] for i, w in amap.yaw])
    thr = sum([w * controls[i] for i, w in amap.throttle])
    if not math.isfinite(roll + pitch + yaw + thr):
        return None
    return (min(max(roll, -1.0), 1.0), -min(max(pitch, -1.0), 1.0), min(max(thr, 0.0), 1.0),
            -min(max(yaw, -1.0), 1.0))
