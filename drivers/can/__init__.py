"""CAN glider autopilot edge: the "raw" profile (``glider.dbc``), its codec, a resilient
python-can link and the ``AutopilotAdapter`` node (docs/can.md).

Modules: :mod:`drivers.can.codec` (cantools, node-id offsets, saturation counting),
:mod:`drivers.can.bus` (``CanLink``: retry, back-off, bus-off recovery, candump logging),
:mod:`drivers.can.samples` (state sample assembly from frames, never mixing two samples),
:mod:`drivers.can.endpoint` (``CanEndpoint``: a link with its receive and transmit threads, run
by the adapter and by the mock autopilot alike), :mod:`drivers.can.bridge_frames` (the signal
values of the frames the bridge sends), :mod:`drivers.can.supervision` (command supervision:
WAITING, FRESH, HOLD, FAILSAFE), :mod:`drivers.can.adapter` (``AutopilotAdapter``, launch node
``autopilot``) and :mod:`drivers.can.busload` (on-wire frame length and bus load).

Host side: it may import :mod:`drivers.faults` (the fault-injecting bus), :mod:`hil_bridge` and
:mod:`sim_core`; never :mod:`drivers.serial`, :mod:`drivers.mocks` or :mod:`drivers.urlhandlers`.
"""
