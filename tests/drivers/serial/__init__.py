"""Tests of the serial sonar-head edge (drivers.serial, mocks, urlhandlers, faults)."""
