"""Device mocks: the sonar head (serial, spec §2) and the glider autopilot (CAN, spec §3).

Sonar head: ``sonar_head`` (``MockSonarHead``, the device's protocol state machine),
``sonar_head_config`` (its parameters), ``echo_range`` (its first-return range estimate); the
serial port it acts on and the pacing of each direction are :mod:`drivers.serial.device_port`.
Autopilot: ``autopilot`` (``MockAutopilot``), ``autopilot_cli`` (``echoloop mock autopilot``).
"""
