"""drivers: the hardware edge (serial sonar head, CAN glider autopilot, ArduPilot SITL) and their
device mocks.

The top layer of echoloop: it may import :mod:`hil_bridge` and :mod:`sim_core`, and nothing
below imports it. Sub-packages, and what each may import of its siblings (no cycles):

* :mod:`drivers.serial` and :mod:`drivers.can`: the host side, what runs against real hardware.
  They know nothing of each other, nor of the mocks or the URL handlers; ``can`` may use
  :mod:`drivers.faults` (the fault-injecting bus its link wraps on request).
* :mod:`drivers.ardupilot`: ArduPilot firmware in the loop over SITL's JSON physics interface;
  it knows nothing of the other drivers, the mocks or the URL handlers.
* :mod:`drivers.faults`: fault injection for both edges; it may stand on ``serial`` (the pty and
  device ends of a serial link), never on ``can``, ``mocks`` or ``urlhandlers``.
* :mod:`drivers.mocks`: the devices' other ends (and SITL's protocol double); they may use
  ``serial``, ``can`` and ``faults``, never ``urlhandlers``.
* :mod:`drivers.urlhandlers`: pyserial URL schemes played by the mocks; it may use ``mocks`` and
  ``serial``, and nothing imports it (pyserial finds it by name, see
  :data:`drivers.serial.link.URL_HANDLERS`).

:mod:`drivers.cli` (``echoloop mock ...``) starts the mocks, naming them as strings.
"""
