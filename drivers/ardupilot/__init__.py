"""drivers.ardupilot: ArduPilot firmware in the loop through SITL's JSON physics interface.

* :mod:`drivers.ardupilot.json_frames`: the wire (servo packets in, JSON state lines out) and
  the one place echoloop's ENU/FLU states become SITL's NED/FRD;
* :mod:`drivers.ardupilot.sitl`: :class:`~drivers.ardupilot.sitl.ArduPilotSitl`, the launchable
  node serving one or more SITL instances, each flying a 6-DoF vehicle of the scene.

It may import :mod:`hil_bridge` and :mod:`sim_core`; it knows nothing of the other drivers or of
the protocol double (:mod:`drivers.mocks.sitl_double`) that stands in for SITL in tests.
"""
