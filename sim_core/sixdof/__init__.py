"""sim_core.sixdof: 6-DoF gliders for firmware in the loop (JSBSim), flown in the scene's air.

A scene models only what it needs: swarms fly the point-mass :mod:`sim_core.flight`; a vehicle
a real autopilot flies (ArduPilot SITL, :mod:`drivers.ardupilot`) needs moments, control
surfaces and an IMU, which :class:`SixDofGliders` gives from JSBSim's aircraft models. The air
mass is the scene's: each step sets JSBSim's wind to the updraft the caller passes.

May import numpy, :mod:`sim_core.pose` and :mod:`jsbsim` (imported when gliders are built; the
aircraft definitions are JSBSim's package data, read by JSBSim itself).
"""

from sim_core.sixdof.model import (
    CONTROLS,
    GROUND_MARGIN_M,
    SixDofGliders,
    SixDofOutputs,
    SixDofSpec,
    enu_from_geodetic,
    geodetic_from_enu,
)
from sim_core.sixdof.polar import Glide, SoarPolar, fit_polar, measure_glides, polar_sink

__all__ = [
    "CONTROLS",
    "GROUND_MARGIN_M",
    "Glide",
    "SixDofGliders",
    "SixDofOutputs",
    "SixDofSpec",
    "SoarPolar",
    "enu_from_geodetic",
    "fit_polar",
    "geodetic_from_enu",
    "measure_glides",
    "polar_sink",
]
