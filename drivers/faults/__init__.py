"""Fault injection for the hardware edge, without root or kernel modules (serial and CAN)."""
