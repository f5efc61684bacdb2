"""DroneCAN messages of echoloop's sensors and echo ranges, and actuator commands to surfaces.

The data types are the ``dronecan`` package's DSDL (``uavcan.equipment.*``); this module fills
them, and is the one place this edge turns echoloop's frames (ENU, FLU) into DroneCAN's (NED,
FRD):

* :func:`measurement`: ``uavcan.equipment.range_sensor.Measurement`` of one ear's range
  (:mod:`sim_core.sensors.echo_range`): ``VALID_RANGE`` with the range, ``TOO_CLOSE`` with
  the minimum below it, ``TOO_FAR`` with the maximum where the echo has no return in reach;
  ``sensor_type`` sonar; ``field_of_view`` rad; the beam's axis as a coarse orientation in
  the body (yaw and pitch in 12° steps, ``ANGLE_MULTIPLIER``). ``range`` is a float16: 11
  significant bits, so a range is a multiple of 2⁻¹⁰ m (0.98 mm) from 1 to 2 m, 2⁻⁹ m
  (1.95 mm) from 2 to 4 m, 2⁻⁸ m (3.9 mm) from 4 to 8 m and 2⁻⁷ m (7.8 mm) from 8 to 16 m,
  rounded to the nearest (an error of at most half that step);
* :func:`raw_air_data`, :func:`static_pressure`, :func:`static_temperature`: the pitot and
  barometer (Pa, K);
* :func:`fix2`: ``uavcan.equipment.gnss.Fix2``, a 3-D fix (1e-8°, mm, NED m/s, its
  covariance's diagonal from the receiver's eph, epv);
* :func:`surfaces_from_array` and :func:`surfaces_from_esc`: ``actuator.ArrayCommand``
  (``UNITLESS`` [-1, 1] or ``PWM`` µs, by ``actuator_id``) and ``esc.RawCommand`` (0..8191)
  to JSBSim's surfaces through a :class:`ServoMap` (ArduPilot's servo order by default).
"""

from __future__ import annotations

import math
from collections.abc import Iterable
from dataclasses import dataclass
from typing import Any

import dronecan
import numpy as np

from sim_core.pose import frd_from_flu, ned_from_enu
from sim_core.sensors import GpsFix, SensorReadings

__all__ = ["FLOAT16_STEP", "ServoMap", "fix2", "measurement", "raw_air_data", "static_pressure",
           "static_temperature", "surfaces_from_array", "surfaces_from_esc"]

uavcan: Any = dronecan.uavcan
_M = uavcan.equipment.range_sensor.Measurement


def FLOAT16_STEP(x: float) -> float:  # noqa: N802 - a constant of the format, as a function
    """The float16 spacing at ``x``: what a DroneCAN ``range`` of ``x`` m is rounded to."""
    return float(np.spacing(np.float16(abs(x))))


def _coarse(o: Any, axis_flu: np.ndarray) -> None:
    """Fill the coarse orientation ``o`` with the beam axis (FLU body); an axis that is not
    finite or has no length leaves the orientation undefined."""
    norm = float(np.linalg.norm(axis_flu))
    if not (math.isfinite(norm) and norm > 0.0):
        o.orientation_defined = False
        return
    x, y, z = (float(v) for v in frd_from_flu(axis_flu / norm))
    yaw = math.atan2(y, x)
    pitch = -math.asin(max(-1.0, min(1.0, z)))  # FRD: a beam down is pitched -90°
    k = o.ANGLE_MULTIPLIER
    o.fixed_axis_roll_pitch_yaw = [0, max(-16, min(15, round(pitch * k))),
                                   max(-16, min(15, round(yaw * k)))]
    o.orientation_defined = True


def measurement(t_us: int, sensor_id: int, range_m: float, axis_flu: np.ndarray, *,
                min_m: float, max_m: float, fov_rad: float, into: Any = None) -> Any:
    """One ear's ``Measurement`` (module docstring); ``range_m`` NaN: no return. ``into``: a
    ``Measurement`` to fill again (a DSDL object costs more to make than to fill)."""
    m = _M() if into is None else into
    m.timestamp.usec = int(t_us)
    m.sensor_id = int(sensor_id)
    _coarse(m.beam_orientation_in_body_frame, np.asarray(axis_flu, dtype=np.float64))
    m.field_of_view = float(fov_rad)
    m.sensor_type = m.SENSOR_TYPE_SONAR
    if not math.isfinite(range_m) or range_m > max_m:
        m.reading_type, m.range = m.READING_TYPE_TOO_FAR, float(max_m)
    elif range_m < min_m:
        m.reading_type, m.range = m.READING_TYPE_TOO_CLOSE, float(min_m)
    else:
        m.reading_type, m.range = m.READING_TYPE_VALID_RANGE, float(range_m)
    return m


def raw_air_data(r: SensorReadings, k: int = 0) -> Any | None:
    """The pitot (and the static port beside it) of readings row ``k``, or None."""
    p, q, t = float(r.abs_pressure[k]), float(r.diff_pressure[k]), float(r.temperature[k])
    if not math.isfinite(p + q + t):
        return None
    m = uavcan.equipment.air_data.RawAirData()
    m.static_pressure, m.differential_pressure = p, q
    m.static_air_temperature = t + 273.15
    m.static_pressure_sensor_temperature = m.differential_pressure_sensor_temperature = t + 273.15
    m.pitot_temperature = float("nan")
    return m


def static_pressure(r: SensorReadings, k: int = 0, sigma_pa: float = 1.0) -> Any | None:
    """The barometer of readings row ``k`` (Pa, variance ``sigma_pa``²), or None."""
    p = float(r.abs_pressure[k])
    if not math.isfinite(p):
        return None
    m = uavcan.equipment.air_data.StaticPressure()
    m.static_pressure, m.static_pressure_variance = p, sigma_pa * sigma_pa
    return m


def static_temperature(r: SensorReadings, k: int = 0) -> Any | None:
    """The outside air temperature of readings row ``k`` (K, variance 1 K²), or None."""
    t = float(r.temperature[k])
    if not math.isfinite(t):
        return None
    m = uavcan.equipment.air_data.StaticTemperature()
    m.static_temperature, m.static_temperature_variance = t + 273.15, 1.0
    return m


def fix2(t_us: int, fix: GpsFix, k: int = 0, sigma_v: float = 0.05) -> Any | None:
    """A 3-D ``Fix2`` of receiver row ``k``, or None when a value is not finite."""
    lat, lon, alt = float(fix.lat_deg[k]), float(fix.lon_deg[k]), float(fix.alt_m[k])
    v = ned_from_enu(fix.velocity[k]).tolist()
    if not math.isfinite(lat + lon + alt + sum(v)):
        return None
    m = uavcan.equipment.gnss.Fix2()
    m.timestamp.usec = m.gnss_timestamp.usec = int(t_us)
    m.gnss_time_standard = m.GNSS_TIME_STANDARD_NONE
    m.longitude_deg_1e8 = round(lon * 1e8)
    m.latitude_deg_1e8 = round(lat * 1e8)
    m.height_ellipsoid_mm = m.height_msl_mm = round(alt * 1e3)
    m.ned_velocity = v
    m.sats_used = int(fix.satellites)
    m.status, m.mode = m.STATUS_3D_FIX, m.MODE_SINGLE
    m.covariance = [fix.eph_m ** 2, fix.eph_m ** 2, fix.epv_m ** 2] + [sigma_v ** 2] * 3
    m.pdop = 1.0
    return m


@dataclass(frozen=True, slots=True)
class ServoMap:
    """Which actuator (``ArrayCommand.actuator_id``, 1-based as ArduPilot numbers its servos)
    drives which surface, which are reversed, and which ESC index (``RawCommand.cmd``, 0-based)
    is the throttle. ArduPilot's defaults: 1 aileron, 2 elevator, 3 throttle, 4 rudder; a value
    is ArduPilot's ``(pwm − 1000)/500 − 1``, so the servo-output reversals of a JSON SITL
    (``SERVO2_REVERSED``, ``SERVO4_REVERSED``) carry over unchanged."""

    aileron: int = 1
    elevator: int = 2
    throttle: int = 3
    rudder: int = 4
    reversed: tuple[str, ...] = ()
    esc_throttle: int = 0

    def __post_init__(self) -> None:
        ids = (self.aileron, self.elevator, self.throttle, self.rudder)
        if any(not 1 <= i <= 255 for i in ids) or len(set(ids)) != 4:
            raise ValueError(f"actuators: expected four distinct actuator ids 1..255, got "
                             f"{list(ids)}")
        bad = sorted(set(self.reversed) - {"aileron", "elevator", "throttle", "rudder"})
        if bad:
            raise ValueError(f"reversed: unknown surface(s) {bad}; expected aileron, elevator, "
                             "throttle or rudder")
        if not 0 <= self.esc_throttle < 20:
            raise ValueError(f"esc_throttle: expected 0..19, got {self.esc_throttle}")


def surfaces_from_array(commands: Iterable[Any], smap: ServoMap,
                        held: tuple[float, float, float, float]
                        ) -> tuple[float, float, float, float] | None:
    """``held`` (aileron, elevator, throttle, rudder) with the surfaces ``commands`` set
    (unitless [-1, 1] or PWM µs; throttle as [0, 1]); None when a command named is not
    finite or of another type."""
    out = list(held)
    slots = {smap.aileron: 0, smap.elevator: 1, smap.throttle: 2, smap.rudder: 3}
    names = ("aileron", "elevator", "throttle", "rudder")
    for c in commands:
        slot = slots.get(int(c.actuator_id))
        if slot is None:
            continue
        v = float(c.command_value)
        if int(c.command_type) == c.COMMAND_TYPE_PWM:
            v = (v - 1500.0) / 500.0
        elif int(c.command_type) != c.COMMAND_TYPE_UNITLESS:
            return None
        if not math.isfinite(v):
            return None
        v = min(max(v, -1.0), 1.0)
        if names[slot] in smap.reversed:
            v = -v
        out[slot] = (v + 1.0) / 2.0 if slot == 2 else v
    return out[0], out[1], out[2], out[3]


def surfaces_from_esc(cmd: Iterable[int], smap: ServoMap,
                      held: tuple[float, float, float, float]
                      ) -> tuple[float, float, float, float]:
    """``held`` with the throttle of ``RawCommand.cmd[esc_throttle]`` (0..8191 → 0..1)."""
    values = list(cmd)
    if smap.esc_throttle >= len(values):
        return held
    thr = min(max(int(values[smap.esc_throttle]) / 8191.0, 0.0), 1.0)
    return held[0], held[1], thr, held[3]
