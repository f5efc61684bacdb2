"""Device mocks: the sonar head (serial, spec §2) and the glider autopilot (CAN, spec §3)."""
