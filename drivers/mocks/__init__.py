"""Device mocks: the sonar head (serial, spec §2) and the glider autopilot (CAN, spec §3).

Sonar head: ``sonar_head`` (``MockSonarHead``, the device's protocol state machine),
``sonar_head_config`` (its parameters); the
serial port it acts on and the pacing of each direction are :mod:`drivers.serial.device_port`.
Autopilot: ``autopilot`` (``MockAutopilot``, its controllers and heartbeats),
``profile_receiver`` (``ProfileReceiver``: what it knows of each glider, from the bridge's
frames), ``path_follower`` (``PathFollower``, the ``path`` controller), ``autopilot_cli``
(``echoloop mock autopilot``).

It may import :mod:`drivers.serial`, :mod:`drivers.can`, :mod:`drivers.faults`,
:mod:`hil_bridge` and :mod:`sim_core`; never :mod:`drivers.urlhandlers`. The host side never
imports it.
"""
