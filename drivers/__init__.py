"""drivers: the hardware edge (serial sonar head, CAN glider autopilot) and their device mocks."""
