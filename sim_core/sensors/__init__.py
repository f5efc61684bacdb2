"""sim_core.sensors: what a vehicle's sensors read, and what a sonar's echo says of range.

* :mod:`~sim_core.sensors.model`: :class:`SensorSuite`, an autopilot's IMU, barometer, pitot,
  magnetometer and GNSS (:mod:`~sim_core.sensors.gps`) read from a vehicle's truth, with
  seeded noise or none; the frames, units, noise and latency of each are in its docstring;
* :mod:`~sim_core.sensors.atmosphere`: the ISA (pressure, temperature, density; pressure
  altitude; dynamic pressure);
* :mod:`~sim_core.sensors.magnetic`: the WMM2025 field (``pygeomag``);
* :mod:`~sim_core.sensors.echo_range`: the echo → range rule every range finder of echoloop
  applies (the first return above a threshold, by time of flight).

Every firmware edge (ArduPilot's JSON, PX4's MAVLink HIL, DroneCAN) draws its sensors from
here; none computes physics of its own. May import numpy, scipy, :mod:`sim_core.pose`,
:mod:`sim_core.rng` and ``pygeomag``.
"""

from sim_core.sensors.atmosphere import (
    dynamic_pressure,
    equivalent_airspeed,
    isa,
    pressure_altitude,
)
from sim_core.sensors.echo_range import EchoRanges, RangeRule, echo_ranges
from sim_core.sensors.gps import GpsFix, GpsReceiver, GpsSpec
from sim_core.sensors.magnetic import WMM_VALID, field_enu
from sim_core.sensors.model import (
    ImuSpec,
    MagSpec,
    SensorReadings,
    SensorSpec,
    SensorSuite,
    SensorTruth,
)

__all__ = [
    "WMM_VALID",
    "EchoRanges",
    "GpsFix",
    "GpsReceiver",
    "GpsSpec",
    "ImuSpec",
    "MagSpec",
    "RangeRule",
    "SensorReadings",
    "SensorSpec",
    "SensorSuite",
    "SensorTruth",
    "dynamic_pressure",
    "echo_ranges",
    "equivalent_airspeed",
    "field_enu",
    "isa",
    "pressure_altitude",
]
