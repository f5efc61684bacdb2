"""Device mocks: the sonar head (serial, spec §2) and the glider autopilot (CAN, spec §3).

Sonar head: ``sonar_head`` (``MockSonarHead``, the device's protocol state machine),
``sonar_head_config`` (its parameters), ``device_port`` (the serial port it acts on and the pacing
of each direction to the baud rate), ``echo_range`` (its first-return range estimate).
Autopilot: ``autopilot`` (``MockAutopilot``), ``autopilot_cli`` (``echoloop mock autopilot``).
"""
