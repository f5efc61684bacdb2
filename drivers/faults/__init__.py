"""Fault injection for the hardware edge, without root or kernel modules (serial and CAN).

Modules: ``can_bus`` (``FaultInjectingBus``: a python-can bus wrapper injecting error frames,
truncation, foreign and dropped frames, full send buffers, bus-off, receive errors, delays) and
``serial_proxy`` (``SerialFaultProxy``: a frame-aware pty proxy between a device and the host).

It may import :mod:`drivers.serial` (the pty and device ends the proxy stands on),
:mod:`hil_bridge` and :mod:`sim_core`; never :mod:`drivers.can` (which imports ``can_bus``),
:mod:`drivers.mocks` or :mod:`drivers.urlhandlers`.
"""
