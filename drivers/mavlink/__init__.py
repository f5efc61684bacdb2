"""drivers.mavlink: stock autopilots in the loop over MAVLink.

* :mod:`~drivers.mavlink.link`: MAVLink links from a URL (TCP either end, UDP, serial), one
  small ABC and its backends;
* :mod:`~drivers.mavlink.hil`: PX4's simulator messages (``HIL_SENSOR``, ``HIL_GPS``,
  ``HIL_STATE_QUATERNION``) from echoloop's sensors and ``HIL_ACTUATOR_CONTROLS`` to control
  surfaces: the one place this edge turns ENU/FLU into NED/FRD;
* :mod:`~drivers.mavlink.ranges`: echoes as ``DISTANCE_SENSOR`` and ``OBSTACLE_DISTANCE``;
* :mod:`~drivers.mavlink.px4`: :class:`~drivers.mavlink.px4.Px4Hil`, the launchable PX4 HIL
  node (SITL over TCP, HITL over USB serial);
* :mod:`~drivers.mavlink.rangefinder`: :class:`~drivers.mavlink.rangefinder.MavlinkRangefinder`,
  the launchable node feeding echo ranges to any MAVLink autopilot (ArduPilot's ``RNGFND``
  type 10, ``PRX`` type 2).

It may import :mod:`hil_bridge` and :mod:`sim_core`; it knows nothing of the other drivers or
of the protocol double (:mod:`drivers.mocks.px4_double`) that stands in for PX4 in tests.
Sensor physics comes from :mod:`sim_core.sensors`; nothing here computes any.
"""
